"""Output files: what carl-sumo writes is written whole or not at all, where it can be written.

Every writer of the package (tables, figures, policies, FCD output, networks, routes, results)
writes to a temporary file beside its target and then moves it into place with ``os.replace``, so
a reader never sees a half-written file and an interrupted run leaves the previous file as it was:

- :func:`atomic_output`: the temporary path to write to (its folder is created);
- :func:`write_text_atomic`: a text file written that way.

The command line checks every output path it is given before any long work starts:

- :func:`check_output_file` (``--json``, ``--fcd``, ``train --out``, ...) and
  :func:`check_output_dir` (``evaluate --out``, ``study --out``) raise
  :class:`~carl_sumo.errors.InputError`, one line and exit status 2, when the path is a folder
  where a file is wanted (or a file where a folder is wanted), or when its folder can neither be
  created nor written; the check leaves nothing behind.
"""

from __future__ import annotations

import os
from pathlib import Path

from carl_sumo.errors import InputError

FIX = "give a path in a folder you can write to"
"""What the message of an unwritable output path tells the user to do."""


def atomic_output(path: Path) -> Path:
    """A temporary path beside ``path`` to write to before ``os.replace`` moves it in place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_text_atomic(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file: never a half-written file."""
    path = Path(path)
    tmp = atomic_output(path)
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _unwritable(folder: Path) -> str | None:
    """Why no file can be written in ``folder`` (None if one can): the missing folders are made,
    a probe file written and removed, and the folders made here removed again."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    try:
        for d in reversed(missing):
            try:
                d.mkdir()
            except OSError as exc:
                return f"cannot create the folder {d} ({exc.strerror or type(exc).__name__})"
        where = missing[0] if missing else folder
        probe = where / f".carl-sumo.{os.getpid()}.probe"
        try:
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            return f"cannot write in {where} ({exc.strerror or type(exc).__name__})"
    finally:
        for d in missing:  # deepest first; only empty folders go
            try:
                d.rmdir()
            except OSError:
                pass
    return None


def check_output_file(path: str | Path, option: str) -> Path:
    """``path`` as a Path, or InputError when ``option`` (e.g. ``--json``) cannot be written
    there: a folder stands at ``path``, or its folder cannot be created or written."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path} is a folder; give the path of a file")
    reason = _unwritable(path.parent)
    if reason:
        raise InputError(f"cannot write {option} {path}: {reason}; {FIX}")
    return path


def check_output_dir(path: str | Path, option: str) -> Path:
    """``path`` as a Path, or InputError when ``option`` (e.g. ``--out``) cannot be a folder of
    outputs: a file stands at ``path``, or the folder cannot be created or written."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path} is a file; give a folder")
    reason = _unwritable(path)
    if reason:
        raise InputError(f"cannot write {option} {path}: {reason}; {FIX}")
    return path
