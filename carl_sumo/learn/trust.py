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
an acceptance test, as a line search accepts a step).

``--trust-backtrack K`` (issue 55): an amplifying actor is not sent straight back. It moves back
along the line in weight space to its anchor, halving its step up to K times (w_anchor +
2^-k·(w - w_anchor), TRPO's backtracking line search with ‖Γ‖∞ ≤ 1 as its acceptance test), and
stays at the first string-stable point, validated there (accepted as the anchor if it then
scores best; α unchanged: the step was shortened, not refused). Only when no point of the K is
string stable does it go back to the anchor, as above. ``check`` (a policy file's worst ‖Γ‖∞) is
given by the command line (:func:`carl_sumo.experiments.string_stability.worst_hinf`, the
gate's frequencies and amplitudes): this layer does not run the experiment itself.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

SHRINK = 0.5
"""α's factor after each rejected checkpoint (the anchor's pull doubles relative to Q)."""


class StableTrust:
    """The trust region of the module docstring; ``check(policy file) -> worst ‖Γ‖∞``."""

    def __init__(self, check: Callable[[Path], float], shrink: float = SHRINK,
                 backtrack: int = 0):
        self.check = check
        self.shrink = shrink
        self.backtrack = backtrack
        self.rejected = 0
        self.accepted: list[int] = []  # the steps accepted as anchors
        self.shortened: list[int] = []  # the steps whose actor backtracking moved

    def judge(self, agent, candidate: Path, step: int, best_score: bool,
              rewrite: Callable[[], Path] | None = None) -> tuple[float, float, float]:
        """Check the actor just validated (written to ``candidate``) and act on the outcome:
        (its worst ‖Γ‖∞, κ, the ‖Γ‖∞ where it stays). κ = 1: it stays where it was; 0: it went
        back to its anchor; 2^-k: the backtracking of ``backtrack`` moved it to a string-stable
        point (each point written by ``rewrite()``, which returns its file), which the caller
        validates and then accepts (:meth:`accept`) if it scores best. ``best_score``: the
        actor as validated scores better than every earlier checkpoint."""
        hinf = float(self.check(candidate))
        if hinf <= 1.0:
            if best_score:
                self.accept(agent, step)
            return hinf, 1.0, hinf
        for k in range(1, self.backtrack + 1 if rewrite is not None else 1):
            agent.blend_toward_anchor(0.5)  # half of what is left of the step
            point = float(self.check(rewrite()))
            if point <= 1.0:
                self.shortened.append(step)
                return hinf, 0.5 ** k, point
        agent.revert_to_anchor()
        agent.bc_alpha *= self.shrink
        self.rejected += 1
        return hinf, 0.0, math.nan

    def accept(self, agent, step: int) -> None:
        """The actor as it is now becomes the anchor (a frozen copy; α unchanged)."""
        agent.anchor(agent.bc_alpha)
        self.accepted.append(step)

    def state(self) -> list[int]:
        """What a checkpoint keeps: [rejections, accepted steps...] (and :attr:`shortened`)."""
        return [self.rejected, *self.accepted]

    def restore(self, state: list[int], shortened: list[int] | None = None) -> None:
        self.rejected, self.accepted = int(state[0]), [int(s) for s in state[1:]]
        self.shortened = [int(s) for s in shortened or []]
