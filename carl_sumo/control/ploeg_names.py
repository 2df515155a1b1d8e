"""The names of the constant-time-gap laws and their parameters: what ``ploeg:h=0.8:kp=0.1:kd=1``,
``ploeg-tuned:h=0.8``, ``acc:h=2.5``, the multi-predecessor ``mpf:r=2:w2=0.3`` and their options
(``aw``, ``ha``, ``ttc``, ``rb``, ``wo``, ``hf``, ``gs``, ``gn``, ``op``, ``ht``, ``gp``,
``gl``, ``gb``) stand for
(:class:`PloegParams`), and the tuned-gains files of ``carl-sumo tune``. The law itself, and what
each option does, is :mod:`carl_sumo.control.cacc`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from carl_sumo.errors import InputError
from carl_sumo.resources import policies_dir

TUNED_FILE = policies_dir() / "ploeg_tuned.json"
"""The tuned gains per time gap, written by ``carl-sumo tune ploeg``."""

HEAVY_BRAKING_MPS2 = 7.0
"""``ht=T``: a vehicle whose own largest braking is below this (m/s²; a truck's 6, a car's 9),
known with ``aw=1``, keeps at least the time gap T in its chain."""


def chain_gap_s(time_gap_s: float, heavy_gap_s: float | None, b_max_mps2: float | None) -> float:
    """The time gap (s) a vehicle that hears a message keeps: h, or for a heavy one (its largest
    braking ``b_max_mps2`` below :data:`HEAVY_BRAKING_MPS2`; None: not known) max(h, ht) where
    ``ht`` is set. The one rule the CACC kernel (inline, compiled), the MPC and the theory use."""
    if heavy_gap_s is not None and b_max_mps2 is not None and b_max_mps2 < HEAVY_BRAKING_MPS2:
        return max(time_gap_s, heavy_gap_s)
    return time_gap_s


GAP_PER_ADJ_S = 1.0
"""``gp=T``: the time gap (s) a learned term of 1 m/s² asks for on top of a vehicle's own (the
actor's range ±adj_max m/s² is a gap offset of ±adj_max s)."""


def gap_offset_step(offset, target, time_constant_s: float, dt_s: float):
    """``gp=T``: each vehicle's time-gap offset (s) one step of ``dt_s`` later, low-passed towards
    ``target`` (s) with the time constant ``time_constant_s``."""
    return offset + (dt_s / time_constant_s) * (target - offset)


def budgeted_offsets(target, least):
    """``gb=1``: the gap offsets (s) nearest to ``target`` (one shift c for all: max(t_i - c,
    lo_i)) that keep the platoon's headway budget, Σ offsets = 0, each at least its
    ``least`` lo_i (s, ≤ 0: its class's least gap less its own). Exact: the sum is piecewise
    linear in c with breakpoints t_i - lo_i; with the k largest breakpoints above c it is zero at
    c = (Σ_k t + Σ_rest lo)/k, the first k whose c lies in its own interval (none: Σ lo = 0, and
    every offset is its floor)."""
    target, least = np.asarray(target, dtype=np.float64), np.asarray(least, dtype=np.float64)
    if target.size == 0:
        return target.copy()
    order = np.argsort(least - target)  # breakpoints t_i - lo_i, largest first
    t, lo = target[order], least[order]
    brk = t - lo
    k = np.arange(1, t.size + 1)
    lo_rest = lo.sum() - np.cumsum(lo)
    c = (np.cumsum(t) + lo_rest) / k
    below = np.append(brk[1:], -np.inf)  # the next breakpoint: c must lie in [below, brk)
    valid = (c < brk) & (c >= below)
    if not valid.any():
        return least.copy()
    return np.maximum(target - c[int(np.argmax(valid))], least)


@dataclass(frozen=True)
class PloegParams:
    """Gains of the Ploeg CACC (units in the names)."""

    time_gap_s: float = 1.0     # h: desired time gap (s)
    kp: float = 0.2             # spacing-error gain (1/s²)
    kd: float = 0.7             # spacing-error-rate gain (1/s)
    standstill_gap_m: float = 2.0  # s0 (m)
    feed_forward: bool = True   # the predecessor's V2V state (CACC), or none (ACC, radar only)
    anti_windup: bool = False   # aw=1: each state stays within its own vehicle's limits
                                # (PloegController.know_vehicles), so messages are realisable
    alone_gap_s: float | None = None  # ha: time gap (s) of a CACC vehicle that hears no V2V
                                # message (the head behind a human, a follower behind a cut-in
                                # human): degraded to an ACC at a longer gap (None: h)
    alone_kp: float | None = None  # pa: the spacing-error gain kp of a vehicle that hears no
                                # message (the ACC at ha: a chain's head behind a human; 1/s²;
                                # None: kp)
    alone_kd: float | None = None  # da: its spacing-error-rate gain kd (1/s; None: kd): a head
                                # with a long ha and a small da lets its gap breathe and passes
                                # on less of the leader's motion
    lead_weight: float | None = None  # fa: the weight (at most 1) of the leader's measured
                                # acceleration, the head's feed-forward (None: 1); below 1 the
                                # head leaves more of the leader's motion to its spacing terms
    lost_weight: float | None = None  # df (with rb=1): a follower whose predecessor's message is
                                # lost feeds forward this share (at most 1) of the acceleration
                                # ahead as its radar measures it, as the head does the leader's
                                # (a degraded CACC), fading in as the held message fades out
                                # (None: no feed-forward, an ACC at ha)
    reaction_ttc_s: float | None = None  # ttc: below this time to collision (s) the state brakes
                                # at least as hard as closing in needs (None: no reaction layer)
    reaction_braking_ahead: bool = False  # rb=1: the reaction adds the braking of the vehicle
                                # ahead as the radar measures it (False: assumes it keeps its speed)
    washout_s: float | None = None  # wo: a learned term enters the law less its own running mean
                                # over this time constant (s), so it cannot move the steady gap
                                # (None: it enters as it is)
    head_free: bool = False     # hf=1 (with wo): a chain's head (no CACC vehicle ahead: behind a
                                # human) takes the learned term as it is, without the washout, so
                                # the learned term can move the head's gap (the followers' stays)
    safe_braking_mps2: float | None = None  # gs: a vehicle without a message keeps Gipps' safe
                                # speed for the vehicle ahead braking at this (m/s²; None: off)
    safe_new_only: bool = False  # gn (in place of gs): only a vehicle whose vehicle ahead is new
                                # (armed: behind a human who cut in, a joiner) until it has room
    heavy_gap_s: float | None = None  # ht: the time gap (s) of a heavy vehicle in its chain (its
                                # braking below 7 m/s², known with aw=1; None: h for every class)
    opening_braking_mps2: float | None = None  # op: an armed vehicle at the front of its chain
                                # opens its gap to 0.8 s braking at up to this (m/s²; None: off)
    gap_policy_s: float | None = None  # gp: the learned term sets each vehicle's time gap (an
                                # offset of GAP_PER_ADJ_S s per m/s², low-passed with this time
                                # constant, s) instead of entering as an acceleration (None: off)
    gap_floor_s: float | None = None  # gl (with gp): the least time gap of a car in a chain (s;
                                # None: h); a heavy vehicle keeps at least ht, the head ha
    gap_budget: bool = False    # gb=1 (with gp): the offsets of a chain sum to 0 (a headway
                                # budget: RL moves gap between vehicles, never adds it)
    gap_hold_s: float | None = None  # gh (with gp): the learned gap target is chosen every gh s
                                # (from a run's first step) and held in between: a decision
                                # period, the step of a semi-MDP (None: every 0.1 s step)
    weights: tuple[float, ...] = (1.0,)  # mpf: w_1..w_r, the weights of the commands of the r
                                # vehicles ahead in the feed-forward (-; Ploeg: (1,); MPF_OPTIONS)

    @property
    def heard(self) -> int:
        """r: how many vehicles ahead the law hears (0: an ACC, 1: Ploeg's CACC, more: ``mpf``)."""
        return len(self.weights) if self.feed_forward else 0

    @property
    def multi(self) -> bool:
        """Whether the feed-forward is more than the predecessor's command (an ``mpf`` law)."""
        return self.feed_forward and self.weights != (1.0,)

    def name(self) -> str:
        """The controller name that runs these gains."""
        kind = "mpf" if self.multi else "ploeg" if self.feed_forward else "acc"
        return f"{kind}:h={self.time_gap_s:g}:kp={self.kp:g}:kd={self.kd:g}" + \
            (f":r={self.heard}" + "".join(f":w{j}={w:g}" for j, w in enumerate(self.weights, 1))
             if self.multi else "") + \
            (":aw=1" if self.anti_windup else "") + \
            (f":ha={self.alone_gap_s:g}" if self.alone_gap_s is not None else "") + \
            (f":pa={self.alone_kp:g}" if self.alone_kp is not None else "") + \
            (f":da={self.alone_kd:g}" if self.alone_kd is not None else "") + \
            (f":fa={self.lead_weight:g}" if self.lead_weight is not None else "") + \
            (f":df={self.lost_weight:g}" if self.lost_weight is not None else "") + \
            (f":ttc={self.reaction_ttc_s:g}" if self.reaction_ttc_s is not None else "") + \
            (":rb=1" if self.reaction_braking_ahead else "") + \
            (f":wo={self.washout_s:g}" if self.washout_s is not None else "") + \
            (":hf=1" if self.head_free else "") + \
            (f":{'gn' if self.safe_new_only else 'gs'}={self.safe_braking_mps2:g}"
             if self.safe_braking_mps2 is not None else "") + \
            (f":op={self.opening_braking_mps2:g}" if self.opening_braking_mps2 is not None else "") + \
            (f":ht={self.heavy_gap_s:g}" if self.heavy_gap_s is not None else "") + \
            (f":gp={self.gap_policy_s:g}" if self.gap_policy_s is not None else "") + \
            (f":gl={self.gap_floor_s:g}" if self.gap_floor_s is not None else "") + \
            (":gb=1" if self.gap_budget else "") + \
            (f":gh={self.gap_hold_s:g}" if self.gap_hold_s is not None else "")

    @property
    def gap_alone_s(self) -> float:
        """The time gap of a vehicle without a V2V predecessor (s): ``ha`` on a CACC, else h."""
        if self.feed_forward and self.alone_gap_s is not None:
            return self.alone_gap_s
        return self.time_gap_s

    def gap_hold_steps(self, dt_s: float = 0.1) -> int:
        """``gh``: the steps of ``dt_s`` between two choices of the learned gap (1: every step)."""
        return 1 if self.gap_hold_s is None else max(1, round(self.gap_hold_s / dt_s))

    def class_gaps(self, b_max_mps2) -> tuple[np.ndarray, np.ndarray]:
        """(own, least) time gaps (s) of a chain's vehicles, head first, whose largest braking
        is ``b_max_mps2`` (m/s², inf or nan: not known): the head's ``ha`` (its least too), a
        follower's :meth:`chain_gap_s`, least ``gl`` for a car and its own for a heavy vehicle
        (``gp``'s floors, as the kernel keeps them)."""
        b = [None if not np.isfinite(x) else float(x) for x in np.asarray(b_max_mps2, float)]
        own = np.array([self.gap_alone_s] + [self.chain_gap_s(x) for x in b[1:]])[:len(b)]
        least = np.where(own > self.time_gap_s, own, self.time_gap_s
                         if self.gap_floor_s is None else self.gap_floor_s)
        if len(b):
            least[0] = own[0]
        return own, least

    def chain_gap_s(self, b_max_mps2: float | None) -> float:
        """The time gap (s) of a follower that hears a message and brakes at most ``b_max_mps2``
        (:func:`chain_gap_s`; its braking is known to the law only with ``aw=1``)."""
        return chain_gap_s(self.time_gap_s, self.heavy_gap_s,
                           b_max_mps2 if self.anti_windup else None)


TEXTBOOK = PloegParams()


# ------------------------------------------------------------------------------------ names
def _parse_options(name: str, allowed: tuple[str, ...]) -> dict[str, float]:
    """``{key: value}`` of ``kind:key=value:...``; InputError naming what is wrong."""
    options: dict[str, float] = {}
    for part in name.split(":")[1:]:
        key, sep, text = part.partition("=")
        if not sep or key not in allowed:
            raise InputError(f"controller {name!r}: {part!r} is not an option; write "
                             f"{name.split(':')[0]}:" + ":".join(f"{k}=VALUE" for k in allowed))
        if key in options:
            raise InputError(f"controller {name!r}: {key} is given twice")
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"controller {name!r}: {key}={text!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"controller {name!r}: {key} must be a positive number, got {text}")
        options[key] = value
    return options


CLASSICAL_KINDS = ("ploeg", "ploeg-tuned", "acc", "acc-tuned", "mpf", "mpf-tuned")
"""The names of the constant-time-gap laws: Ploeg's CACC, the same law as a radar-only ACC, and
the multi-predecessor CACC (``mpf``; ``mpf-tuned``: its weights tuned for a plant by
``carl-sumo tune mpf``)."""


@dataclass(frozen=True)
class OptionSpec:
    """One option of a controller name: its key, type, unit, default, range and meaning."""

    key: str
    kind: type
    unit: str
    default: str
    low: float
    high: float
    doc: str

    def value(self, name: str, text: str) -> float:
        """The option's value in ``text``; InputError, one line, when it is not one."""
        try:
            value = self.kind(text) if self.kind is float else float(text)
        except ValueError:
            value = math.nan
        if self.kind is int and math.isfinite(value) and value != int(value):
            value = math.nan
        if not (math.isfinite(value) and self.low <= value <= self.high):
            bounds = f"from {self.low:g} to {self.high:g}" if math.isfinite(self.high) else \
                f"of at least {self.low:g}, finite"
            raise InputError(f"controller {name!r}: {self.key}={text} must be "
                             f"{'a whole number' if self.kind is int else 'a number'} {bounds} "
                             f"({self.doc})")
        return self.kind(value)


MAX_HEARD = 9
"""The most vehicles ahead an ``mpf`` law can hear (the platoon bounds it too: r ≤ n - 1)."""
MPF_OPTIONS = (
    OptionSpec("r", int, "vehicles", "2", 0, MAX_HEARD,
               "how many vehicles ahead it hears: 0 is the ACC, 1 Ploeg's CACC"),
    OptionSpec("wJ", float, "-", "what the weights given leave of 1, shared equally", 0.0,
               math.inf, "the weight of the command of the J-th vehicle ahead, J = 1..r, "
               "in the feed-forward"),
)
"""The options an ``mpf`` name adds to Ploeg's (:func:`parse_ploeg`; docs/string_stability.md)."""
MPF_DEFAULT_HEARD = 2


def _mpf_weights(name: str, parts: dict[str, str]) -> tuple[float, ...]:
    """(w_1, ..., w_r) of an ``mpf`` name's ``r`` and ``wJ`` options (:data:`MPF_OPTIONS`):
    the weights not given share equally what the given ones leave of 1; InputError (one line)
    for a weight beyond r, a bad value, or given weights above 1 with some left to share."""
    r_spec, w_spec = MPF_OPTIONS
    r = r_spec.value(name, parts.pop("r")) if "r" in parts else MPF_DEFAULT_HEARD
    given: dict[int, float] = {}
    for key in list(parts):
        j = int(key[1:])
        if not 1 <= j <= r:
            raise InputError(f"controller {name!r}: {key} is the weight of vehicle {j} ahead, "
                             f"but the law hears r = {r}; give w1..w{r}" if r else
                             f"controller {name!r}: {key}: the law with r = 0 hears no vehicle "
                             "ahead and has no weights")
        given[j] = replace(w_spec, key=key).value(name, parts.pop(key))
    missing = [j for j in range(1, r + 1) if j not in given]
    left = 1.0 - sum(given.values())
    if missing and left < 0:
        raise InputError(f"controller {name!r}: the weights given sum to {1 - left:g} > 1, so "
                         f"w{', w'.join(map(str, missing))} (the rest of 1) would be negative; "
                         "give every weight")
    return tuple(given.get(j, left / len(missing) if missing else 0.0) for j in range(1, r + 1))


def is_ploeg_name(name: str) -> bool:
    """Whether ``name`` is one of the constant-time-gap laws (CACC or ACC)."""
    return name.split(":")[0] in CLASSICAL_KINDS


def tuned_file_for(law: str, plant: str) -> Path:
    """Where ``carl-sumo tune`` writes the gains of a law for a plant: :data:`TUNED_FILE` for the
    Ploeg CACC on the ideal plant, else ``policies/<law>_tuned_<plant>.json``."""
    if law == "ploeg" and plant == "ideal":
        return TUNED_FILE
    slug = "".join(c if c.isalnum() or c == "." else "_" for c in plant).strip("_")
    return TUNED_FILE.with_name(f"{law}_tuned_{slug}.json")


def read_tuned_entries(path: Path | None = None) -> list[dict]:
    """Every tuned entry (``h``, ``kp``, ``kd``, ``law`` and ``plant``) of ``path``, or of every
    tuned-gains file beside :data:`TUNED_FILE` (one per law and plant)."""
    if path is None:
        paths = sorted(p for p in TUNED_FILE.parent.glob("*_tuned*.json")
                       if not p.name.endswith(".partial.json"))
        if TUNED_FILE not in paths:
            paths.insert(0, TUNED_FILE)
        return [e for p in paths for e in read_tuned_entries(p)]
    path = Path(path)
    if not path.is_file():
        raise InputError(f"no tuned Ploeg gains at {path}; run `carl-sumo tune ploeg` first")
    try:
        payload = json.loads(path.read_text())
        entries = [{"law": payload.get("controller", "ploeg"),
                    "plant": payload.get("plant", "ideal"), **e} for e in payload["entries"]]
        for e in entries:
            float(e["h"])
        return entries
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path} is not a tuned-gains file of `carl-sumo tune ploeg` "
                         f"({type(exc).__name__}); run the tuning again") from None


def read_tuned(path: Path | None = TUNED_FILE, law: str = "ploeg", plant: str | None = "ideal"
               ) -> dict[str, dict]:
    """The tuned entries of one law and plant (None: every plant), keyed by the time gap as
    written (``"0.8"``)."""
    return {f"{float(e['h']):g}": e for e in read_tuned_entries(path)
            if e.get("law", "ploeg") == law and plant in (None, e.get("plant", "ideal"))}


def _flag(name: str, opts: dict[str, float], key: str, what: str) -> bool:
    """Whether a name sets the switch ``key=1`` (aw, rb); InputError for another value."""
    if opts.get(key, 1.0) != 1.0:
        raise InputError(f"controller {name!r}: {key} takes 1 ({what}) or is left out")
    return key in opts


def _switches(name: str, opts: dict[str, float]) -> dict:
    """The options of a name beyond the gains (PloegParams' keywords)."""
    if "gs" in opts and "gn" in opts:
        raise InputError(f"controller {name!r}: give gs (every vehicle without a message) or gn "
                         "(only one with a new vehicle ahead), not both")
    head_free = _flag(name, opts, "hf", "the head takes the learned term without the washout")
    if head_free and "wo" not in opts:
        raise InputError(f"controller {name!r}: hf=1 frees the head from the washout wo; give "
                         "wo too (e.g. wo=5:hf=1)")
    if "gp" in opts and "wo" in opts:
        raise InputError(f"controller {name!r}: gp=T makes the learned term a time gap, which "
                         "the washout wo would undo; give one of them")
    for key in ("gl", "gb", "gh"):
        if key in opts and "gp" not in opts:
            raise InputError(f"controller {name!r}: {key} shapes the gaps the learned gap policy "
                             "gp sets; give gp too (e.g. gp=5:gl=0.5:gb=1)")
    if name.startswith("acc") and {"pa", "da", "fa", "df"} & set(opts):
        raise InputError(f"controller {name!r}: pa, da, fa and df set what a CACC vehicle does "
                         "without a message; an acc law has no V2V: give kp and kd")
    if opts.get("df", 0.0) > 1.0:
        raise InputError(f"controller {name!r}: df={opts['df']:g} weights the radar's "
                         "acceleration ahead in place of a lost message; give df in (0, 1]")
    if "df" in opts and "rb" not in opts:
        raise InputError(f"controller {name!r}: df feeds forward the acceleration ahead that "
                         "the radar measures for rb=1; give rb=1 too")
    if opts.get("fa", 0.0) > 1.0:
        raise InputError(f"controller {name!r}: fa={opts['fa']:g} weights the leader's "
                         "acceleration in the head's law; give fa in (0, 1]")
    if opts.get("gl", 0.0) > opts.get("h", TEXTBOOK.time_gap_s):
        raise InputError(f"controller {name!r}: gl={opts['gl']:g} is above the time gap h; "
                         "give gl at most h")
    return {"anti_windup": _flag(name, opts, "aw", "each vehicle's state within its own limits"),
            "alone_gap_s": opts.get("ha"), "alone_kp": opts.get("pa"),
            "alone_kd": opts.get("da"), "lead_weight": opts.get("fa"),
            "lost_weight": opts.get("df"),
            "reaction_ttc_s": opts.get("ttc"),
            "reaction_braking_ahead": _flag(name, opts, "rb", "the reaction counts the braking "
                                                              "of the vehicle ahead"),
            "washout_s": opts.get("wo"), "head_free": head_free,
            "safe_braking_mps2": opts.get("gs", opts.get("gn")),
            "safe_new_only": "gn" in opts, "opening_braking_mps2": opts.get("op"),
            "heavy_gap_s": opts.get("ht"), "gap_policy_s": opts.get("gp"),
            "gap_floor_s": opts.get("gl"),
            "gap_budget": _flag(name, opts, "gb", "the learned gap offsets sum to 0"),
            "gap_hold_s": opts.get("gh")}


def parse_ploeg(name: str, tuned_file: Path | None = None, plant: str = "ideal") -> PloegParams:
    """The gains a constant-time-gap law's name stands for (``ploeg*``: CACC, ``acc*``: ACC);
    a ``-tuned`` name reads the gains tuned for ``plant`` (:func:`plant_key`). InputError on a
    bad name or value, or on a plant the gains were not tuned for."""
    kind = name.split(":")[0]
    law = "acc" if kind.startswith("acc") else "ploeg"
    if kind == "mpf-tuned":
        return parse_ploeg(tuned_law(name, tuned_file, plant))
    if kind == "mpf":  # Ploeg's options, and r and the weights (MPF_OPTIONS)
        parts = [part.partition("=") for part in name.split(":")[1:]]
        mpf = {k: v for k, sep, v in parts if sep and (k == "r" or (k[:1] == "w" and
                                                                     k[1:].isdigit()))}
        if len(mpf) < sum(1 for k, sep, _ in parts if sep and k in mpf):
            raise InputError(f"controller {name!r}: an option is given twice")
        base = ":".join(["ploeg"] + [k + s + v for k, s, v in parts if k not in mpf])
        weights = _mpf_weights(name, dict(mpf))
        try:
            p = parse_ploeg(base)
        except InputError as exc:
            raise InputError(str(exc).replace(repr(base), repr(name)).replace(
                "write ploeg:", "write mpf:r=R:wJ=W:")) from None
        return replace(p, feed_forward=bool(weights), weights=weights or (1.0,))
    if kind in ("ploeg", "acc"):
        opts = _parse_options(name, ("h", "kp", "kd", "aw", "ha", "pa", "da", "fa", "df", "ttc", "rb", "wo", "hf", "gs",
                                      "gn", "op", "ht", "gp", "gl", "gb", "gh"))
        return PloegParams(opts.get("h", TEXTBOOK.time_gap_s), opts.get("kp", TEXTBOOK.kp),
                           opts.get("kd", TEXTBOOK.kd), feed_forward=law == "ploeg",
                           **_switches(name, opts))
    if kind in ("ploeg-tuned", "acc-tuned"):
        opts = _parse_options(name, ("h", "aw", "ha", "pa", "da", "fa", "df", "ttc", "rb", "wo", "hf", "gs", "gn",
                                      "op", "ht", "gp", "gl", "gb", "gh"))
        if "h" not in opts:
            raise InputError(f"controller {name!r}: name the time gap, e.g. {kind}:h=1")
        entries = [e for e in read_tuned_entries(tuned_file) if e.get("law", "ploeg") == law]
        for_plant = {f"{float(e['h']):g}": e for e in entries
                     if e.get("plant", "ideal") == plant}
        if not for_plant:
            plants = sorted({e.get("plant", "ideal") for e in entries})
            raise InputError(f"controller {name!r}: no gains tuned for the plant {plant!r} (tuned "
                             f"for: {'; '.join(plants) or 'none'}); run `carl-sumo tune {law}` "
                             "with this plant's options, or give the gains (kp=..:kd=..)")
        entry = for_plant.get(f"{opts['h']:g}")
        if entry is None:
            raise InputError(f"controller {name!r}: {tuned_file or TUNED_FILE.parent} has tuned "
                             f"gains for h = "
                             f"{', '.join(sorted(for_plant, key=float))} s only on this plant")
        if entry.get("kp") is None:
            raise InputError(f"controller {name!r}: the tuning found no safe gains for h = "
                             f"{opts['h']:g} s (see {tuned_file or TUNED_FILE.parent})")
        return PloegParams(float(entry["h"]), float(entry["kp"]), float(entry["kd"]),
                           feed_forward=law == "ploeg", **_switches(name, opts))
    raise InputError(f"{name!r} is not a Ploeg CACC or ACC controller name")


TUNED_LAWS = {"mpf-tuned": "mpf", "mpc-tuned": "mpc"}
"""The names that run a law chosen by ``carl-sumo tune`` as a whole name (its weights), and
that law: ``mpf-tuned`` (:mod:`carl_sumo.experiments.tune_mpf`), ``mpc-tuned``
(:mod:`carl_sumo.experiments.tune_mpc`)."""


def _law_key(name: str, law: str, entries: dict[str, dict]) -> str:
    """The gap (as written) whose law ``LAW-tuned[:h=H]`` runs: h, else the only gap tuned,
    else the base's own gap; InputError (one line) when there is none."""
    opts = _parse_options(name, ("h",))
    key = f"{opts['h']:g}" if "h" in opts else next(iter(entries)) if len(entries) == 1 else \
        next((k for k, e in entries.items() if e.get("base_h") == float(k)), "")
    if key not in entries:
        raise InputError(f"controller {name!r}: {law} weights are tuned for h = "
                         f"{', '.join(sorted(entries, key=float)) or 'none'} s on this plant; "
                         f"name one ({law}-tuned:h=H)")
    return key


def tuned_law(name: str, tuned_file: Path | None = None, plant: str = "ideal") -> str:
    """The law that ``mpf-tuned``, ``mpc-tuned`` (:data:`TUNED_LAWS`), with or without ``:h=H``,
    stands for on ``plant``: the name ``carl-sumo tune LAW`` chose for that plant at h (without
    h: at the only gap tuned, else at the base's; for mpf the base's ``ploeg`` name where no
    weights beat it). InputError (one line) when none was tuned for the plant or the gap."""
    kind = name.split(":")[0]
    law = TUNED_LAWS[kind]
    entries = read_tuned(tuned_file, law, plant)
    if not entries:
        example = "mpf:r=2:w2=0.3" if law == "mpf" else "mpc:wq=0.1:wv=1"
        raise InputError(f"controller {name!r}: no {law} weights tuned for the plant {plant!r}; "
                         f"run `carl-sumo tune {law}` with this plant's options, or give the "
                         f"weights ({example})")
    key = _law_key(name, law, entries)
    if not entries[key].get("name"):
        raise InputError(f"controller {name!r}: the tuning found no safe weights for h = {key} s "
                         f"(see {tuned_file or TUNED_FILE.parent})")
    return str(entries[key]["name"])


def tuned_gap(name: str) -> float:
    """The time gap (s) of a ``-tuned`` name whichever plant's gains it reads: its ``h``, or for
    ``mpf-tuned``/``mpc-tuned`` without one the gap of the law it runs (:func:`tuned_law`)."""
    options = dict(part.partition("=")[::2] for part in name.split(":")[1:])
    if "h" in options:
        return float(options["h"])
    law = TUNED_LAWS[name.split(":")[0]]
    return float(_law_key(name, law, read_tuned(None, law, None)))


def without_washout(name: str) -> str:
    """A law's name (a preset expanded) without its washout ``wo``, which only acts on a learned
    term: the classical law itself (``carl-sumo tune mpf``'s base)."""
    return ":".join(part for part in expand_preset(name).split(":") if not part.startswith("wo="))


PRESETS = {
    "cacc-real": "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:ht=0.8",
    "product-base": "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:wo=5:gn=6:op=2:ht=0.8",
}
"""Laws a user picks by one word (the short strings stay for experts):

- ``cacc-real``: Ploeg's CACC with the gains tuned for the real fleet (kp 0.0445 1/s², kd 1 1/s)
  at the product's time gaps (cars 0.6 s, trucks 0.8 s: ``ht``) with the layers every
  real-plant reference has: anti-windup (``aw``), the degraded head as an ACC at 1.4 s (``ha``)
  and the reaction layer (``ttc=2:rb=1``); the classical reference of the scenario tables.
- ``product-base``: that law with the product's own layers, the washout of the learned term
  (``wo=5`` s), Gipps' safe speed towards a vehicle not heard (``gn=6``) and the gap-opening law
  (``op=2``): the base under the shipped product's learned term."""


def expand_preset(name: str) -> str:
    """The law a preset name stands for (:data:`PRESETS`); any other name unchanged."""
    return PRESETS.get(name, name)
