"""Worker faults: a killed worker's tasks run again in a fresh pool with the same results; a task
whose workers die every time stops the job with one line naming it; nothing hangs."""

import os
import signal
from pathlib import Path

import pytest

from carl_sumo.scale.workers import WorkerError, run_parallel


def square_or_die(x: int, marker: str, always: bool) -> int:
    """x², but the process kills itself (SIGKILL) at x = 3: once if ``marker`` is absent, or
    every time with ``always``."""
    if x == 3 and (always or not Path(marker).exists()):
        Path(marker).touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return x * x


def test_a_killed_worker_is_replaced_and_its_tasks_run_again(tmp_path):
    items = [(x, str(tmp_path / "died"), False) for x in range(8)]
    assert list(run_parallel(square_or_die, items, 2)) == [x * x for x in range(8)]
    assert (tmp_path / "died").exists()
    unordered = run_parallel(square_or_die, [(x, str(tmp_path / "d2"), False) for x in range(8)],
                             2, ordered=False)
    assert sorted(unordered) == [x * x for x in range(8)]


def test_a_task_that_kills_every_worker_stops_the_job_with_one_line(tmp_path):
    items = [(x, str(tmp_path / "m"), True) for x in range(6)]
    with pytest.raises(WorkerError, match=r"died three times while running task x=3") as info:
        list(run_parallel(square_or_die, items, 2, describe=lambda a: f"task x={a[0]}"))
    assert "\n" not in str(info.value)


def _children(pid: int) -> list[int]:
    kids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                kids.append(int(entry.name))
    return kids


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the workers")
def test_simulate_survives_a_killed_worker_with_the_same_metrics(tmp_path):
    import json
    import subprocess
    import sys
    import time

    from conftest import NET

    def run(out: Path, kill: bool) -> int:
        cmd = [sys.executable, "-m", "carl_sumo", "simulate", "--net", str(NET), "--data",
               "default", "--split", "all", "--vehicles", "10", "--controller", "idm-external",
               "--workers", "2", "--json", str(out)]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        if kill:
            deadline = time.time() + 60
            while time.time() < deadline and proc.poll() is None:
                workers = [k for k in _children(proc.pid)
                           if "spawn_main" in Path(f"/proc/{k}/cmdline").read_text(errors="ignore")]
                if len(workers) >= 2:  # both chunks are submitted and not done: the pool breaks
                    os.kill(workers[0], signal.SIGKILL)
                    break
                time.sleep(0.05)
        proc.wait(timeout=300)
        return proc.returncode

    assert run(tmp_path / "ref.json", kill=False) == 0
    assert run(tmp_path / "killed.json", kill=True) == 0
    ref, killed = (json.loads((tmp_path / f).read_text()) for f in ("ref.json", "killed.json"))
    assert killed == ref


def test_training_envs_report_a_dead_worker_in_one_line():
    import numpy as np

    from carl_sumo.experiments.bench import cruise_event
    from carl_sumo.learn.vec_env import VecPlatoon
    from conftest import NET

    vec = VecPlatoon([cruise_event(100)], 2, NET, num_envs=2, seed=0)
    try:
        vec.reset(0)
        vec.step(np.zeros((2, 2)))
        os.kill(vec._procs[1].pid, signal.SIGKILL)
        vec._procs[1].join(timeout=10)
        with pytest.raises(WorkerError, match=r"worker\(s\) \[1\] died.*--resume") as info:
            vec.step(np.zeros((2, 2)))
        assert "\n" not in str(info.value)
    finally:
        vec.close()


def test_workers_die_with_a_command_killed_by_sigkill():
    """SIGKILL cannot be handled: the workers see their parent go (PR_SET_PDEATHSIG on Linux)
    and end too, instead of waiting for tasks for ever (issue 37)."""
    import subprocess
    import sys
    import time

    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    from conftest import REPO_ROOT
    from test_faults import alive, children_of

    proc = subprocess.Popen([sys.executable, "-m", "carl_sumo", "simulate", "--workers", "2",
                             "--split", "all", "--vehicles", "5"], cwd=REPO_ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 60
    while len(children_of(proc.pid)) < 2 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.1)
    time.sleep(1.0)
    workers = children_of(proc.pid)
    proc.kill()
    proc.wait()
    deadline = time.time() + 30  # a worker still importing ends when it starts
    while any(alive(w) for w in workers) and time.time() < deadline:
        time.sleep(0.2)
    assert len(workers) >= 2 and not [w for w in workers if alive(w)]
