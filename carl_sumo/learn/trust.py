"""String stability where the actor moves: a trust region that a measured ‖Γ‖∞ steers.

``train --gate-string-stable PLANT`` alone checks the validated checkpoints after training and
keeps the best string-stable one; the actor meanwhile drifts wherever the critic leads it, and
on the real plant every checkpoint that beats its start by 5 % or more amplified (docs/
training.md, issue 55 step 2). With ``--trust-string-stable`` the same check runs on each
checkpoint as it is validated, and its outcome acts on the actor:

- ‖Γ‖∞ > 1 (it amplifies at some frequency, amplitude or vehicle class; a collision counts as
  inf): the actor, its target and its optimiser's moments go back to the **anchor** (the last
  accepted actor: the start, or the last accepted checkpoint), and the behaviour regulariser
  tightens: α ← α·``SHRINK`` (TD3+BC's actor loss -α·Q/mean|Q| + ((a - a_anchor)/adj_max)²);
- ‖Γ‖∞ ≤ 1 and the best validation score so far: **accepted**, the anchor moves to it (the
  regulariser now holds the actor near this checkpoint, not near the start);
- otherwise the actor goes on from where it is.

So the actor explores a neighbourhood of the last string-stable improvement, and the
neighbourhood shrinks each time it leaves the string-stable set (an adaptive trust region with
an acceptance test, as a line search accepts a step). ``check`` (a policy file's worst ‖Γ‖∞) is
given by the command line (:func:`carl_sumo.experiments.string_stability.worst_hinf`, the
gate's frequencies and amplitudes): this layer does not run the experiment itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

SHRINK = 0.5
"""α's factor after each rejected checkpoint (the anchor's pull doubles relative to Q)."""


class StableTrust:
    """The trust region of the module docstring; ``check(policy file) -> worst ‖Γ‖∞``."""

    def __init__(self, check: Callable[[Path], float], shrink: float = SHRINK):
        self.check = check
        self.shrink = shrink
        self.rejected = 0
        self.accepted: list[int] = []  # the steps accepted as anchors

    def judge(self, agent, candidate: Path, step: int, best_score: bool) -> float:
        """Check the actor just validated (written to ``candidate``) and act on the outcome;
        its worst ‖Γ‖∞. ``best_score``: it scores better than every earlier checkpoint."""
        hinf = float(self.check(candidate))
        if hinf > 1.0:
            agent.revert_to_anchor()
            agent.bc_alpha *= self.shrink
            self.rejected += 1
        elif best_score:
            agent.anchor(agent.bc_alpha)  # a frozen copy of the actor as it is now
            self.accepted.append(step)
        return hinf

    def state(self) -> list[int]:
        """What a checkpoint keeps: [rejections, accepted steps...]."""
        return [self.rejected, *self.accepted]

    def restore(self, state: list[int]) -> None:
        self.rejected, self.accepted = int(state[0]), [int(s) for s in state[1:]]
