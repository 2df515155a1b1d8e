"""Progress of a long command: a tqdm bar on a terminal, otherwise one line on stderr every few
seconds (logs and CI show that the command is alive and how far it is), or nothing."""

from __future__ import annotations

import sys
import time
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")

LINE_EVERY_S = 30.0
"""Seconds between progress lines when stderr is not a terminal."""


def progress_mode() -> bool | float:
    """What a command shows: True (a bar) on a terminal, else a line every :data:`LINE_EVERY_S`."""
    return True if sys.stderr.isatty() else LINE_EVERY_S


class Tracker:
    """Counts done items of ``total``: ``progress`` True draws a tqdm bar, a positive number
    prints ``desc: k/total units (p %), elapsed, ETA`` to stderr every that many seconds (and at
    the end of a run that printed a line), False or 0 shows nothing."""

    def __init__(self, total: int, desc: str, unit: str = "task",
                 progress: bool | float = False) -> None:
        self.total, self.desc, self.unit, self.done = total, desc, unit, 0
        self.start = self.last = time.monotonic()
        self.every = None if progress is True or not progress else float(progress)
        self.bar, self.printed = None, False
        if progress is True:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit=unit, leave=False)

    def update(self, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)
            return
        now = time.monotonic()
        if self.every is None:
            return
        # a line every `every` seconds, and a last one at the end of a run that printed any
        # (a run shorter than `every` prints nothing: its result is the next line)
        if now - self.last >= self.every or (self.done >= self.total and self.printed):
            self.last, self.printed = now, True
            elapsed = now - self.start
            eta = elapsed / self.done * (self.total - self.done) if self.done else float("nan")
            print(f"{self.desc}: {self.done}/{self.total} {self.unit}s "
                  f"({100 * self.done / max(self.total, 1):.0f} %), {elapsed:.0f} s, "
                  f"ETA {eta:.0f} s", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def track(items: Iterable[T], total: int, desc: str, unit: str = "task",
          progress: bool | float = False) -> Iterator[T]:
    """``items``, with a :class:`Tracker` counting each one as it is taken."""
    tracker = Tracker(total, desc, unit, progress)
    try:
        for item in items:
            yield item
            tracker.update()
    finally:
        tracker.close()
