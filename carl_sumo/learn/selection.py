"""Validation and checkpoint selection: the greedy policy on held-out events, its paired
improvement over the base, and the rules (``--select``) that keep one checkpoint of a run and rank
the runs of several seeds (``carl-sumo rank``). Only validation numbers enter these choices,
never a test-split number.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from carl_sumo.learn.agents import Agent
from carl_sumo.control.channel import BURSTY_CHANNEL, Impairments, PlatoonLinks
from carl_sumo.data.events import Event
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.errors import InputError
from carl_sumo.sim.metrics import BETTER, PlatoonTrajectory, aggregate, event_weights, score_event
from carl_sumo.learn.policy import read_policy_payload


VALIDATION_IMPAIRMENTS = replace(BURSTY_CHANNEL, sensor_noise=True)
"""``train --val-impaired``: validation also runs here (the robustness suite's hardest setting:
30 % loss in bursts of 3 steps, 0.2 s delay, sensor noise), with impairment seed 0."""


def validate_events(agent: Agent, env: PlatoonEnv, events: Sequence[Event],
                    conditions: Sequence[Impairments | None] = (None,),
                    helpers: Sequence["ValidationHelper"] = ()
                    ) -> tuple[float, list[dict[str, float]]]:
    """Greedy policy on each event under each of ``conditions`` (None: a perfect channel and
    clean sensors): mean per-vehicle reward and each (condition, event)'s metrics, scored on the
    true state (after an event's warm-up, :meth:`carl_sumo.data.events.Event.with_warmup`).
    With ``helpers`` (:class:`ValidationHelper`, each its own SUMO in a spawned process) the
    (condition, event) runs are dealt out in turn, this process running its share in ``env``;
    the numbers are those of one process."""
    from carl_sumo.learn.inference import CompiledActor

    act = CompiledActor(agent) if isinstance(agent, Agent) else agent.act  # numba, ~40 µs a step
    jobs = [(impairments, agent.cfg.message_impairments(impairments)
             if isinstance(agent, Agent) else impairments, event)
            for impairments in conditions for event in events]
    k = min(len(helpers) + 1, len(jobs))
    for i, helper in enumerate(helpers[:k - 1]):
        helper.submit(act, jobs[i + 1::k])
    results: list = [None] * len(jobs)
    results[0::k] = run_jobs(act, env, jobs[0::k])
    for i, helper in enumerate(helpers[:k - 1]):
        results[i + 1::k] = helper.result()
    rewards = [r for step_rewards, _ in results for r in step_rewards]
    return float(np.mean(rewards)), [metrics for _, metrics in results]


def run_jobs(act, env: PlatoonEnv, jobs: Sequence[tuple]) -> list[tuple[list[float], dict]]:
    """Each validation run (impairments, what the CA messages cross, event) of ``act`` in ``env``:
    its per-step mean rewards after the warm-up and its metrics."""
    from carl_sumo.learn.inference import CompiledActor

    out = []
    for impairments, heard, event in jobs:
        obs = env.reset_array(event=event, impairments=impairments)
        links = None
        if (heard is not None and not heard.perfect_channel
                and isinstance(act, CompiledActor) and act.message_dim):
            links = PlatoonLinks(len(obs), act.message_dim, heard, event.event_id)
        true = env.true_observation
        speeds, gaps, leader = [true[:, 0]], [true[:, 2]], [env.sim.leader_speed]
        rewards, collisions, done = [], 0, False
        while not done:
            action = act(obs) if links is None else act.act_over(obs, links)
            obs, reward, terminated, truncated, _ = env.step_array(action)
            true = env.true_observation
            if env.sim.k > event.scored_from:  # a warm-up is not scored (Event.with_warmup)
                rewards.append(reward.mean())
            speeds.append(true[:, 0]), gaps.append(true[:, 2])
            leader.append(env.sim.leader_speed)
            collisions = int((true[:, 2] <= 0).sum()) if terminated else 0
            done = terminated or truncated
        out.append((rewards, score_event(PlatoonTrajectory(
            event.event_id, np.array(leader), np.array(speeds), np.array(gaps),
            collisions).scored(event.scored_from))))
    return out


def _helper_main(conn, env_kwargs: dict) -> None:
    from carl_sumo.interrupts import die_with_parent

    die_with_parent()  # no helper outlives a killed training run
    env = PlatoonEnv(**env_kwargs)
    while True:
        try:
            message = conn.recv()
        except EOFError:  # the training process has gone
            return
        if message is None:
            conn.close()
            return
        try:
            conn.send(run_jobs(*message[:1], env, message[1]))
        except Exception as exc:  # noqa: BLE001 - raised again in the training process
            conn.send(exc)


class ValidationHelper:
    """A second validation environment in a spawned process (libsumo runs one simulation per
    process): :func:`validate_events` hands it a share of the runs while the training process
    runs the rest. ``env_kwargs``: :class:`carl_sumo.learn.env.PlatoonEnv`'s arguments."""

    def __init__(self, env_kwargs: dict):
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_helper_main, args=(child, env_kwargs), daemon=True)
        self._proc.start()
        child.close()

    def submit(self, act, jobs: Sequence[tuple]) -> None:
        self._conn.send((act, list(jobs)))

    def result(self) -> list[tuple[list[float], dict]]:
        from carl_sumo.scale.workers import WorkerError

        try:
            out = self._conn.recv()
        except (EOFError, ConnectionResetError):
            raise WorkerError(f"a validation helper process died (exit code "
                              f"{self._proc.exitcode}); the training stops here: continue it "
                              "from its last checkpoint with --resume") from None
        if isinstance(out, BaseException):
            raise out
        return out

    def close(self) -> None:
        try:
            self._conn.send(None)
        except (BrokenPipeError, OSError):
            pass
        self._proc.join(timeout=5)
        if self._proc.is_alive():
            self._proc.terminate()


class Validation:
    """Where a training run validates: ``env`` in this process and the ``helpers`` beside it
    (``--val-workers``)."""

    def __init__(self, env: PlatoonEnv, helpers: Sequence[ValidationHelper] = ()):
        self.env, self.helpers = env, list(helpers)

    def run(self, agent, events: Sequence[Event], conditions: Sequence[Impairments | None]
            ) -> tuple[float, list[dict[str, float]]]:
        """:func:`validate_events` here and in the helpers."""
        return validate_events(agent, self.env, events, conditions, self.helpers)

    def close(self) -> None:
        for helper in self.helpers:
            helper.close()


def validate(agent: Agent, env: PlatoonEnv, events: Sequence[Event]) -> dict[str, float]:
    """Greedy policy on each event: mean per-vehicle reward and the paper's metrics."""
    reward, per_event = validate_events(agent, env, events)
    return {"val_reward": reward, **aggregate(per_event)}


MARGIN_KEYS = {key: (name, BETTER[key]) for key, name in
               (("jerk_mps3", "z_jerk"), ("dampening_ratio", "z_dampening"),
                ("speed_mps", "z_speed"))}
"""The criteria the quality bar compares with IDM: their z key and the better direction."""


def improvement_z(per_event: Sequence[dict], baseline: Sequence[dict]) -> dict[str, float]:
    """Paired z-statistic of the improvement over the baseline (IDM on the same events, in the
    same order) on each criterion of the quality bar: less jerk, a lower dampening ratio, a higher
    mean speed. Per event e the difference d_e (signed so that positive is better) is weighted as
    :func:`aggregate` weights it (jerk and speed by sample count, the ratio by event); z = the
    weighted mean of d_e over its standard error. Events where either value is undefined (NaN) are
    left out; with no usable event z is 0, with one it is the sign of the difference."""
    out = {}
    for key, (name, sign) in MARGIN_KEYS.items():
        x = np.array([e[key] for e in per_event], float)
        y = np.array([e[key] for e in baseline], float)
        w = event_weights(per_event, key)
        ok = np.isfinite(x) & np.isfinite(y) & (w > 0)
        if not ok.any():
            out[name] = 0.0
            continue
        d, w = sign * (x[ok] - y[ok]), w[ok]
        mean = float(np.sum(w * d) / np.sum(w))
        if len(d) < 2:  # no spread to measure: the sign of the difference
            out[name] = float(np.sign(mean))
            continue
        se = np.sqrt(np.sum((w * (d - mean)) ** 2) * len(d) / (len(d) - 1)) / np.sum(w)
        out[name] = mean / max(float(se), 1e-12)
    return out


SAFETY_KEYS = ("collisions", "ttc_lt_1_5s_count", "headway_s")
SELECT_RULES = ("margin", "comfort", "metrics", "reward")
COMFORT_HEADWAY_SLACK = 1.05
"""``comfort`` selection: a mean headway above this times the base's is ranked as unsafe."""


def is_unsafe(val: dict[str, float]) -> bool:
    """Any collision, any TTC < 1.5 s sample, or a mean headway outside [1, 2.5] s."""
    return bool(val["collisions"] > 0 or val["ttc_lt_1_5s_count"] > 0
                or not 1.0 <= val["headway_s"] <= 2.5)


def selection_score(val: dict[str, float], select: str,
                    baseline: dict[str, float] | None = None) -> float:
    """Higher is better. Every rule but ``reward`` ranks an unsafe checkpoint (any collision, any
    TTC < 1.5 s sample, a mean headway outside [1, 2.5] s) below all safe ones.

    - ``reward``: mean validation reward (the objective the agent is trained on), with more
      collisions or more TTC < 1.5 s samples than the ``baseline`` (none when there is no
      baseline: validation events may include ones the base itself cannot survive) ranked below
      all safe checkpoints; no headway bound (a reward with a spacing term sets the gap itself).
    - ``metrics``: -(dampening ratio + mean |jerk|), each divided by the IDM ``baseline``'s value
      on the same events when one is given, with (given a baseline) a lower mean speed than
      IDM's ranked as unsafe. An undefined term (NaN: a leader that never accelerates) counts 0.
    - ``margin``: the smallest of the paired z-statistics of the improvement over the base
      (IDM for the paper's configuration) on jerk, dampening ratio and speed (``z_jerk``,
      ``z_dampening``, ``z_speed`` in ``val``, from :func:`improvement_z`): the checkpoint that
      beats its base most convincingly on its weakest criterion of the quality bar.
    - ``comfort``: the smaller of ``z_jerk`` and ``z_dampening``, with a mean headway more than
      5 % above the base's ranked as unsafe: the checkpoint that improves most on its classical
      base at the base's headway (a residual on a CACC on its tuned frontier has to beat the
      frontier where it stands, not by following further behind).
    """
    if select == "reward":
        allowed = baseline or {"collisions": 0.0, "ttc_lt_1_5s_count": 0.0}
        unsafe = val["collisions"] > allowed["collisions"] or \
            val["ttc_lt_1_5s_count"] > allowed["ttc_lt_1_5s_count"]
        return val["val_reward"] - (1000.0 if unsafe else 0.0)
    penalty = 1000.0 if is_unsafe(val) else 0.0
    if select == "margin":
        return min(val[name] for name, _ in MARGIN_KEYS.values()) - penalty
    if select == "comfort":
        if baseline is not None and val["headway_s"] > COMFORT_HEADWAY_SLACK * baseline["headway_s"]:
            penalty = 1000.0
        return min(val["z_jerk"], val["z_dampening"]) - penalty
    damp, jerk = np.nan_to_num(val["dampening_ratio"]), np.nan_to_num(val["jerk_mps3"])
    if baseline is not None:
        if val["speed_mps"] < baseline["speed_mps"]:
            penalty = 1000.0
        damp = damp / max(np.nan_to_num(baseline["dampening_ratio"]), 1e-6)
        jerk = jerk / max(np.nan_to_num(baseline["jerk_mps3"]), 1e-6)
    return -float(damp + jerk) - penalty


def rank_runs(paths: Sequence[Path], select: str = "margin") -> list[dict[str, Any]]:
    """Policy files of one model (runs of several seeds), best first by the validation
    :func:`selection_score` of each file's kept checkpoint (ties: the lower seed first).

    Reads the metadata only (the validation metrics stored at training time), so no test number
    enters the choice. Each row: path, seed, score, unsafe and the ``select`` rule's inputs.
    InputError for files of different algorithms or platoon lengths, or without the validation
    metrics the rule needs.
    """
    if select not in SELECT_RULES:
        raise InputError(f"unknown rule {select!r}; choose {', '.join(SELECT_RULES)}")
    rows, model = [], None
    for path in paths:
        payload = read_policy_payload(Path(path))
        cfg, meta = payload["agent_config"], payload.get("metadata") or {}
        this = (cfg["algo"], int(meta.get("trained_vehicles", cfg.get("n_vehicles", 1))))
        if model is None:
            model = this
        elif this != model:
            raise InputError(f"{path} is {this[0]} on {this[1]} vehicle(s), the first file is "
                             f"{model[0]} on {model[1]}; rank the runs of one model at a time")
        val = meta.get("validation") or {}
        baseline = meta.get("validation_base") or meta.get("validation_idm") or None
        needed = {"margin": [name for name, _ in MARGIN_KEYS.values()],
                  "comfort": ["z_jerk", "z_dampening"],
                  "metrics": ["jerk_mps3", "dampening_ratio", "speed_mps"],
                  "reward": ["val_reward"]}[select]
        missing = [k for k in (*needed, *SAFETY_KEYS) if k not in val]
        if missing:
            raise InputError(f"{path} has no validation {', '.join(missing)} in its metadata "
                             f"(trained by an older carl-sumo?); rank with another --select or "
                             "retrain it")
        rows.append({"path": str(path), "seed": meta.get("seed"),
                     "score": float(selection_score(val, select, baseline)),
                     "unsafe": is_unsafe(val), **{k: float(val[k]) for k in needed}})
    return sorted(rows, key=lambda r: (-r["score"], r["seed"] is None, r["seed"] or 0))


class BaseOnly:
    """a_adj = 0: the base model alone (IDM in the paper's configuration), the validation
    baseline."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(obs.shape[:-1])
