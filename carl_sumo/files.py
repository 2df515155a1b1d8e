"""Output files: what carl-sumo writes is written whole or not at all.

Every writer of the package (tables, figures, policies, FCD output, networks, routes, results)
writes to a temporary file beside its target and then moves it into place with ``os.replace``, so
a reader never sees a half-written file and an interrupted run leaves the previous file as it was:

- :func:`atomic_output`: the temporary path to write to (its folder is created);
- :func:`write_text_atomic`: a text file written that way.
"""

from __future__ import annotations

import os
from pathlib import Path


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
