#!/usr/bin/env bash
# The wheel works outside the source tree: build it, install it (not editable) into a fresh venv
# and run simulate, replay, train and study from an empty folder, finding the network, vehicle
# types, default leaders and shipped policies through importlib.resources.
# Usage: .ci/wheel_smoke.sh PYTHON   (PYTHON: an interpreter that has the dependencies, e.g. the
# test venv's; the fresh venv reads them from its site-packages, so that torch is not installed
# twice, while carl_sumo itself comes only from the wheel)
set -euo pipefail
deps_python=${1:?give the python of a venv with the dependencies}
root=$(cd "$(dirname "$0")/.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
# from a clean copy of the tracked files (setuptools' build/ keeps stale modules between builds)
git -C "$root" ls-files -z | (cd "$root" && tar --null -T - -cf -) | (mkdir "$tmp/src" && cd "$tmp/src" && tar -xf -)
"$deps_python" -m pip wheel -q --no-deps --no-build-isolation -w "$tmp/dist" "$tmp/src"
python3 -m venv "$tmp/venv"
site=$("$deps_python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
echo "$site" > "$(ls -d "$tmp"/venv/lib/python3*/site-packages)/deps.pth"
"$tmp/venv/bin/pip" install -q --no-deps "$tmp"/dist/carl_sumo-*.whl
mkdir "$tmp/work" && cd "$tmp/work"
run() { echo "+ carl-sumo $*" >&2; "$tmp/venv/bin/carl-sumo" "$@"; }
where=$("$tmp/venv/bin/python" -c "import carl_sumo, sys; print(carl_sumo.__file__)")
case "$where" in "$tmp"/venv/*) ;; *) echo "carl_sumo imported from $where, not the wheel"; exit 1;; esac
run simulate --data default --controller idm-external,product --events 1 --vehicles 4 --plant real
run replay --data default --controller product --vehicles 4 --plant real \
    --event "$("$tmp/venv/bin/python" -c "from carl_sumo.data import load_events; print(load_events('default', 'test')[0].event_id)")" \
    --fcd fcd.xml
test -s fcd.xml
run train --net i80.net.xml --algo td3 --vehicles 2 --steps 60 --learning-starts 20 --envs 1 \
    --eval-every 60 --eval-events 1 --checkpoint-every 60 --out p.pt
run policy-info --recipe p.pt > p.toml
run train --config p.toml --print-config > /dev/null
run study --controller idm-external --penetration 0.5 --duration 30 --warmup 10 --seeds 1 \
    --out study
ls study
echo "wheel smoke test passed: $(ls "$tmp"/dist)"
