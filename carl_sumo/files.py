"""Output files: what carl-sumo writes is written whole or not at all, where it can be written.

Every writer of the package (tables, figures, policies, checkpoints, learning curves, FCD output,
networks, routes, results) writes to a temporary file beside its target (``.NAME.PID.tmp``) and
moves it into place with ``os.replace`` after an ``fsync``, so a reader never sees a half-written
file and an interrupted run leaves the previous file as it was:

- :func:`atomic_write`: ``with atomic_write(path, "wb") as f:`` a file object to write to;
- :func:`atomic_path`: ``with atomic_path(path) as tmp:`` the temporary path, for writers that
  take a path (``torch.save``, SUMO's own outputs, ``netconvert``); ``verify(tmp)`` (e.g.
  :func:`check_xml`) runs on the finished file before it moves into place;
- :func:`write_text_atomic`: a text file written that way.

Each of them refuses a target that is neither a regular file nor absent (a device, a pipe, a
socket: ``--json /dev/null`` leaves /dev/null alone), and turns an OS error while writing (a full
disk, a read-only or failing file system) into :class:`~carl_sumo.errors.OutputError` (one line,
exit status 2) after removing its temporary file. An exception or a signal in the block (the CLI
turns SIGTERM and SIGHUP into one) removes the temporary file too.

The command line checks every output path it is given before any long work starts:

- :func:`check_output_file` (``--json``, ``--fcd``, ``train --out``, ...) and
  :func:`check_output_dir` (``evaluate --out``, ``study --out``) raise
  :class:`~carl_sumo.errors.InputError`, one line and exit status 2, when the path is empty, a
  folder where a file is wanted (or a file where a folder is wanted), a device or other special
  file, or when its folder can neither be created nor written; the check leaves nothing behind.
"""

from __future__ import annotations

import errno
import os
import stat
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Callable, Iterator

from carl_sumo.errors import InputError, OutputError

FIX = "give a path in a folder you can write to"
"""What the message of an unwritable output path tells the user to do."""

TEMP_SUFFIX = ".tmp"
"""How the name of every temporary output file ends (``.NAME.PID.tmp``)."""


def atomic_output(path: Path, suffix: str = "") -> Path:
    """The temporary path beside ``path`` that :func:`atomic_path` writes to (its folder is
    created); ``suffix`` after it for writers that read the format from the name. Temporary
    files of the same target left by a process that no longer runs (killed with SIGKILL, which
    no handler sees) are removed first."""
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(path, suffix)
    return path.with_name(f".{path.name}.{os.getpid()}{TEMP_SUFFIX}{suffix}")


def _remove_stale(path: Path, suffix: str) -> None:
    """Remove ``.NAME.PID.tmp`` files beside ``path`` whose process PID is gone."""
    prefix, end = f".{path.name}.", f"{TEMP_SUFFIX}{suffix}"
    for tmp in path.parent.glob(f"{prefix}*{end}"):
        pid_text = tmp.name[len(prefix):len(tmp.name) - len(end)]
        if not pid_text.isdigit() or int(pid_text) == os.getpid():
            continue
        try:
            os.kill(int(pid_text), 0)
        except ProcessLookupError:
            _remove(tmp)
        except OSError:  # it runs under another user: not ours to remove
            pass


def check_target(path: str | Path, option: str = "") -> None:
    """InputError unless ``path`` is absent or a regular file (a symbolic link counts as what it
    points to): a device, pipe or socket is never replaced by an output file."""
    what = f"{option} {path}" if option else str(path)
    try:
        mode = os.stat(path).st_mode
    except OSError:  # absent, or a dangling link: os.replace puts a file there
        return
    if stat.S_ISDIR(mode):
        raise InputError(f"{what} is a folder; give the path of a file")
    if not stat.S_ISREG(mode):
        raise InputError(f"{what} is a device, pipe or socket, not a regular file; carl-sumo "
                         "writes its outputs as files and never replaces one of those: give the "
                         "path of a file")


def output_error(exc: OSError, path: Path) -> OutputError:
    """The one-line error of an OS error while ``path`` was being written."""
    reason = exc.strerror or type(exc).__name__
    code = errno.errorcode.get(exc.errno or 0)
    hint = ("free some space" if exc.errno in (errno.ENOSPC, errno.EDQUOT)
            else "write to another folder")
    return OutputError(f"cannot write {path}: {reason}{f' ({code})' if code else ''}; nothing "
                       f"was written and any previous {path.name} is as it was: {hint} and run "
                       "the command again")


def _fsync_path(path: Path, directory: bool = False) -> None:
    """Flush a file's (or a folder's entries') data to the disk; a folder that cannot be opened
    or synced (some file systems) is left to the kernel."""
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except OSError:
        if directory:
            return
        raise
    try:
        os.fsync(fd)
    except OSError as exc:
        if not directory or exc.errno not in (errno.EINVAL, errno.EBADF, errno.EROFS):
            raise
    finally:
        os.close(fd)


def _remove(tmp: Path) -> None:
    try:
        tmp.unlink(missing_ok=True)
    except OSError:  # a failing file system: nothing more can be done here
        pass


@contextmanager
def atomic_path(path: str | Path, verify: Callable[[Path], None] | None = None,
                suffix: str = "") -> Iterator[Path]:
    """The temporary path to write ``path`` at (ending in ``suffix`` where the writer reads the
    format from the name); when the block ends without an error (and ``verify(tmp)`` raises
    none) it is synced and moved into place, else removed. OSError while writing:
    :class:`OutputError`; a target that is not a regular file: InputError."""
    path = Path(path)
    check_target(path)
    try:
        tmp = atomic_output(path, suffix)
    except OSError as exc:
        raise output_error(exc, path) from None
    try:
        yield tmp
        if verify is not None:
            verify(tmp)
        _fsync_path(tmp)
        check_target(path)  # nothing special appeared there while the file was written
        os.replace(tmp, path)
        _fsync_path(path.parent, directory=True)
    except OSError as exc:
        raise output_error(exc, path) from None
    finally:
        _remove(tmp)


@contextmanager
def atomic_write(path: str | Path, mode: str = "w", **open_kw) -> Iterator[IO]:
    """``open(path, mode)`` written whole or not at all (see :func:`atomic_path`)."""
    if not mode.startswith("w"):
        raise ValueError(f"atomic_write writes a new file; mode {mode!r} is not one of w, wb")
    with atomic_path(path) as tmp:
        with open(tmp, mode, **open_kw) as f:
            yield f


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file: never a half-written file."""
    path = Path(path)
    with atomic_write(path, "w") as f:
        f.write(text)
    return path


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file: never a half-written file."""
    path = Path(path)
    with atomic_write(path, "wb") as f:
        f.write(data)
    return path


def check_xml(tmp: Path, what: str = "SUMO's output") -> None:
    """OutputError unless ``tmp`` (plain or gzip) is one complete XML document: an output that
    SUMO or netconvert could not finish (a full disk) never moves into place."""
    import gzip
    from xml.etree.ElementTree import ParseError, iterparse

    try:
        with open(tmp, "rb") as raw:
            gzipped = raw.read(2) == b"\x1f\x8b"
        with (gzip.open(tmp, "rb") if gzipped else open(tmp, "rb")) as f:
            for _, element in iterparse(f, events=("end",)):
                element.clear()
    except (ParseError, EOFError, gzip.BadGzipFile) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise OutputError(f"{what} is incomplete or not XML ({reason}; was the disk full?); "
                          "nothing was moved into place: free some space or write to another "
                          "folder and run the command again") from None


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


def _not_empty(path: str | Path, option: str) -> None:
    if isinstance(path, str) and not path.strip():
        raise InputError(f"{option} is an empty path; give the path to write to (an empty path "
                         "never means the current folder)")


def check_output_file(path: str | Path, option: str) -> Path:
    """``path`` as a Path, or InputError when ``option`` (e.g. ``--json``) cannot be written
    there: the path is empty, a folder or a special file (a device, pipe or socket) stands at
    ``path``, or its folder cannot be created or written."""
    _not_empty(path, option)
    path = Path(path)
    check_target(path, option)
    reason = _unwritable(path.parent)
    if reason:
        raise InputError(f"cannot write {option} {path}: {reason}; {FIX}")
    return path


OUTPUT_SUFFIXES = (".csv", ".md", ".png", ".json", ".txt", ".xml")
"""The kinds of file the commands write into an output folder."""


def check_output_names(path: str | Path, option: str) -> Path:
    """:func:`check_output_dir`, and InputError when the folder already holds a folder (or a
    special file) under a name of the kind the commands write there (``README.md``,
    ``study.csv`` ...): found before the work starts, not after it."""
    path = check_output_dir(path, option)
    if path.is_dir():
        for entry in sorted(path.iterdir()):
            if entry.suffix in OUTPUT_SUFFIXES and not (entry.is_file() and not entry.is_symlink()
                                                        or not entry.exists()):
                kind = "a folder" if entry.is_dir() else "not a regular file"
                raise InputError(f"{option} {path}: {entry} is {kind} where a command writes a "
                                 "file; move it away or give another --out")
    return path


def check_output_dir(path: str | Path, option: str) -> Path:
    """``path`` as a Path, or InputError when ``option`` (e.g. ``--out``) cannot be a folder of
    outputs: the path is empty, a file stands at ``path``, or the folder cannot be created or
    written."""
    _not_empty(path, option)
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path} is a file; give a folder")
    reason = _unwritable(path)
    if reason:
        raise InputError(f"cannot write {option} {path}: {reason}; {FIX}")
    return path
