"""Where a training run reports: the learning-curve CSV beside the policy and its figure
(``runs/NAME.csv``, ``runs/NAME.png``), TensorBoard with ``--tensorboard DIR``, and progress on
stderr: a bar on a terminal, else one line every few seconds (ETA, steps/s, last validation)."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Sequence, TextIO

from carl_sumo.errors import InputError
from carl_sumo.files import atomic_path
from carl_sumo.learn.curve import LOG_COLUMNS, LearningCurve
from carl_sumo.learn.selection import MARGIN_KEYS

TB_HELP = "pip install -e \".[tb]\" (tensorboardX) or pip install tensorboard"


def _summary_writer_class():
    """TensorBoard's SummaryWriter (tensorboardX, else torch's with the tensorboard package);
    InputError naming the extra when neither is installed."""
    try:
        from tensorboardX import SummaryWriter
    except ImportError:
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            raise InputError(f"--tensorboard needs tensorboardX or tensorboard: {TB_HELP}"
                             ) from None
    return SummaryWriter


def tensorboard_writer(logdir: Path):
    """A TensorBoard SummaryWriter on ``logdir`` (see :func:`_summary_writer_class`)."""
    return _summary_writer_class()(str(logdir))


def check_tensorboard() -> None:
    """InputError now, before any training, when no TensorBoard writer can be made."""
    _summary_writer_class()


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    return f"{h}h{rest // 60:02d}m" if h else f"{rest // 60}m{rest % 60:02d}s"


class ProgressLines:
    """Progress without a terminal: one line to ``file`` at most every ``every_s`` seconds and
    one at the end: steps done, steps/s, ETA and the last validation."""

    def __init__(self, name: str, total: int, initial: int, every_s: float = 30.0,
                 file: TextIO | None = None, clock=time.monotonic):
        self.name, self.total, self.every_s = name, total, every_s
        self.done = self.start = initial
        self.file = file if file is not None else sys.stderr
        self.clock = clock
        self.t0 = self.last = clock()
        self.summary = ""

    def line(self) -> str:
        """The progress line as it is now."""
        elapsed = self.clock() - self.t0
        rate = (self.done - self.start) / elapsed if elapsed > 0 else math.nan
        eta = (self.total - self.done) / rate if rate > 0 else math.nan
        return (f"{self.name}: step {self.done}/{self.total} "
                f"({100.0 * self.done / max(self.total, 1):.0f} %), {rate:.1f} steps/s, "
                f"ETA {_duration(eta)}" + (f"; last validation: {self.summary}"
                                           if self.summary else ""))

    def update(self, n: int = 1) -> None:
        self.done += n
        now = self.clock()
        if now - self.last >= self.every_s:
            self.last = now
            print(self.line(), file=self.file, flush=True)

    def set_postfix(self, **values) -> None:
        self.summary = ", ".join(f"{k}={v}" for k, v in values.items())

    def close(self) -> None:
        print(self.line(), file=self.file, flush=True)


def plot_curve(rows: Sequence[Sequence[str]], png: Path, title: str) -> Path:
    """The learning curve as a figure (matplotlib, written atomically): rewards, jerk, dampening
    and headway against the training step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def column(name: str) -> list[float]:
        i = LOG_COLUMNS.index(name)
        return [float(r[i]) if r[i] not in ("", "nan") else math.nan for r in rows]

    steps = column("step")
    fig, axes = plt.subplots(2, 2, figsize=(9, 5.5), sharex=True, constrained_layout=True)
    panels = (("reward", ("train_reward", "val_reward")), ("jerk (m/s³)", ("jerk_mps3",)),
              ("dampening ratio", ("dampening_ratio",)), ("headway (s)", ("headway_s",)))
    for ax, (label, names) in zip(axes.flat, panels):
        for name in names:
            ax.plot(steps, column(name), marker="o", ms=3, label=name.replace("_", " "))
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if len(names) > 1:
            ax.legend(fontsize=8)
    for ax in axes[1]:
        ax.set_xlabel("training step")
    fig.suptitle(title, fontsize=10)
    try:
        with atomic_path(png) as tmp:
            fig.savefig(tmp, format="png", dpi=90)
    finally:
        plt.close(fig)
    return png


class Report:
    """The reports of one run (see the module docstring) from ``start_step`` (a run resumed from
    the checkpoint ``resume`` continues its curve). ``progress``: True a bar, a number N
    a line every N seconds, False nothing; ``tensorboard``: the log folder (None: no
    TensorBoard)."""

    def __init__(self, cfg, out: Path, resume: Path | None, start_step: int,
                 progress: bool | float, tensorboard: Path | None = None):
        self.curve = LearningCurve(out.with_suffix(".csv"),
                                   start_step if resume is not None else None)
        self.png, self.title = out.with_suffix(".png"), f"{cfg.algo}: {out.name}"
        self.board = tensorboard_writer(tensorboard) if tensorboard is not None else None
        self.num_envs = cfg.num_envs  # transitions: decisions (0.1 s steps, or held gh s)
        self.losses: dict[str, list[float]] = {}
        self.bar = None
        if not isinstance(progress, bool):
            self.bar = ProgressLines(cfg.algo, cfg.steps, start_step, float(progress))
        elif progress:
            from tqdm import tqdm

            self.bar = tqdm(total=cfg.steps, initial=start_step, desc=cfg.algo, unit="step",
                            file=sys.stderr, dynamic_ncols=True)

    def validation(self, done_steps: int, wall_s: float, train_reward: float,
                   val: dict[str, float]) -> None:
        """One row of the learning curve and its figure, its TensorBoard scalars and the
        progress summary."""
        self.curve.append([done_steps, done_steps * self.num_envs, f"{wall_s:.1f}",
                           f"{train_reward:.4f}", f"{val['val_reward']:.4f}",
                           *(f"{val[k]:.4f}" for k in ("headway_s", "jerk_mps3", "speed_mps",
                                                        "dampening_ratio")),
                           val["collisions"],
                           *(f"{val[name]:.3f}" for name, _ in MARGIN_KEYS.values()),
                           val.get("ttc_lt_1_5s_count", ""),
                           f"{val['lagrange']:.4f}" if "lagrange" in val else "",
                           *(f"{val[k]:.4f}" if k in val else ""
                             for k in ("score", "critic_td", "critic_rank", "worst_hinf",
                                       "kappa", "raw_score"))])
        plot_curve(self.curve.rows, self.png, self.title)
        if self.board is not None:
            for key, value in val.items():
                self.board.add_scalar(f"validation/{key}", value, done_steps)
            self.board.add_scalar("train/reward", train_reward, done_steps)
            self.board.flush()
        if self.bar is not None:
            self.bar.set_postfix(reward=f"{train_reward:.3f}", val=f"{val['val_reward']:.3f}",
                                 jerk=f"{val['jerk_mps3']:.3f}", coll=val["collisions"],
                                 min_z=f"{min(val[k] for k, _ in MARGIN_KEYS.values()):.2f}")

    def updated(self, step: int, stats: dict[str, float] | None, every: int = 100) -> None:
        """The statistics of a gradient update (critic_loss, actor_loss, q_mean); their means
        go to TensorBoard every ``every`` steps."""
        if self.board is None:
            return
        for key, value in (stats or {}).items():
            self.losses.setdefault(key, []).append(value)
        if (step + 1) % every == 0 and self.losses:
            for key, values in self.losses.items():
                self.board.add_scalar(f"train/{key}", sum(values) / len(values), step + 1)
            self.losses = {}

    def flush(self) -> None:
        """The curve is on disk already (written whole with every row)."""
        if self.board is not None:
            self.board.flush()

    def advance(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.board is not None:
            self.board.close()
        if self.bar is not None:
            self.bar.close()
