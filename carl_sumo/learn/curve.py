"""The learning curve of a training run: a CSV beside the policy (``runs/NAME.csv``), one row per
validation, written whole at every row (:func:`carl_sumo.files.write_text_atomic`), so a full
disk or a killed run never leaves a truncated curve. A resumed run keeps the rows up to its
checkpoint's step and drops those a killed run wrote after it, so every step appears once."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Sequence

from carl_sumo.files import write_text_atomic
from carl_sumo.learn.selection import MARGIN_KEYS

LOG_COLUMNS = ["step", "transitions", "wall_s", "train_reward", "val_reward", "headway_s",
               "jerk_mps3", "speed_mps", "dampening_ratio", "collisions",
               *(name for name, _ in MARGIN_KEYS.values()), "ttc_lt_1_5s_count", "lagrange",
               "score", "critic_td", "critic_rank", "worst_hinf", "kappa", "raw_score"]
"""Columns of the learning-curve CSV written beside the policy: ``score`` is the validation's
selection score (``--select``; the run keeps the best-scoring checkpoint), ``critic_td`` and
``critic_rank`` the critic's criterion on the held-out transitions (``--critic-holdout``;
:mod:`carl_sumo.learn.calibration`; empty without), ``worst_hinf`` the checkpoint's ‖Γ‖∞ as
``--trust-string-stable`` measured it (empty without); ``kappa`` and ``raw_score``: a
``--trust-backtrack`` step, the fraction of the actor's step kept at the string-stable point
the row validates, and the score of the amplifying actor before it (empty otherwise)."""


def _csv_text(rows: Sequence[Sequence]) -> str:
    out = io.StringIO()
    csv.writer(out).writerows(rows)
    return out.getvalue()


def read_rows(path: Path) -> list[list[str]]:
    """The rows of a learning curve (header excluded) in the current columns: a curve of an
    older carl-sumo (fewer columns) gets its missing values empty."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    width = len(LOG_COLUMNS)
    return [r + [""] * (width - len(r)) for r in rows[1:] if r]


def upgrade_log(path: Path) -> None:
    """Give a learning curve written by an older carl-sumo (fewer columns) the current header,
    its missing values empty, so that a resumed run can append to it."""
    with open(path, newline="") as f:
        header = next(csv.reader(f), None)
    if header is None or header == LOG_COLUMNS:
        return
    write_text_atomic(path, _csv_text([LOG_COLUMNS] + read_rows(path)))


class LearningCurve:
    """The rows of a run's learning curve, the whole file written again with every row.

    ``resumed_at``: the step of the checkpoint a resumed run starts from; the rows of the curve
    already at ``path`` up to that step are kept, later ones (a killed run validated after its
    last checkpoint) are dropped. None: a new run, a new curve."""

    def __init__(self, path: Path, resumed_at: int | None = None):
        self.path = Path(path)
        self.rows: list[list[str]] = []
        if resumed_at is not None and self.path.exists():
            self.rows = [r for r in read_rows(self.path) if _step(r) <= resumed_at]
        self._write()  # an unwritable curve stops the run now, not after its first validation

    def append(self, row: Sequence) -> None:
        """Add one row (values in :data:`LOG_COLUMNS` order) and write the curve."""
        self.rows.append([str(v) for v in row])
        self._write()

    def _write(self) -> None:
        write_text_atomic(self.path, _csv_text([LOG_COLUMNS] + self.rows))


def _step(row: Sequence[str]) -> float:
    try:
        return float(row[0])
    except (ValueError, IndexError):
        return float("inf")  # an unreadable row is not kept
