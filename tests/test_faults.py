"""Fault injection (issue 37): a full disk, special files, empty paths, signals at random moments
and event tables with non-finite and extreme values. Every fault ends as the project promises:
one line and exit status 2 (bad input, an output that cannot be written) or 128 + n (signal n),
no partial or temporary file, no process left; never a traceback.

The full disk is a small tmpfs mounted for the test (as root; skipped where mounting is not
permitted). The module runs in well under a minute."""

from __future__ import annotations

import errno
import os
import random
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carl_sumo.cli import main
from carl_sumo.errors import InputError, OutputError
from carl_sumo.files import atomic_path, atomic_write, check_output_file, write_text_atomic

from conftest import NET, REPO_ROOT, braking_event, event_table

EVENT = "sumo42_f661_l654_fr3000"
"""An event of the shipped default set (27 s; `carl-sumo data list --split all`)."""

PAGE = 4096


# --- a full disk -------------------------------------------------------------------------------

@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs; ``fill(free)`` leaves ``free`` bytes (rounded to pages) of it."""
    mount = tmp_path / "disk"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode})")
    try:
        yield mount
    finally:
        if subprocess.run(["umount", str(mount)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def fill(disk: Path, free: int = 0) -> None:
    """Fill ``disk`` up to ``free`` bytes (0: write until the file system says it is full)."""
    with open(disk / "filler", "ab") as f:
        while True:
            room = os.statvfs(disk).f_bavail * os.statvfs(disk).f_frsize - free
            if room <= 0:
                return
            try:
                f.write(b"\0" * min(room, PAGE))
                f.flush()
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
                return


def left_on(disk: Path) -> list[str]:
    """What is on the disk besides the filler (hidden temporary files included)."""
    return sorted(p.name for p in disk.iterdir() if p.name not in ("filler", "old"))


def one_line_exit_2(code: int, err: str, *phrases: str) -> None:
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("carl-sumo: error: "), err
    for phrase in phrases:
        assert phrase in err, err


def test_simulate_json_on_a_full_disk_keeps_the_previous_file(small_disk, capsys):
    old = small_disk / "s.json"
    old.write_text("previous results\n")
    fill(small_disk)
    code = main(["simulate", "--events", "2", "--vehicles", "3", "--net", str(NET),
                 "--json", str(old)])
    one_line_exit_2(code, capsys.readouterr().err, f"cannot write {old}", "ENOSPC",
                    "free some space")
    assert old.read_text() == "previous results\n"
    assert left_on(small_disk) == ["s.json"]


def test_replay_fcd_on_a_full_disk_writes_no_partial_fcd(small_disk, capsys):
    fill(small_disk, free=PAGE)  # SUMO starts the file, and cannot finish it
    code = main(["replay", "--event", EVENT, "--split", "all", "--vehicles", "3", "--net",
                 str(NET), "--fcd", str(small_disk / "f.xml")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "f.xml" in err and ("incomplete or not XML" in err or "ENOSPC" in err), err
    assert left_on(small_disk) == []


def test_net_build_on_a_full_disk_writes_no_partial_network(small_disk, capsys):
    fill(small_disk, free=PAGE)  # the network (7 KB) does not fit
    code = main(["net", "build", "--out", str(small_disk / "i80.net.xml")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "i80.net.xml" in err and ("incomplete or not XML" in err or "ENOSPC" in err), err
    assert left_on(small_disk) == []


@pytest.fixture
def tiny_events(tmp_path) -> Path:
    path = tmp_path / "events.csv"
    event_table([braking_event(150, "cruise")]).to_csv(path, index=False)
    return path


def train_argv(events: Path, out: Path, steps: int = 40) -> list[str]:
    return ["train", "--algo", "td3", "--vehicles", "1", "--data", str(events), "--split",
            "all", "--net", str(NET), "--learning-starts", "20", "--eval-every", "20",
            "--checkpoint-every", "20", "--envs", "1", "--steps", str(steps), "--out", str(out)]


@pytest.mark.parametrize("free", [0, 2 * PAGE], ids=["curve", "policy"])
def test_train_on_a_full_disk_leaves_no_partial_curve_or_policy(small_disk, tiny_events, free):
    """No room at all: the curve cannot be started; two pages: the curve (a few hundred bytes,
    rewritten whole) fits, the policy (23 KB) does not."""
    fill(small_disk, free)
    out = small_disk / "p.pt"
    done = subprocess.run([sys.executable, "-m", "carl_sumo", *train_argv(tiny_events, out)],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    err = done.stderr.strip().splitlines()
    assert done.returncode == 2 and err[-1].startswith("carl-sumo: error: cannot write"), \
        done.stderr
    assert "Traceback" not in done.stderr
    assert not (small_disk / "p.pt").exists() and not (small_disk / "p.ckpt").exists()
    assert not [n for n in left_on(small_disk) if n.endswith(".tmp")]
    if (small_disk / "p.csv").exists():  # whole: a header and complete rows
        lines = (small_disk / "p.csv").read_text().splitlines()
        from carl_sumo.learn.curve import LOG_COLUMNS

        assert lines[0].startswith("step,") and \
            all(len(x.split(",")) == len(LOG_COLUMNS) for x in lines)


def test_an_os_error_while_writing_removes_the_temporary_file(tmp_path):
    target = tmp_path / "out.bin"
    with pytest.raises(OutputError, match="cannot write .*out.bin: .*EIO"):
        with atomic_write(target, "wb") as f:
            f.write(b"half")
            raise OSError(errno.EIO, "Input/output error")
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_folder_is_one_line(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k,ro", "tmpfs", str(ro)],
                          capture_output=True)
    if done.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        with pytest.raises(OutputError, match="EROFS"):
            write_text_atomic(ro / "x.txt", "x")
        with pytest.raises(InputError, match="cannot write --json"):
            check_output_file(ro / "x.json", "--json")
    finally:
        subprocess.run(["umount", str(ro)], capture_output=True)


# --- special files and empty paths ------------------------------------------------------------

def test_a_device_or_pipe_is_never_replaced(tmp_path, capsys):
    """A null device of the test's own (never /dev/null itself: code that replaced it would
    break the machine) and a named pipe stay what they are."""
    fifo, null = tmp_path / "pipe", tmp_path / "null"
    os.mkfifo(fifo)
    try:
        os.mknod(null, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        null = None  # not root: the pipe stands for every special file
    for target in [t for t in (null, fifo) if t is not None]:
        code = main(["simulate", "--events", "1", "--json", str(target)])
        one_line_exit_2(code, capsys.readouterr().err, "not a regular file")
    assert null is None or stat.S_ISCHR(os.stat(null).st_mode)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    with pytest.raises(InputError, match="not a regular file"):  # the writer checks it itself
        with atomic_path(fifo) as tmp:
            tmp.write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null", "pipe"][null is None:]


EMPTY = {"evaluate --out": ["evaluate", "--quick", "--out", ""],
         "simulate --json": ["simulate", "--json", ""],
         "replay --fcd": ["replay", "--event", EVENT, "--fcd", ""],
         "train --out": ["train", "--out", ""],
         "train --resume": ["train", "--resume", ""],
         "export --out": ["export", "x.ckpt", "--out", ""],
         "tune --out": ["tune", "ploeg", "--out", ""],
         "study --out": ["study", "--out", ""],
         "net build --out": ["net", "build", "--out", ""],
         "data make-default --out": ["data", "make-default", "--out", ""],
         "string-stability --json": ["string-stability", "--json", ""],
         "sweep --out": ["sweep", "sweeps/ca_td3.toml", "--out", ""],
         "simulate --data": ["simulate", "--data", ""]}


@pytest.mark.parametrize("case", list(EMPTY))
def test_an_empty_path_never_means_the_current_folder(tmp_path, monkeypatch, capsys, case):
    monkeypatch.chdir(tmp_path)
    code = main(EMPTY[case])
    one_line_exit_2(code, capsys.readouterr().err, f"{case.split()[-1]} is an empty path")
    assert list(tmp_path.iterdir()) == []


# --- signals ------------------------------------------------------------------------------------

def children_of(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.append(int(entry))
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def run_and_signal(argv: list[str], signum: int, delay_s: float, ready, group: bool = False
                   ) -> tuple[int, str, list]:
    """Start ``carl-sumo argv``, wait until ``ready(pid)`` holds, then ``delay_s``, send
    ``signum`` (``group``: to all its processes, as a terminal's Ctrl-C does); (exit status,
    stderr, the child processes it had before the signal)."""
    proc = subprocess.Popen([sys.executable, "-m", "carl_sumo", *argv], cwd=REPO_ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=group)
    try:
        deadline = time.time() + 60
        while not ready(proc.pid) and time.time() < deadline and proc.poll() is None:
            time.sleep(0.05)
        time.sleep(delay_s)
        children = children_of(proc.pid)
        if group:
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err, children


@pytest.mark.parametrize("signum, group", [(signal.SIGTERM, False), (signal.SIGINT, False),
                                           (signal.SIGHUP, False), (signal.SIGINT, True)],
                         ids=["SIGTERM", "SIGINT", "SIGHUP", "Ctrl-C"])
def test_a_signal_stops_simulate_with_its_workers(tmp_path, signum, group):
    """simulate --workers 2 on the shipped leader set, stopped at a (seeded) random moment once
    its two workers run: exit 128 + n, one line (none from the workers, also when a terminal's
    Ctrl-C reaches them too), no output, no temporary file, no process left."""
    delay = random.Random(signum + group).uniform(0.2, 2.0)
    out = tmp_path / "s.json"
    code, err, children = run_and_signal(
        ["simulate", "--workers", "2", "--split", "all", "--data", "default", "--net",
         "networks/i80.net.xml", "--vehicles", "5", "--json", str(out)], signum, delay,
        lambda pid: len(children_of(pid)) >= 2, group)
    assert len(children) >= 2, "the workers had not started"
    assert code == 128 + signum, err
    assert err.strip() == "carl-sumo: interrupted", err
    time.sleep(0.2)
    assert not [c for c in children if alive(c)], "a worker outlived its command"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("workers", ["1", "2"])
def test_sigterm_to_study_leaves_no_temporary_run_folder(tmp_path, workers):
    """A study's runs write SUMO's outputs into a temporary folder (in their worker processes,
    or in the command itself with one worker): stopped, each removes its own."""
    code, err, children = run_and_signal(
        ["study", "--penetration", "0,1", "--seeds", "1", "--duration", "300", "--warmup", "60",
         "--workers", workers, "--out", str(tmp_path / "st")], signal.SIGTERM,
        random.Random(11).uniform(1.0, 3.0),
        lambda pid: len(list((tmp_path / "st" / "runs").glob(".*.tmp"))) >= 1)
    assert code == 128 + signal.SIGTERM, err
    assert err.strip() == "carl-sumo: interrupted", err
    time.sleep(0.2)
    assert not [c for c in children if alive(c)]
    assert not [p for p in tmp_path.rglob("*") if p.is_file() or p.name.endswith(".tmp")]


def test_a_signal_that_lands_in_a_c_callback_is_delivered_again(capsys):
    """A signal raised inside a ctypes callback (as numba's compiler runs through llvmlite) is
    dropped by C and reported to sys.unraisablehook: the command's hook delivers it again, so the
    command still stops, and nothing is printed about it."""
    import ctypes
    import threading

    from carl_sumo.interrupts import Interrupted, stop_on_signals

    callback = ctypes.CFUNCTYPE(None)(lambda: time.sleep(0.5))  # the signal lands in here
    restore = stop_on_signals()
    try:
        threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGTERM)).start()
        with pytest.raises(Interrupted) as stopped:
            callback()
            time.sleep(2.0)  # the second delivery interrupts this
    finally:
        restore()
    assert stopped.value.signum == signal.SIGTERM
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_held_signal_stops_the_command_once_the_block_has_ended():
    """interrupts.held (around ray.init): a SIGTERM inside the block does not cut it; when the
    block ends the command stops with that signal; outside stop_on_signals nothing is held."""
    from carl_sumo.interrupts import Interrupted, held, stop_on_signals

    with held() as holding:
        assert not holding
    finished = []
    restore = stop_on_signals()
    try:
        with pytest.raises(Interrupted) as stopped:
            with held() as holding:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.2)
                finished.append(holding)
    finally:
        restore()
    assert finished == [True] and stopped.value.signum == signal.SIGTERM


def test_sigterm_to_replay_leaves_no_fcd_and_no_temporary_file(tmp_path):
    fcd = tmp_path / "f.xml"
    code, err, _ = run_and_signal(
        ["replay", "--event", EVENT, "--split", "all", "--vehicles", "10", "--warmup", "900",
         "--fcd", str(fcd)], signal.SIGTERM, random.Random(7).uniform(0.0, 0.3),
        lambda pid: any(p.name.endswith(".tmp") for p in tmp_path.iterdir()))
    assert code == 128 + signal.SIGTERM, err
    assert list(tmp_path.iterdir()) == []


# --- non-finite and extreme values ------------------------------------------------------------

EXTREME = st.sampled_from([float("inf"), float("-inf"), float("nan"), 1e300, -1e300, 1e-300,
                           -0.0, 1e6, -1e6, 3.4e38])


@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(column=st.sampled_from(["leader_speed_mps", "follower_speed_mps", "gap_m",
                                "rel_speed_mps", "t_s"]),
       where=st.integers(0, 59), value=EXTREME, vehicles=st.sampled_from(["1", "3"]))
def test_non_finite_and_extreme_values_are_refused_or_run_cleanly(tmp_path, capsys, column,
                                                                  where, value, vehicles):
    import json
    import tempfile

    work = Path(tempfile.mkdtemp(dir=tmp_path))  # one folder per example
    table = event_table([braking_event(60, "e")])
    table.loc[where, column] = value
    table.to_csv(work / "events.csv", index=False)
    code = main(["simulate", "--data", str(work / "events.csv"), "--split", "all", "--vehicles",
                 vehicles, "--net", str(NET), "--json", str(work / "m.json")])
    err = capsys.readouterr().err
    if code == 2:
        assert err.count("\n") == 1 and err.startswith("carl-sumo: error: "), err
        assert sorted(p.name for p in work.iterdir()) == ["events.csv"]
    else:
        assert code == 0, err
        metrics = json.loads((work / "m.json").read_text())["metrics"]
        assert np.isfinite(metrics["headway_s"]) and np.isfinite(metrics["speed_mps"])


# --- sumo-gui closed, or interrupted, during replay --gui -------------------------------------

@pytest.fixture
def traci_sumo(monkeypatch):
    """A SUMO over TraCI as replay --gui runs sumo-gui (no display here: the same TraCI
    connection to the command-line sumo), registered as this process's GUI simulation."""
    import sumolib
    import traci

    import carl_sumo.sim.sumo as sumo

    traci.start([sumolib.checkBinary("sumo"), *sumo.sumo_args(NET)],
                port=sumolib.miscutils.getFreeSocketPort())
    monkeypatch.setattr(sumo, "_gui", True)
    monkeypatch.setattr(sumo, "_sumo_running", True)
    process = traci.getConnection()._process
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        try:
            traci.close(wait=False)
        except Exception:
            pass


def test_a_closed_sumo_gui_is_one_clear_error_and_no_process(traci_sumo):
    import traci

    import carl_sumo.sim.sumo as sumo

    traci.simulationStep()
    traci_sumo.kill()  # what closing sumo-gui's window does to the connection
    traci_sumo.wait()
    with pytest.raises(Exception) as closed:
        traci.simulationStep()
    assert sumo.gui_connection_lost(closed.value)
    sumo.abandon_sumo()  # forgets the lost connection: a next replay --gui can start
    with pytest.raises(Exception, match="not known"):  # TraCIException
        traci.getConnection()
    assert not sumo._sumo_running


def test_an_interrupted_replay_gui_takes_sumo_gui_down(traci_sumo):
    import traci

    import carl_sumo.sim.sumo as sumo

    traci.simulationStep()
    assert not sumo.gui_connection_lost(KeyboardInterrupt())
    started = time.time()
    sumo.abandon_sumo()  # killed, not waited for until someone closes its window
    assert traci_sumo.poll() is not None and time.time() - started < 5
    with pytest.raises(Exception, match="not known"):  # TraCIException
        traci.getConnection()


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children, theirs, ...)."""
    found, todo = [], [pid]
    while todo:
        kids = children_of(todo.pop())
        found += kids
        todo += kids
    return found


def command_of(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def replay_gui_until_running(tmp_path: Path) -> tuple[subprocess.Popen, int, int]:
    """``replay --gui`` under Xvfb (0.1 s a step: 27 s of event take 27 s), started; (its
    process, the carl-sumo process, the sumo-gui process) once the FCD file is being written."""
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run is not installed")
    proc = subprocess.Popen(
        ["xvfb-run", "-a", "-s", "-screen 0 1024x768x24", sys.executable, "-m", "carl_sumo",
         "replay", "--gui", "--delay", "100", "--event", EVENT, "--split", "all", "--vehicles",
         "3", "--fcd", str(tmp_path / "f.xml")], cwd=REPO_ROOT, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True,
        env={k: v for k, v in os.environ.items() if k != "DISPLAY"})
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None:
        below = descendants(proc.pid)
        ours = [p for p in below if "carl_sumo" in command_of(p)]
        gui = [p for p in below if "sumo-gui" in command_of(p)]
        if ours and gui and any(p.name.endswith(".tmp") for p in tmp_path.iterdir()):
            time.sleep(1.0)
            return proc, ours[0], gui[0]
        time.sleep(0.1)
    proc.kill()
    pytest.fail(f"replay --gui did not start: {proc.communicate()[1][-1000:]}")


def test_closing_sumo_gui_during_replay_is_one_line_and_leaves_nothing(tmp_path):
    proc, _, gui = replay_gui_until_running(tmp_path)
    os.kill(gui, signal.SIGTERM)  # the window closes
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1].startswith("carl-sumo: error: sumo-gui was closed"), err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_sigterm_to_replay_gui_takes_sumo_gui_down(tmp_path):
    proc, ours, gui = replay_gui_until_running(tmp_path)
    os.kill(ours, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert "Traceback" not in err, err
    time.sleep(0.2)
    assert not alive(gui), "sumo-gui outlived its command"
    assert list(tmp_path.iterdir()) == []


# --- training options out of range ----------------------------------------------------------

BAD_TRAINING = ["--noise -1", "--hidden 0", "--message-dim -1", "--noise-correlation 1",
                "--eval-events 0", "--adj-max 0", "--w-gap nan", "--jerk-scale 0",
                "--critic-burn-in -3", "--braking-events -1", "--smooth-jerk inf", "--seed -1",
                "--adj-l2 -1", "--w-safe inf", "--actor-lr -1", "--gamma 1.5", "--tau 2",
                "--vehicles 100000"]


@pytest.mark.parametrize("option", BAD_TRAINING)
def test_a_training_option_out_of_range_is_one_line_before_any_work(tmp_path, capsys, option):
    code = main(["train", "--out", str(tmp_path / "p.pt"), "--steps", "50",
                 "--learning-starts", "10", *option.split()])
    one_line_exit_2(code, capsys.readouterr().err, option.split()[0])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["simulate", "--controller", "ploeg", "--comm-loss", "0.1"],
                                  ["replay", "--controller", "ploeg", "--plant", "real",
                                   "--event", EVENT, "--split", "all", "--fcd", "f.xml"]],
                         ids=["simulate", "replay"])
def test_a_negative_impairment_seed_is_one_line(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    code = main(argv + ["--events", "1"] * (argv[0] == "simulate") + ["--impairment-seed", "-1"])
    one_line_exit_2(code, capsys.readouterr().err, "--impairment-seed must be 0 or more")
    assert list(tmp_path.iterdir()) == []


# --- controllers of the user (issue 56) --------------------------------------------------------

USER_CONTROLLERS = '''
import sys
import numpy as np


class Law:
    """Output ``OUT[kind]`` from step 5 on (a finite, zero output before)."""
    kind = "nan"

    def reset(self, n):
        self.n, self.k = n, 0

    def acceleration(self, obs):
        self.k += 1
        if self.k <= 5:
            return np.zeros(obs.shape[0])
        return OUT[self.kind](obs)


OUT = {"nan": lambda o: np.full(o.shape[0], np.nan), "inf": lambda o: np.full(o.shape[0], np.inf),
       "long": lambda o: np.zeros(o.shape[0] + 1), "scalar": lambda o: 0.0,
       "short_list": lambda o: [0.0] * (o.shape[0] - 1), "none": lambda o: None,
       "text": lambda o: "fast", "type_error": lambda o: len(5),
       "recursion": lambda o: OUT["recursion"](o), "memory": lambda o: bytearray(1 << 62),
       "exit": lambda o: sys.exit(7)}
for _kind in OUT:
    globals()[_kind] = type(_kind, (Law,), {"kind": _kind})


class Adjust:
    def reset(self, n):
        pass

    def adjustment(self, obs):
        return np.full(obs.shape[0], np.nan)


class NeedsArgument(Law):
    def __init__(self, gain):
        self.gain = gain


class ResetRaises(Law):
    def reset(self, n):
        raise ValueError("no reset today")


class ListOk:
    def reset(self, n):
        pass

    def acceleration(self, obs):
        return [0.0] * obs.shape[0]


def function_nan(obs):
    return np.full(obs.shape[0], np.nan)


def function_raises(obs):
    raise ZeroDivisionError("division by zero")
'''


@pytest.fixture
def user_controllers(tmp_path) -> Path:
    path = tmp_path / "mine.py"
    path.write_text(USER_CONTROLLERS)
    return path


def simulate_argv(controller: str, *extra: str) -> list[str]:
    return ["simulate", "--events", "1", "--vehicles", "2", "--net", str(NET),
            "--controller", controller, *extra]


USER_FAULTS = {
    "nan": "at step 5: acceleration() returned [nan nan]",
    "inf": "at step 5: acceleration() returned [inf inf]",
    "long": "at step 5: acceleration() returned [0. 0. 0.]",
    "scalar": "at step 5: acceleration() returned 0.",
    "short_list": "at step 5: acceleration() returned [0.] (list",
    "none": "at step 5: acceleration() returned None",
    "text": "at step 5: acceleration() returned 'fast'",
    "type_error": "at step 5: acceleration() raised TypeError",
    "recursion": "at step 5: acceleration() raised RecursionError",
    "memory": "at step 5: acceleration() raised MemoryError",
    "exit": "at step 5: acceleration() called sys.exit(7)",
    "Adjust": "at step 0: adjustment() returned [nan nan]",
    "function_nan": "at step 0: function_nan(observations) returned [nan nan]",
    "function_raises": "at step 0: function_raises(observations) raised ZeroDivisionError",
    "NeedsArgument": "constructing NeedsArgument() raised TypeError",
    "ResetRaises": "in reset() raised ValueError: no reset today",
}


@pytest.mark.parametrize("attr", list(USER_FAULTS))
def test_a_user_controller_that_fails_is_one_line_naming_it(user_controllers, capsys, attr):
    """Classes and functions alike: a non-finite, misshapen or non-numeric output, an exception
    of any kind or sys.exit in user code is one line naming the controller, the step and what it
    returned or raised; exit 2."""
    name = f"{user_controllers}:{attr}"
    code = main(simulate_argv(name))
    one_line_exit_2(code, capsys.readouterr().err, f"controller {name}", USER_FAULTS[attr])


def test_sys_exit_when_a_controller_is_imported_is_one_line(tmp_path, capsys):
    path = tmp_path / "leaves.py"
    path.write_text("import sys\nsys.exit(7)\n")
    code = main(simulate_argv(f"{path}:f"))
    one_line_exit_2(code, capsys.readouterr().err, "does not import", "called sys.exit(7)")


def test_a_controller_returning_a_list_of_the_right_length_runs(user_controllers, capsys):
    assert main(simulate_argv(f"{user_controllers}:ListOk")) == 0, capsys.readouterr().err


def test_a_user_controller_failing_in_a_worker_is_the_same_line(user_controllers, capsys):
    name = f"{user_controllers}:nan"
    code = main(["simulate", "--events", "2", "--vehicles", "2", "--net", str(NET), "--workers",
                 "2", "--controller", name])
    one_line_exit_2(code, capsys.readouterr().err, f"controller {name}", USER_FAULTS["nan"])


@pytest.mark.parametrize("command", ["replay", "string-stability", "study", "scenario"])
def test_a_user_controller_fails_alike_in_every_command(user_controllers, tmp_path, capsys,
                                                        command):
    name = f"{user_controllers}:function_nan"
    argv = {"replay": ["replay", "--event", EVENT, "--split", "all", "--vehicles", "2",
                       "--fcd", str(tmp_path / "f.xml")],
            "string-stability": ["string-stability", "--vehicles", "2", "--frequencies", "1"],
            "study": ["study", "--penetration", "1", "--duration", "20", "--warmup", "5",
                      "--seeds", "1", "--workers", "1", "--out", str(tmp_path / "st")],
            "scenario": ["simulate", "--events", "1", "--vehicles", "2", "--scenario", "cut-in"]}
    code = main(argv[command] + ["--net", str(NET), "--controller", name])
    one_line_exit_2(code, capsys.readouterr().err, f"controller {name}", "returned [nan")
    assert not (tmp_path / "f.xml").exists() and not (tmp_path / "st" / "study.csv").exists()


# --- leaders faster than the network's lanes (issue 56) ----------------------------------------

def fast_events() -> list:
    """A leader slowing from 36 to 15 m/s (80 mph down) and a highD-like 40 m/s cruise, both
    above i80.net.xml's 33.3 m/s limit; followers start at 34 and 40 m/s."""
    from carl_sumo.data.events import Event

    n = 150
    acc = np.zeros(n - 1)
    acc[20:20 + 105] = -2.0
    slowing = 36.0 + np.concatenate([[0.0], np.cumsum(acc) * 0.1])
    cruise = np.full(n, 40.0)
    return [Event(event_id, "zhu2020_testset", "i-80",
                  np.concatenate([[0.0], np.cumsum(v[1:]) * 0.1]), v, 5.0, np.full(n, v0),
                  np.full(n, gap))
            for event_id, v, v0, gap in (("slowing36", slowing, 34.0, 40.0),
                                         ("cruise40", cruise, 40.0, 50.0))]


@pytest.fixture
def fast_table(tmp_path) -> Path:
    path = tmp_path / "fast.csv"
    event_table(fast_events()).to_csv(path, index=False)
    return path


def test_a_leader_faster_than_the_lanes_is_replayed_exactly():
    from carl_sumo.sim.sumo import PlatoonSim

    for event in fast_events():
        sim = PlatoonSim(NET, "idm")
        sim.reset(event, 2)
        while not sim.done:
            sim.step()
            assert sim.leader_sumo_speed() == pytest.approx(sim.leader_speed, abs=1e-6)
            assert sim.leader_sumo_position() == pytest.approx(sim.leader_pos, abs=1e-3)


@pytest.mark.parametrize("scenario", [None, "cut-in", "join"])
def test_fast_freeway_events_run_end_to_end(fast_table, tmp_path, capsys, scenario):
    code = main(["simulate", "--data", str(fast_table), "--split", "all", "--vehicles", "2",
                 "--net", str(NET), "--controller", "idm,krauss,sumo-cacc,idm-external,ploeg",
                 "--json", str(tmp_path / "s.json")]
                + ["--scenario", scenario] * (scenario is not None))
    assert code == 0, capsys.readouterr().err
    assert (tmp_path / "s.json").is_file()
    code = main(["replay", "--data", str(fast_table), "--split", "all", "--event", "cruise40",
                 "--vehicles", "2", "--net", str(NET), "--fcd", str(tmp_path / "f.xml")])
    assert code == 0, capsys.readouterr().err


# --- sizes without an upper bound (issue 56) ---------------------------------------------------

UNBOUNDED = {
    "simulate --actuation-delay 1e9": (["simulate", "--events", "1", "--controller", "ploeg",
                                        "--actuation-delay", "1e9"], "--actuation-delay"),
    "simulate --vehicle-lag 1e9": (["simulate", "--events", "1", "--controller", "ploeg",
                                    "--vehicle-lag", "1e9"], "--vehicle-lag"),
    "simulate --warmup 1e8": (["simulate", "--events", "1", "--warmup", "1e8"], "--warmup"),
    "replay --warmup 1e8": (["replay", "--event", EVENT, "--split", "all", "--warmup", "1e8",
                             "--fcd", "f.xml"], "--warmup"),
    "replay --actuation-delay 1e9": (["replay", "--event", EVENT, "--split", "all",
                                      "--controller", "ploeg", "--actuation-delay", "1e9",
                                      "--fcd", "f.xml"], "--actuation-delay"),
    "evaluate --warmup 1e8": (["evaluate", "--quick", "--warmup", "1e8", "--out", "ev"],
                              "--warmup"),
    "string-stability --min-frequency 1e-9": (["string-stability", "--controller", "ploeg",
                                               "--min-frequency", "1e-9"], "1e-09 rad/s"),
    "string-stability --frequencies 1e8": (["string-stability", "--controller", "ploeg",
                                            "--frequencies", "100000000"], "--frequencies"),
    "string-stability --actuation-delay 1e9": (["string-stability", "--controller", "ploeg",
                                                "--actuation-delay", "1e9"], "--actuation-delay"),
    "study --warmup 1e9": (["study", "--warmup", "1e9", "--out", "st"], "--warmup"),
    "study --duration 1e9": (["study", "--duration", "1e9", "--out", "st"], "--duration"),
    "study --seeds 1e9": (["study", "--seeds", "1000000000", "--out", "st"], "--seeds"),
    "study --actuation-delay 1e9": (["study", "--controller", "ploeg", "--actuation-delay", "1e9",
                                     "--out", "st"], "--actuation-delay"),
}


@pytest.mark.parametrize("case", list(UNBOUNDED))
def test_a_size_beyond_what_a_run_holds_is_one_line_before_any_allocation(tmp_path, monkeypatch,
                                                                          capsys, case):
    argv, phrase = UNBOUNDED[case]
    monkeypatch.chdir(tmp_path)
    code = main(argv)
    one_line_exit_2(code, capsys.readouterr().err, phrase)
    assert list(tmp_path.iterdir()) == []


def test_the_plant_and_the_warm_up_are_bounded_for_every_caller():
    """The Gymnasium plant, training and tuning build these directly."""
    from carl_sumo.sim.vehicle import Plant

    with pytest.raises(InputError, match="--actuation-delay must be at most"):
        Plant(dead_time_s=1e9)
    with pytest.raises(InputError, match="--warmup must be from 0 to"):
        fast_events()[0].with_warmup(1e8)


def test_a_tune_pool_stops_after_a_worker_start_up_failure(tmp_path):
    """A worker whose start-up fails (here: an event table that is not there) stops the run with
    that error, instead of a pool that replaces the worker forever."""
    script = tmp_path / "pool.py"
    script.write_text(f'''
from carl_sumo.errors import InputError
from carl_sumo.experiments.tune import GridPoint, TuneConfig, Runner

if __name__ == "__main__":
    cfg = TuneConfig(data={str(tmp_path / "missing.csv")!r}, workers=2, n_followers=2)
    runner = Runner(cfg, 4, None, None)
    try:
        runner.run([GridPoint(0.8, 0.2, 0.7)])
    except InputError as exc:
        print("stopped:", exc)
    finally:
        runner.close(failed=True)
''')
    try:
        done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                              timeout=60, cwd=REPO_ROOT)
    except subprocess.TimeoutExpired:
        pytest.fail("the pool kept replacing its failing workers")
    assert done.returncode == 0 and "stopped:" in done.stdout and "missing.csv" in done.stdout, \
        done.stdout + done.stderr


# --- policy file fields (issue 56) -------------------------------------------------------------

@pytest.mark.parametrize("field,value", [("adj_max", float("nan")), ("adj_max", float("inf")),
                                         ("adj_max", -1.0), ("n_vehicles", -3),
                                         ("hidden", 0), ("gamma", 2.0)])
@pytest.mark.parametrize("command", ["simulate", "replay", "policy-info", "string-stability"])
def test_a_policy_file_field_out_of_range_is_one_line_in_every_command(tmp_path, capsys, field,
                                                                       value, command):
    import torch

    payload = torch.load(REPO_ROOT / "policies" / "ca_td3_10.pt", weights_only=True)
    payload["agent_config"][field] = value
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    argv = {"simulate": ["simulate", "--events", "1", "--vehicles", "2", "--controller", str(bad)],
            "replay": ["replay", "--event", EVENT, "--split", "all", "--vehicles", "2",
                       "--controller", str(bad), "--fcd", str(tmp_path / "f.xml")],
            "policy-info": ["policy-info", str(bad)],
            "string-stability": ["string-stability", "--vehicles", "2", "--controller",
                                 str(bad)]}[command]
    code = main(argv)
    one_line_exit_2(code, capsys.readouterr().err, f"policy file {bad}",
                    f"agent_config {field} = ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pt"]


@pytest.mark.parametrize("sibling, kind", [(".ckpt", "dir"), (".csv", "dir"), (".png", "dir"),
                                            (".candidates", "file")])
def test_train_checks_every_output_beside_out_before_it_trains(tmp_path, capsys, sibling, kind):
    """Found by the fault round 2: with b.ckpt a folder, train trained and wrote b.csv, b.png and
    b.pt, then exited 2; with b.candidates a file, a FileExistsError traceback."""
    out = tmp_path / "b.pt"
    blocker = out.with_suffix(sibling)
    blocker.mkdir() if kind == "dir" else blocker.write_text("x")
    gate = ["--gate-string-stable", "ideal"] if sibling == ".candidates" else []
    code = main(["train", "--algo", "td3", "--vehicles", "1", "--steps", "20",
                 "--learning-starts", "10", "--envs", "1", "--out", str(out), *gate])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and str(blocker.name) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [blocker.name]


def test_train_with_every_training_event_held_out_is_one_line(tmp_path, capsys):
    from carl_sumo.data import load_events

    ids = tmp_path / "all.txt"
    ids.write_text("\n".join(e.event_id for e in load_events("default", "train")) + "\n")
    code = main(["train", "--algo", "td3", "--vehicles", "1", "--steps", "20",
                 "--learning-starts", "10", "--val-events", str(ids),
                 "--out", str(tmp_path / "p.pt")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "no training event is left" in err and "\n" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["all.txt"]


@pytest.mark.parametrize("argv, blocker", [
    (["evaluate", "--suite", "paper", "--quick"], "README.md"),
    (["study", "--penetration", "0.5", "--duration", "30", "--warmup", "10", "--seeds", "1"],
     "study.csv")])
def test_a_folder_where_a_command_writes_a_file_is_refused_before_the_work(tmp_path, capsys,
                                                                           argv, blocker):
    """Found by the fault round 2: evaluate failed after 45 s and 18 files, study likewise."""
    out = tmp_path / "out"
    (out / blocker).mkdir(parents=True)
    code = main([*argv, "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and f"{blocker} is a folder" in err
    assert [p.name for p in out.iterdir()] == [blocker]


@pytest.mark.parametrize("option", ["--max-frequency", "--min-frequency"])
def test_a_non_finite_frequency_is_one_line_without_warnings(capsys, option):
    """Found by the fault round 2: numpy's RuntimeWarning printed before the error line."""
    assert main(["string-stability", "--controller", "ploeg", option, "inf"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("carl-sumo: error: --min-frequency and --max-frequency must be finite")
    assert "\n" not in err


@pytest.mark.parametrize("second_s", [0.05, 0.3])
def test_a_second_sigterm_during_shutdown_still_exits_143(tmp_path, second_s):
    """Found by the fault round 2: a second SIGTERM 50 ms after the first printed
    "interrupted" and then killed the command by the signal (main() had restored the default
    handlers before Python finished)."""
    proc = subprocess.Popen([sys.executable, "-m", "carl_sumo", "simulate", "--workers", "2",
                             "--split", "all", "--vehicles", "5", "--json",
                             str(tmp_path / "s.json")], cwd=REPO_ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 60
        while len(children_of(proc.pid)) < 2 and time.time() < deadline and proc.poll() is None:
            time.sleep(0.05)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        time.sleep(second_s)
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip() == "carl-sumo: interrupted", err


def test_a_foreign_pickle_as_a_policy_is_one_line(tmp_path):
    """Found by the fault round 2: torch's pickle-protocol UserWarning came before the line."""
    import pickle

    path = tmp_path / "p.pt"
    path.write_bytes(pickle.dumps({"a": 1}, protocol=4))
    proc = subprocess.run([sys.executable, "-m", "carl_sumo", "policy-info", str(path)],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "is corrupt or not a PyTorch file" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_policy_info_table_of_a_policy_without_metadata_prints_no_warning(tmp_path):
    """Found by the fault round 2: numpy's RuntimeWarnings (mean of an empty slice) with exit 0."""
    import torch

    payload = torch.load(REPO_ROOT / "policies" / "td3_1.pt", weights_only=True)
    payload.pop("metadata", None)
    torch.save(payload, tmp_path / "bare.pt")
    proc = subprocess.run([sys.executable, "-m", "carl_sumo", "policy-info", "--table",
                           str(tmp_path / "bare.pt")], cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0 and proc.stderr == "" and "`bare.pt`" in proc.stdout


def test_sumo_guis_own_line_does_not_come_before_the_error(tmp_path):
    """Found by the fault round 2: sumo-gui's "FXApp::openDisplay: unable to open display" line
    came before carl-sumo's one line; it is now quoted in that line."""
    import shutil as _shutil

    if _shutil.which("sumo-gui") is None and not (Path(sys.executable).parent / "sumo-gui").exists():
        pytest.skip("no sumo-gui")
    from carl_sumo.data import load_events

    event = load_events("default", "test")[0].event_id
    env = {**os.environ, "DISPLAY": ":97", "PATH": f"{Path(sys.executable).parent}:"
           + os.environ.get("PATH", "")}
    env.pop("WAYLAND_DISPLAY", None)
    proc = subprocess.run([sys.executable, "-m", "carl_sumo", "replay", "--gui", "--event", event,
                           "--vehicles", "2", "--fcd", str(tmp_path / "f.xml")], cwd=REPO_ROOT,
                          env=env, capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("carl-sumo: error: sumo-gui could not open on display ':97'")
    assert not list(tmp_path.iterdir())
