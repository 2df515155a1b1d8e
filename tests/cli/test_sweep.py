"""``carl-sumo sweep``: a 2-trial sweep end to end (its runs are `train`'s runs), a trial whose
worker process is killed resumes from its last checkpoint and the sweep finishes, the tables'
statistics, and one line with exit status 2 for a bad spec. The Ray runs skip without the extra."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.cli.sweep_report import config_rows

from conftest import NET, REPO_ROOT

SPEC = """name = "small"
out = "{out}"
results = "{results}"
cpus_per_trial = 1

[train]
algo = "ca-td3"
vehicles = 3
steps = {steps}
learning_starts = 100
eval_every = 100
eval_events = 2
checkpoint_every = 100
net = "{net}"

[grid]
seed = {seeds}
"""


def write_spec(tmp_path: Path, steps: int = 200, seeds: str = "[0, 1]", extra: str = "") -> Path:
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(out=tmp_path / "runs", results=tmp_path / "results", net=NET,
                                steps=steps, seeds=seeds) + extra)
    return spec


def curve(path: Path) -> list[list[str]]:
    """A learning-curve CSV without its wall-time column."""
    rows = list(csv.reader(open(path)))
    col = rows[0].index("wall_s")
    return [r[:col] + r[col + 1:] for r in rows]


def test_a_two_trial_sweep_runs_train_and_writes_its_tables(tmp_path, capsys):
    pytest.importorskip("ray")
    assert main(["sweep", str(write_spec(tmp_path)), "--workers", "2"]) == 0
    results = tmp_path / "results"
    assert {"sweep.md", "trials.csv", "configs.csv"} <= {p.name for p in results.iterdir()}
    trials = list(csv.DictReader(open(results / "trials.csv")))
    assert [(t["trial"], t["seed"], t["status"]) for t in trials] == [
        ("small_seed0", "0", "ok"), ("small_seed1", "1", "ok")]
    configs = list(csv.DictReader(open(results / "configs.csv")))
    assert len(configs) == 1 and configs[0]["seeds"] == "2"
    scores = [float(t["score"]) for t in trials]
    assert float(configs[0]["score_mean"]) == pytest.approx(np.mean(scores), rel=1e-5)
    assert "Best configuration: **small**" in (results / "sweep.md").read_text()
    # a trial is the `train` run of the same options: the same learning curve, step for step
    direct = tmp_path / "direct" / "p.pt"
    assert main(["train", "--algo", "ca-td3", "--vehicles", "3", "--steps", "200",
                 "--learning-starts", "100", "--eval-every", "100", "--eval-events", "2",
                 "--checkpoint-every", "100", "--net", str(NET), "--seed", "1",
                 "--out", str(direct)]) == 0
    assert curve(tmp_path / "runs" / "small_seed1.csv") == curve(direct.with_suffix(".csv"))


def _descendants(pid: int) -> list[int]:
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        for kid in children.get(todo.pop(), []):
            found.append(kid)
            todo.append(kid)
    return found


def _trial_process(sweep_pid: int) -> int | None:
    """The Ray worker process running the trial (Tune's ``ImplicitFunc``), if it runs."""
    for pid in _descendants(sweep_pid):
        try:
            title = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0]
        except OSError:
            continue
        if title.startswith(b"ray::ImplicitFunc"):
            return pid
    return None


def _driver_holds_second_checkpoint(tune_dir: Path) -> bool:
    """Tune's driver has registered the step-200 checkpoint. The worker writes the folder
    before the driver hears of it; only after registering it does the driver delete the
    step-100 one (``num_to_keep=1``)."""
    return any(tune_dir.glob("*/checkpoint_000001")) and \
        not any(tune_dir.glob("*/checkpoint_000000"))


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the trial's worker")
def test_a_killed_trial_resumes_from_its_checkpoint_and_the_sweep_finishes(tmp_path):
    pytest.importorskip("ray")
    spec = write_spec(tmp_path, steps=500, seeds="[2]")
    proc = subprocess.Popen([sys.executable, "-m", "carl_sumo", "sweep", str(spec),
                             "--workers", "1"], cwd=REPO_ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        tune_dir = tmp_path / "results" / "tune"
        deadline = time.monotonic() + 480  # a loaded 2-core machine needs minutes
        victim = None
        while victim is None and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            if _driver_holds_second_checkpoint(tune_dir):
                victim = _trial_process(proc.pid)
        assert victim is not None, "the trial never reached its second checkpoint"
        os.kill(victim, signal.SIGKILL)
        output, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, output[-2000:]
    (trial,) = csv.DictReader(open(tmp_path / "results" / "trials.csv"))
    assert trial["status"] == "ok" and int(trial["resumed_at"]) >= 200
    steps = [int(r[0]) for r in curve(tmp_path / "runs" / "small_seed2.csv")[1:]]
    assert steps == [100, 200, 300, 400, 500]  # every validation once: resumed, not restarted


def test_configurations_are_compared_across_seeds_and_the_best_comes_first():
    def run(config: str, seed: int, score: float) -> dict:
        return {"config": config, "seed": seed, "status": "ok", "score": score, "unsafe": False,
                "val_reward": 0.0, "headway_s": 1.5, "jerk_mps3": score / 10,
                "speed_mps": 8.0, "dampening_ratio": 1.0, "collisions": 0}

    rows = [run("a", s, v) for s, v in enumerate((1.0, 2.0, 3.0))] + \
           [run("b", s, v) for s, v in enumerate((4.0, 5.0, 6.0))] + \
           [{**run("b", 9, 100.0), "status": "failed: killed"}]  # a failed run does not count
    table = config_rows(rows)
    assert [r["config"] for r in table] == ["b", "a"]
    b, a = table
    assert (b["score_mean"], b["score_std"], b["seeds"]) == (5.0, 1.0, 3)
    assert (a["d_score"], b["d_score"]) == (-3.0, 0.0)
    # 3 against 3 seeds, fully separated: the exact permutation p is 2/20
    assert 0.07 < a["p_score"] < 0.13 and b["p_score"] == 1.0


@pytest.mark.parametrize("text, needle", [
    ("name = \"x\"\n[train\n", "not valid TOML"),
    ("name = \"x\"\ncolour = 1\n", "unknown key(s) colour"),
    ("name = \"x\"\n[train]\nalgo = \"ppo\"\n", "unknown --algo 'ppo'"),
    ("name = \"x\"\n[train]\nwarp = 9\n", "unrecognized arguments: --warp 9"),
    ("name = \"x\"\n[train]\nsteps = 0\n", "--steps must be a whole number in [1, "),
    ("name = \"x\"\n[grid]\nseed = []\n", "grid.seed must be a non-empty list"),
    ("name = \"x\"\n[grid]\nout = [\"a\"]\n", "out, resume and ray belong to the sweep"),
    ("name = \"x\"\nsearch = \"random\"\n[random]\nnoise = {uniform = [0.2, 0.1]}\n",
     "uniform needs [lo, hi] with lo < hi"),
    ("name = \"x\"\n[train]\ndata = \"/nonexistent/events.csv\"\n", "trial x_seed0"),
    ("name = \"x\"\nout = \"/proc/nope\"\n", "cannot write out /proc/nope"),
    ("name = \"x\"\nship_string_stable = \"mars\"\n", "give \"ideal\" or \"real\""),
])
def test_a_bad_spec_is_one_line_exit_2_and_nothing_is_written(tmp_path, capsys, text, needle):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    assert main(["sweep", str(spec), "--results", str(tmp_path / "r"),
                 *([] if "out =" in text else ["--out", str(tmp_path / "o")])]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("carl-sumo: error:") and "\n" not in err and needle in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_a_missing_spec_is_one_line_exit_2(tmp_path, capsys):
    assert main(["sweep", str(tmp_path / "none.toml")]) == 2
    assert "cannot read sweep spec" in capsys.readouterr().err


SHIPPED_SEEDS = REPO_ROOT / "policies" / "seeds"


@pytest.mark.parametrize("spec", sorted((REPO_ROOT / "sweeps").glob("*.toml")),
                         ids=lambda p: p.stem)
def test_shipped_specs_run_the_recipes_of_the_shipped_seed_files(spec):
    """Every trial of a shipped spec trains its recipe file with exactly the configuration of
    the command recorded in the seed file that trained it (same stem and seed; only the output
    path and the command text differ): the recipes reproduce the shipped runs."""
    import shlex
    from dataclasses import asdict

    from carl_sumo.cli.config_options import config_from_args
    from carl_sumo.cli.policies import TRAIN_CONVERTERS, train_parser
    from carl_sumo.cli.sweep_trials import load_spec, plan_trials
    from carl_sumo.learn.policy import read_policy_payload

    parser = train_parser()

    def resolved(argv):  # the configuration only (every check of a trial: check_trials' test)
        return config_from_args(parser.parse_args(argv), converters=TRAIN_CONVERTERS,
                                check=False)

    loaded = load_spec(spec)
    assert loaded.ship == Path("policies") / f"{loaded.name}.pt" and loaded.ship.exists()
    assert loaded.recipe == Path("recipes") / f"{loaded.name}.toml"
    trials = plan_trials(loaded)
    assert trials
    for trial in trials:
        meta = read_policy_payload(SHIPPED_SEEDS / f"{trial.name}.pt")["metadata"]
        recorded = resolved(shlex.split(meta["command"])[1:])
        planned = resolved(["train", *trial.argv])
        configs = [{k: v for k, v in asdict(c).items() if k not in ("out", "command")}
                   for c in (recorded, planned)]
        assert configs[0] == configs[1], trial.name


def test_seed_in_a_string_option_is_the_trials_seed(tmp_path):
    """A warm start per seed: {seed} in a [train] string becomes each trial's seed."""
    from carl_sumo.cli.sweep_trials import load_spec, plan_trials

    spec = write_spec(tmp_path, extra="")
    text = spec.read_text().replace('[train]\n', '[train]\ninit = "policies/seeds/x_seed{seed}.pt"\n')
    spec.write_text(text)
    trials = plan_trials(load_spec(spec))
    for trial in trials:
        i = trial.argv.index("--init")
        assert trial.argv[i + 1] == f"policies/seeds/x_seed{trial.seed}.pt"


def test_a_sweep_does_not_overwrite_files_unless_asked(tmp_path, capsys, monkeypatch):
    spec = write_spec(tmp_path)
    missing = tmp_path / "missing.csv.gz"  # the data check after the overwrite check fails
    spec.write_text(spec.read_text().replace('net = "', f'data = "{missing}"\nnet = "'))
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "small_seed1.pt").write_bytes(b"a run of an earlier sweep")
    code = main(["sweep", str(spec)])
    err = capsys.readouterr().err
    assert code == 2 and "would overwrite" in err and "small_seed1.pt" in err
    assert "--overwrite" in err and len(err.strip().splitlines()) == 1
    assert (tmp_path / "runs" / "small_seed1.pt").read_bytes() == b"a run of an earlier sweep"
    assert not (tmp_path / "results").exists()
    code = main(["sweep", str(spec), "--overwrite"])  # asked: on to the next check
    err = capsys.readouterr().err
    assert code == 2 and "would overwrite" not in err and "missing.csv.gz" in err
    monkeypatch.chdir(REPO_ROOT)  # the shipped specs write the tracked policies/seeds/ files
    code = main(["sweep", "sweeps/ca_td3.toml"])
    err = capsys.readouterr().err
    assert code == 2 and "would overwrite policies/seeds/ca_td3_ploeg_10_seed0.pt" in err
