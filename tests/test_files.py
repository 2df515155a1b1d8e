"""carl_sumo.files: atomic writes, and the one place every writer takes them from."""

from __future__ import annotations

import ast
from pathlib import Path

import carl_sumo
from carl_sumo.files import atomic_output, write_text_atomic

PACKAGE = Path(carl_sumo.__file__).parent
HELPERS = {"atomic_output", "write_text_atomic"}


def test_write_text_atomic_creates_folders_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "a" / "b" / "out.txt"
    assert write_text_atomic(path, "one\n") == path
    write_text_atomic(path, "two\n")
    assert path.read_text() == "two\n"
    assert sorted(p.name for p in path.parent.iterdir()) == ["out.txt"]
    tmp = atomic_output(path)
    assert tmp.parent == path.parent and tmp.name.startswith(".out.txt.") and not tmp.exists()


def test_every_writer_imports_the_file_helpers_from_files():
    import carl_sumo.sumo as sumo

    assert not HELPERS & set(vars(sumo)), "sumo.py still holds file helpers"
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name in HELPERS:
                assert path.name == "files.py", f"{path} defines {node.name}"
            if isinstance(node, ast.ImportFrom) and HELPERS & {a.name for a in node.names}:
                assert node.module == "carl_sumo.files", \
                    f"{path}:{node.lineno} imports a file helper from {node.module}"
