"""Policy files: a trained actor with its metadata, loadable with ``torch.load(weights_only=True)``.

A policy file is a dict: ``format`` ("carl-sumo-policy"), ``format_version``, ``agent_config``
(:class:`carl_sumo.learn.agents.AgentConfig` as a dict), ``actor`` (state dict) and ``metadata``
(algorithm, platoon length trained on, observation and reward settings, data and split, SUMO and
package versions, training command, validation metrics). Files are written atomically.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from carl_sumo.learn.agents import AgentConfig, Agent
from carl_sumo.control.channel import Impairments, PlatoonLinks
from carl_sumo.control.controllers import AheadAcceleration, CommandHistory, adjustment_bounds, \
    base_controller, shield_adjustment
from carl_sumo.errors import InputError
from carl_sumo.learn.inference import CompiledActor
from carl_sumo.files import atomic_write

FORMAT = "carl-sumo-policy"
FORMAT_VERSION = 1


def save_torch_atomic(payload: dict[str, Any], path: Path) -> None:
    """torch.save to a temporary file beside ``path``, then rename: never a half-written file."""
    with atomic_write(path, "wb") as f:
        sink = _WriteErrors(f)
        try:
            torch.save(payload, sink)
        except RuntimeError:
            if sink.error is not None:  # torch reports a failed write (a full disk) as this
                raise sink.error from None
            raise


class _WriteErrors:
    """A binary file whose writes remember their OSError: torch.save turns it into a
    RuntimeError, and the writer needs it back (one line, exit status 2)."""

    def __init__(self, f):
        self.f, self.error = f, None

    def write(self, data) -> int:
        try:
            return self.f.write(data)
        except OSError as exc:
            self.error = exc
            raise

    def flush(self) -> None:
        self.f.flush()


def load_torch(path: Path, what: str) -> dict[str, Any]:
    """torch.load(weights_only=True) with one clear InputError for missing or corrupt files."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} {path} does not exist; give the path of a file written by "
                         "`carl-sumo train`")
    try:
        with warnings.catch_warnings():  # a foreign pickle's protocol warning: the error says it
            warnings.simplefilter("ignore", UserWarning)
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"{what} {path} is corrupt or not a PyTorch file ({type(exc).__name__}); "
                         "retrain it or restore it from git") from exc
    if not isinstance(payload, dict):
        raise InputError(f"{what} {path} is not a carl-sumo file (no metadata dict)")
    return payload


def save_policy(agent: Agent, path: Path, metadata: dict[str, Any]) -> None:
    payload = {"format": FORMAT, "format_version": FORMAT_VERSION,
               "agent_config": asdict(agent.cfg), "actor": agent.actor.state_dict(),
               "metadata": metadata}
    save_torch_atomic(payload, path)


def read_policy_payload(path: Path) -> dict[str, Any]:
    """The stored dict of a policy file (weights, ``agent_config``, ``metadata``), no network
    built; InputError if it is missing, corrupt, foreign or of another format version."""
    payload = load_torch(path, "policy file")
    cfg = payload.get("agent_config")
    if payload.get("format") != FORMAT or not isinstance(cfg, dict) or "algo" not in cfg:
        raise InputError(f"policy file {path} is not a carl-sumo policy (format "
                         f"{payload.get('format')!r}); give a file written by `carl-sumo train`")
    if payload.get("format_version") != FORMAT_VERSION:
        raise InputError(f"policy file {path} has format version {payload.get('format_version')}"
                         f", this carl-sumo reads {FORMAT_VERSION}; retrain it")
    check_agent_config(cfg, path)
    return payload


CONFIG_RANGES: dict[str, tuple[type, float, float, str]] = {
    "n_vehicles": (int, 1, 100_000, "a platoon length of 1 or more"),
    "message_dim": (int, 0, 4096, "a message width of 0 or more"),
    "hidden": (int, 1, 65_536, "a layer width of 1 or more"),
    "adj_max": (float, 1e-9, 50.0, "a positive bound in m/s² (at most 50)"),
    "gamma": (float, 0.0, 1.0, "a discount from 0 to 1"),
    "tau": (float, 0.0, 1.0, "a rate from 0 to 1"),
    "batch_size": (int, 1, 10**9, "1 or more"),
    "policy_delay": (int, 1, 10**9, "1 or more"),
    "shield_ttc_s": (float, 0.0, 1e6, "0 s or more"),
}
"""Fields of a policy file's ``agent_config`` that size or bound what it computes: (type, lowest,
highest, what is needed); every other number must be finite and not negative."""


def check_agent_config(cfg: dict[str, Any], path: Path) -> None:
    """InputError (one line) for a policy file's configuration field that is not finite, of the
    wrong type or out of range: a NaN ``adj_max`` would drive every follower to a stop."""
    import math

    for key, value in cfg.items():
        if isinstance(value, (str, bool)) or value is None:
            continue
        kind, low, high, need = CONFIG_RANGES.get(key, (float, 0.0, math.inf, "0 or more"))
        ok = isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high \
            and (kind is float or float(value).is_integer())
        if not ok:
            raise InputError(f"policy file {path} has agent_config {key} = {value!r} ({need} "
                             "needed); retrain it or restore it from git")


def policy_fingerprint(path: Path, over_links: bool = True) -> str:
    """A digest of what a policy file computes: its agent configuration and actor weights (not
    its metadata), so two files that drive alike have the same one. ``over_links=False``: as
    it drives on a perfect channel, where what it does on hearing no neighbour
    (``comm_fallback``) never happens, so that setting does not count."""
    import hashlib
    import json

    payload = read_policy_payload(path)
    config = asdict(AgentConfig(**payload["agent_config"]))  # older files: their defaults
    if not over_links:
        config.pop("comm_fallback")
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode())
    for name, tensor in sorted(payload["actor"].items()):
        digest.update(name.encode())
        digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def load_policy(path: Path) -> tuple[Agent, dict[str, Any]]:
    """The agent (actor loaded) and metadata of a policy file; InputError if it is not one."""
    payload = read_policy_payload(path)
    bad = [k for k, v in payload["actor"].items()
           if isinstance(v, torch.Tensor) and v.is_floating_point() and not bool(v.isfinite().all())]
    if bad:
        raise InputError(f"policy file {path} has non-finite weights ({bad[0]}); retrain it or "
                         "restore it from git")
    try:
        cfg = AgentConfig(**payload["agent_config"])
        agent = Agent(cfg)
        agent.actor.load_state_dict(payload["actor"])
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"policy file {path} does not match its own configuration "
                         f"({type(exc).__name__}); retrain it") from exc
    agent.eval()
    return agent, payload.get("metadata", {})


class PolicyController:
    """A trained policy on the IDM base as a :class:`carl_sumo.control.controllers.Controller`.

    Acts through :class:`carl_sumo.learn.inference.CompiledActor` (numba, same numbers as
    ``agent.act``), compiled from ``agent``'s actor when the controller is made.
    """

    def __init__(self, agent: Agent, name: str):
        self.agent, self.name = agent, name
        self._actor = CompiledActor(agent)
        self._ahead = AheadAcceleration() if agent.cfg.observe_ahead else None
        self.bounds = adjustment_bounds(agent.cfg.adj_max)
        self._links: PlatoonLinks | None = None
        self._n = agent.cfg.n_vehicles

    def reset(self, n_followers: int) -> None:
        self.agent.check_length(n_followers)
        if self._ahead is not None:
            self._ahead.reset()
        self._links = None
        self._n = n_followers
        if self.agent.cfg.comm_off and self._actor.message_dim:  # CA-off: nothing is heard
            self.connect(Impairments(), "comm-off")

    def connect(self, impairments: Impairments, event_id: str) -> None:
        """Carry this episode's CA messages over impaired links (:mod:`carl_sumo.control.channel`:
        forward and backward, link streams 2 and 3 of the event); a policy without messages
        (DDPG, TD3, MADDPG) has nothing to send. Call after :meth:`reset`."""
        m = self._actor.message_dim
        if m:
            self._links = PlatoonLinks(self._n, m, self.agent.cfg.message_impairments(impairments),
                                       event_id)

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        """a_adj (m/s², shape (n,)) for one platoon observation (n, 4) of a step; a policy that
        observes the acceleration ahead measures it here (once per step); the policy's safety
        shield, if it has one, applies here."""
        if self._ahead is not None:
            obs = np.column_stack([obs[:, :4], self._ahead(obs)])
        if self._links is None:
            action = self._actor(obs)
        else:
            action = self._actor.act_over(obs, self._links)
        return shield_adjustment(obs, action, self.agent.cfg.shield_ttc_s)


class ResidualPolicyController(PolicyController):
    """A trained policy on a classical base (``agent.cfg.base``, e.g. ``ploeg-tuned:h=1``) as an
    :class:`carl_sumo.control.controllers.AccelerationController`: a_adj enters the base's law."""

    def __init__(self, agent: Agent, name: str):
        super().__init__(agent, name)
        self.base = base_controller(agent.cfg.base)
        k = agent.cfg.command_history
        self._history = CommandHistory(k) if k else None

    def reset(self, n_followers: int) -> None:
        super().reset(n_followers)
        self.base.reset(n_followers)
        if self._history is not None:
            self._history.reset(n_followers)

    def know_vehicles(self, a_max_mps2: np.ndarray, b_max_mps2: np.ndarray) -> None:
        """The base knows each vehicle's limits (:meth:`carl_sumo.control.cacc.PloegController.know_vehicles`)."""
        self.base.know_vehicles(a_max_mps2, b_max_mps2)

    def connect(self, impairments: Impairments, event_id: str) -> None:
        """The CA messages and the base's predecessor messages both cross impaired links."""
        super().connect(impairments, event_id)
        self.base.connect(impairments, event_id)

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        """a (m/s², shape (n,)) for one platoon observation (n, 4), head first; the actor sees
        a_base as a fifth column (and its last commands after it, with a command history)."""
        obs = obs[:, :4]
        seen = np.column_stack([obs, self.base.acceleration(obs, commit=False)])
        if self._history is None:
            return self.base.acceleration(obs, self.adjustment(seen))
        accel = self.base.acceleration(obs, self.adjustment(
            np.column_stack([seen, self._history.columns()])))
        self._history.push(accel)
        return accel


def load_controller(path: Path) -> PolicyController:
    """The controller of a policy file: on IDM, or on the classical base it was trained on."""
    agent, _ = load_policy(path)
    if agent.cfg.residual:
        return ResidualPolicyController(agent, str(path))
    return PolicyController(agent, str(path))


def _metric_list(values: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                     for k, v in values.items())


def _held_out(meta: dict[str, Any]) -> str:
    ids = meta.get("validation_events") or []
    if not ids:
        return "held-out training events"
    return f"{len(ids)} held-out training events, listed in the metadata's validation_events"


def _renamed(meta: dict[str, Any], path: Path) -> str:
    """A note when the file no longer has the name its training command wrote it under."""
    words = str(meta.get("command", "")).split()
    trained_as = Path(words[words.index("--out") + 1]).name if "--out" in words[:-1] else None
    if trained_as is None or trained_as == Path(path).name:
        return ""
    return f" (written as `{trained_as}`, since renamed `{Path(path).name}`)"


def _training_wall_s(curve: Path) -> float:
    """Wall time (s) of a whole training run, from the last row of its learning curve."""
    if not curve.is_file():
        return float("nan")
    rows = curve.read_text().strip().splitlines()
    return float(rows[-1].split(",")[2]) if len(rows) > 1 else float("nan")


def _wall_cell(walls: list[float]) -> str:
    """``mean (max max)`` of the known wall times (s), ``–`` without any."""
    known = [w for w in walls if np.isfinite(w)]
    return f"{np.mean(known):.0f} (max {np.max(known):.0f})" if known else "–"


def policy_table(paths: list[Path]) -> str:
    """A Markdown table of shipped policy files, one row each: algorithm, base, platoon length,
    the seed files beside it (``seeds/<stem>_seed<K>.pt``) and which one is shipped, steps,
    training wall time per seed, and the validation metrics against the base alone."""
    head = ("| file | algorithm | base | trained on | seeds (shipped) | steps | wall time per "
            "seed (s) | validation headway (s) | jerk (m/s³) | dampening | base alone: headway "
            "/ jerk / dampening |\n|---|---|---|---|---|---|---|---|---|---|---|")
    rows = [head]
    for path in map(Path, paths):
        agent, meta = load_policy(path)
        val = meta.get("validation", {})
        base = meta.get("validation_base") or meta.get("validation_idm") or {}
        seeds = [p for p in (path.parent / "seeds").glob(f"{path.stem}_seed*.pt")
                 if p.stem.rsplit("_seed", 1)[1].isdigit()]
        seeds.sort(key=lambda p: int(p.stem.rsplit("_seed", 1)[1]))
        seed_ids = [p.stem.rsplit("_seed", 1)[1] for p in seeds]
        walls = [_training_wall_s(p.with_suffix(".csv")) for p in seeds] or \
            [_training_wall_s(path.with_suffix(".csv"))]
        fmt = lambda d, k: f"{d[k]:.3f}" if k in d else "–"
        rows.append(
            f"| `{path.name}` | {meta.get('algo', agent.cfg.algo)} | {agent.cfg.base} | "
            f"{meta.get('trained_vehicles', agent.cfg.n_vehicles)} | "
            f"{', '.join(seed_ids) or '–'} ({meta.get('seed')}) | {meta.get('steps')} | "
            f"{_wall_cell(walls)} | {fmt(val, 'headway_s')} | "
            f"{fmt(val, 'jerk_mps3')} | {fmt(val, 'dampening_ratio')} | "
            f"{fmt(base, 'headway_s')} / {fmt(base, 'jerk_mps3')} / "
            f"{fmt(base, 'dampening_ratio')} |")
    return "\n".join(rows)


def policy_card(path: Path) -> str:
    """A Markdown card of a policy file: algorithm, command, seed, wall time, validation metrics."""
    agent, meta = load_policy(path)
    val = meta.get("validation", {})
    curve = Path(path).with_suffix(".csv")
    total = ""
    if curve.is_file():
        rows = curve.read_text().strip().splitlines()
        if len(rows) > 1:
            last = rows[-1].split(",")
            total = f"; whole run {float(last[2]):.0f} s for {last[0]} steps (learning curve: `{curve.name}`)"
    lines = [f"### `{Path(path).name}`", "",
             f"- algorithm: {meta.get('algo', agent.cfg.algo)}, trained on "
             f"{meta.get('trained_vehicles', agent.cfg.n_vehicles)} vehicle(s), seed {meta.get('seed')}, "
             f"base {agent.cfg.base}",
             f"- data: {meta.get('data')} split {meta.get('split')}, {meta.get('steps')} steps, "
             f"wall time {meta.get('wall_time_s', float('nan')):.0f} s to the best checkpoint{total}",
             f"- command: `{meta.get('command', '')}`" + _renamed(meta, path),
             f"- reward: {meta.get('reward')}",
             f"- versions: {meta.get('sumo_version')}, carl-sumo {meta.get('carl_sumo_version')}, "
             f"torch {meta.get('torch_version')}",
             f"- validation ({_held_out(meta)}): " + _metric_list(val)]
    if meta.get("training") or meta.get("step") is not None:
        lines.insert(-4, _training_line(meta))
    baseline = meta.get("validation_base") or meta.get("validation_idm")
    if baseline:
        lines.append(f"- the base ({agent.cfg.base}) alone on the same events: "
                     + _metric_list(baseline))
    lines.append("")
    return "\n".join(lines)


def _training_line(meta: dict) -> str:
    """The card's line on how the run learned: the step kept, RL's first actor update, the end
    of the critic burn-in and where the wall time went (files written before they were
    recorded say so)."""
    training = meta.get("training") or {}
    first = training.get("first_actor_update_step")
    parts = [f"step kept {meta.get('step', '?')}",
             "RL's first actor update " + (f"at step {first}" if first is not None else
                                           "never" if training else "not recorded")]
    calibration = training.get("critic_calibration") or {}
    if calibration.get("criterion", "off") != "off":
        parts.append(f"critic calibrated by {calibration['criterion']} until step "
                     f"{training.get('actor_from_step')} ({len(calibration.get('checks', []))} "
                     "checks)")
    if training.get("bc_alpha"):
        parts.append(f"behaviour-regularised actor, alpha {training['bc_alpha']:g}")
    trust = training.get("trust_string_stable")
    if trust is not None:
        parts.append(f"string-stability trust region: {trust['rejected']} checkpoints sent back "
                     f"to their anchor, anchors accepted at steps "
                     f"{', '.join(map(str, trust['accepted_steps'])) or 'none'}, final alpha "
                     f"{trust['final_bc_alpha']:g}")
        if trust.get("shortened_steps"):
            parts.append("actors moved back to a string-stable point by --trust-backtrack at "
                         f"steps {', '.join(map(str, trust['shortened_steps']))}")
    wall = training.get("wall_s")
    if wall:
        parts.append(f"wall time {wall['total']:.0f} s: " + ", ".join(
            f"{k} {v:.0f} s" for k, v in wall.items() if k != "total"))
    return "- training: " + "; ".join(parts)
