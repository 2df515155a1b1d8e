"""``--ray``: the same metrics through Ray tasks as through the local pool, tasks on both nodes of
a two-node cluster, and one line with exit status 2 for a bad address or a missing extra.
Skipped without the Ray extra (``pip install -e ".[ray]"``); CI installs it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

ray = pytest.importorskip("ray")

from carl_sumo.scale import cluster# noqa: E402
from carl_sumo.cli import main  # noqa: E402

from conftest import NET, REPO_ROOT  # noqa: E402


@pytest.fixture(autouse=True)
def no_ray_left():
    """Every test leaves no Ray runtime (and so no Ray process of its own) behind."""
    yield
    assert not ray.is_initialized()
    from carl_sumo.scale import workers

    assert workers._backend is None


def simulate_json(tmp_path, name: str, *extra: str) -> dict:
    out = tmp_path / f"{name}.json"
    code = main(["simulate", "--controller", "idm-external,ploeg", "--net", str(NET),
                 "--events", "40", "--workers", "2", "--json", str(out), *extra])
    assert code == 0
    return json.loads(out.read_text())


def test_simulate_gives_the_same_metrics_through_ray(tmp_path, capsys):
    local = simulate_json(tmp_path, "local")
    through_ray = simulate_json(tmp_path, "ray", "--ray", "local")
    assert through_ray == local
    assert len(local["controllers"]["ploeg"]["events"]) == 40
    err = capsys.readouterr().err
    assert "ray: 4 tasks on 1 Ray node(s)" in err  # two controllers, two chunks each


def test_tasks_land_on_both_nodes_of_a_two_node_cluster(tmp_path, capsys):
    from ray.cluster_utils import Cluster

    two = Cluster(initialize_head=True, head_node_args={"num_cpus": 1,
                                                        "include_dashboard": False})
    try:
        two.add_node(num_cpus=1)
        two.wait_for_nodes()
        result = simulate_json(tmp_path, "two", "--ray", two.address)
        assert len(cluster.last_nodes) == 2  # each node ran a chunk of each controller
        assert sorted(cluster.last_nodes.values()) == [2, 2]
        capsys.readouterr()
        one_line_exit_2(capsys, [*TRAIN_ARGS, "--envs", "3", "--ray", two.address, "--out",
                                 str(tmp_path / "x" / "p.pt")], "needs 3 CPUs on the Ray cluster")
        assert not (tmp_path / "x").exists()
    finally:
        two.shutdown()
    assert result["controllers"]["ploeg"]["metrics"] == \
        simulate_json(tmp_path, "alone")["controllers"]["ploeg"]["metrics"]


def one_line_exit_2(capsys, argv: list[str], needle: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("carl-sumo: error:") and "\n" not in err
    assert needle in err


@pytest.mark.parametrize("address, needle", [
    ("nonsense", "is not an address"),
    ("localhost:99999", "is not an address"),
    ("127.0.0.1:1", "no Ray cluster answers there"),
])
def test_a_bad_address_is_one_line_exit_2(capsys, tmp_path, address, needle):
    one_line_exit_2(capsys, ["simulate", "--ray", address, "--json", str(tmp_path / "x.json")],
                    needle)
    assert not (tmp_path / "x.json").exists()


def test_auto_without_a_cluster_is_one_line_exit_2(capsys, tmp_path, monkeypatch):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    one_line_exit_2(capsys, ["study", "--ray", "auto", "--out", str(tmp_path / "s"),
                             "--seeds", "1", "--penetration", "0", "--duration", "10",
                             "--warmup", "0"], "cannot join a Ray cluster")
    assert not (tmp_path / "s").exists()


def test_a_missing_extra_is_one_line_exit_2(tmp_path):
    code = ("import sys; sys.modules['ray'] = None\n"  # what `import ray` does without the extra
            "from carl_sumo.cli import main\n"
            f"sys.exit(main(['evaluate', '--quick', '--ray', 'local', '--out', {str(tmp_path / 'e')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"carl-sumo: error: {cluster.EXTRA_HINT}"
    assert not (tmp_path / "e").exists()


def curve(path) -> list[list[str]]:
    """A learning-curve CSV without its wall-time column."""
    import csv

    rows = list(csv.reader(open(path)))
    col = rows[0].index("wall_s")
    return [r[:col] + r[col + 1:] for r in rows]


TRAIN_ARGS = ["train", "--vehicles", "3", "--steps", "200", "--learning-starts", "100",
              "--eval-every", "100", "--eval-events", "2", "--checkpoint-every", "100",
              "--seed", "3", "--net", str(NET)]


def test_train_with_ray_actors_takes_the_same_steps(tmp_path, capsys):
    """``train --ray local``: the rollout environments in Ray actors give the same learning curve
    (every validation of every step count) as the spawned processes."""
    args = TRAIN_ARGS
    assert main([*args, "--out", str(tmp_path / "local" / "p.pt")]) == 0
    assert main([*args, "--out", str(tmp_path / "ray" / "p.pt"), "--ray", "local"]) == 0
    local = curve(tmp_path / "local" / "p.csv")
    assert len(local) == 3 and curve(tmp_path / "ray" / "p.csv") == local


@pytest.mark.parametrize("wait_s", [0.0, 2.0], ids=["while-ray-starts", "once-workers-run"])
def test_sigterm_stops_a_ray_run_with_its_workers(tmp_path, wait_s):
    """SIGTERM to `evaluate --quick --ray local` as soon as a Ray worker process exists (ray.init
    is still starting: the signal waits until it has, instead of Ray's own handler exiting 15 or
    its C++ handler aborting) and 2 s later: exit status 143 (Ray's waits turn the signal's
    exception into a plain KeyboardInterrupt; the status still says SIGTERM), one line, and no
    process of the Ray runtime left (issue 37)."""
    import signal
    import time

    sys.path.insert(0, str(REPO_ROOT / "tests"))
    from test_faults import alive, command_of, descendants

    proc = subprocess.Popen([sys.executable, "-m", "carl_sumo", "evaluate", "--quick", "--ray",
                             "local", "--workers", "2", "--out", str(tmp_path / "ev")],
                            cwd=REPO_ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and not any(
            "ray::" in command_of(p) for p in descendants(proc.pid)):  # a Ray worker runs
        time.sleep(0.05)
    time.sleep(wait_s)
    below = descendants(proc.pid)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines()[-1] == "carl-sumo: interrupted"
    time.sleep(2.0)
    assert below and not [p for p in below if alive(p)], "a Ray process outlived its command"
