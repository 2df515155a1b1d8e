"""carl_sumo.files: atomic writes, and the one place every writer takes them from."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import carl_sumo
from carl_sumo.errors import InputError
from carl_sumo.files import atomic_output, check_output_dir, check_output_file, write_text_atomic

PACKAGE = Path(carl_sumo.__file__).parent
HELPERS = {"atomic_output", "atomic_path", "atomic_write", "write_text_atomic", "write_bytes_atomic",
           "check_xml"}


def test_write_text_atomic_creates_folders_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "a" / "b" / "out.txt"
    assert write_text_atomic(path, "one\n") == path
    write_text_atomic(path, "two\n")
    assert path.read_text() == "two\n"
    assert sorted(p.name for p in path.parent.iterdir()) == ["out.txt"]
    tmp = atomic_output(path)
    assert tmp.parent == path.parent and tmp.name.startswith(".out.txt.") and not tmp.exists()


def test_a_temporary_left_by_a_killed_writer_goes_with_the_next_write(tmp_path):
    """SIGKILL leaves a writer's ``.NAME.PID.tmp`` behind; the next write of the same file
    removes it, and leaves a running process's own temporary alone."""
    import os
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    path = tmp_path / "p.ckpt"
    stale = tmp_path / f".p.ckpt.{int(dead.stdout)}.tmp"
    alive = tmp_path / f".p.ckpt.{os.getppid()}.tmp"
    other = tmp_path / f".q.ckpt.{int(dead.stdout)}.tmp"
    for f in (stale, alive, other):
        f.write_text("half")
    write_text_atomic(path, "whole\n")
    assert not stale.exists() and alive.exists() and other.exists()
    assert path.read_text() == "whole\n"


def test_every_writer_imports_the_file_helpers_from_files():
    import carl_sumo.sim.sumo as sumo

    assert not HELPERS & set(vars(sumo)), "sumo.py still holds file helpers"
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name in HELPERS:
                assert path.name == "files.py", f"{path} defines {node.name}"
            if isinstance(node, ast.ImportFrom) and HELPERS & {a.name for a in node.names}:
                assert node.module == "carl_sumo.files", \
                    f"{path}:{node.lineno} imports a file helper from {node.module}"


def _must_not_run(*args, **kwargs):
    raise AssertionError("the long work started before the output path was checked")


LONG_WORK = ("carl_sumo.experiments.simulate.simulate", "carl_sumo.experiments.simulate.replay",
             "carl_sumo.experiments.evaluate.evaluate", "carl_sumo.learn.train.train",
             "carl_sumo.learn.train.export_policy", "carl_sumo.experiments.tune.tune_ploeg",
             "carl_sumo.study.run.run_study", "carl_sumo.sim.network.build_network",
             "carl_sumo.data.default_set.make_default_set")

BAD_OUTPUTS = {
    "simulate --json": ["simulate", "--json", "/proc/x/y.json"],
    "replay --fcd": ["replay", "--event", "e", "--fcd", "/proc/nope/f.xml"],
    "evaluate --out": ["evaluate", "--quick", "--out", "/proc/nope"],
    "study --out": ["study", "--out", "/proc/nope", "--seeds", "1"],
    "tune --out": ["tune", "ploeg", "--out", "/proc/nope/t.json"],
    "train --out": ["train", "--out", "/proc/nope/p.pt"],
    "export --out": ["export", "x.ckpt", "--out", "/proc/nope/p.pt"],
    "net build --out": ["net", "build", "--out", "/proc/nope/i80.net.xml"],
    "data make-default --out": ["data", "make-default", "--out", "/proc/nope/e.csv.gz"],
}


@pytest.mark.parametrize("case", list(BAD_OUTPUTS))
def test_unwritable_output_is_one_line_exit_2_before_any_work(capsys, monkeypatch, case):
    from carl_sumo.cli import main

    for target in LONG_WORK:
        monkeypatch.setattr(target, _must_not_run)
    argv = BAD_OUTPUTS[case]
    assert main(argv) == 2
    err = capsys.readouterr().err
    option = case.split()[-1]
    assert err.count("\n") == 1 and err.startswith("carl-sumo: error: cannot write " + option)
    assert "/proc/" in err and "give a path in a folder you can write to" in err


def test_a_folder_for_a_file_and_a_file_for_a_folder_are_refused(capsys, tmp_path):
    from carl_sumo.cli import main

    assert main(["simulate", "--json", str(tmp_path)]) == 2
    assert "is a folder; give the path of a file" in capsys.readouterr().err
    (tmp_path / "f").write_text("")
    assert main(["evaluate", "--quick", "--out", str(tmp_path / "f")]) == 2
    assert "is a file; give a folder" in capsys.readouterr().err


def test_the_check_leaves_nothing_behind(tmp_path):
    assert check_output_file(tmp_path / "a" / "b" / "c.json", "--json") == tmp_path / "a/b/c.json"
    assert check_output_dir(tmp_path / "d" / "e", "--out") == tmp_path / "d" / "e"
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="cannot create the folder /proc/nope"):
        check_output_dir("/proc/nope/deeper", "--out")


def test_the_command_itself_exits_2_on_an_unwritable_json(tmp_path):
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "carl_sumo", "simulate", "--json",
                             "/proc/x/y.json"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and "cannot write --json /proc/x/y.json" in result.stderr


def _writes_outside_the_writer(path: Path) -> list[str]:
    """Calls in ``path`` that write or move a file into place without :mod:`carl_sumo.files`."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
        owner = getattr(func.value, "id", "") if isinstance(func, ast.Attribute) else ""
        mode = next((a.value for a in node.args[1:2] if isinstance(a, ast.Constant)), None)
        mode = next((k.value.value for k in node.keywords if k.arg == "mode"
                     and isinstance(k.value, ast.Constant)), mode)
        if (name in ("write_text", "write_bytes", "atomic_output")
                or (owner == "os" and name in ("replace", "rename"))
                or (name == "open" and isinstance(mode, str) and set(mode) & set("wax"))):
            found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {name}")
    return found


def test_no_module_writes_or_moves_a_file_into_place_by_itself():
    """Every output goes through carl_sumo.files (temporary file, fsync, special files refused,
    OS errors one line); only a study run moves its finished folder of SUMO outputs itself."""
    found = [hit.split(":")[0] for path in sorted(PACKAGE.rglob("*.py"))
             if path.name != "files.py" for hit in _writes_outside_the_writer(path)]
    assert found == ["carl_sumo/study/run.py"], found  # its one os.replace: a run's folder
