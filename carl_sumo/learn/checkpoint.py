"""Training checkpoints: everything a run needs to go on where it stopped (agent, optimisers,
replay buffer, random states, step, best score, wall time, and the rollouts' state: every action
sent to the environments, the exploration noise, the recent rewards), written atomically, and
read back. With the actions a resumed run replays its environments to where they were, so it
continues exactly as the run would have without the stop (:func:`carl_sumo.learn.train.train`).
With ``--gate-string-stable`` every validated actor is also kept as a candidate policy file."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from carl_sumo.errors import InputError
from carl_sumo.learn.agents import Agent
from carl_sumo.learn.policy import load_torch, save_policy, save_torch_atomic
from carl_sumo.learn.replay_buffer import ReplayBuffer
from carl_sumo.learn.train_config import TrainConfig

CHECKPOINT_FORMAT = "carl-sumo-checkpoint"


def _decode_rng(saved: dict) -> dict:
    return {"bit_generator": saved["bit_generator"],
            "state": {"state": int(saved["state_hi"]) << 64 | int(saved["state_lo"]),
                      "inc": int(saved["inc_hi"]) << 64 | int(saved["inc_lo"])},
            "has_uint32": int(saved["has_uint32"]), "uinteger": int(saved["uinteger"])}


def _rng_for_save(rng: np.random.Generator) -> dict:
    s = rng.bit_generator.state
    state, inc = int(s["state"]["state"]), int(s["state"]["inc"])
    mask = (1 << 64) - 1
    return {"bit_generator": s["bit_generator"], "state_hi": state >> 64, "state_lo": state & mask,
            "inc_hi": inc >> 64, "inc_lo": inc & mask, "has_uint32": int(s["has_uint32"]),
            "uinteger": int(s["uinteger"])}


def save_checkpoint(path: Path, cfg: TrainConfig, agent: Agent, buffer: ReplayBuffer,
                     rng: np.random.Generator, step: int, best: float, wall_s: float,
                     rollouts: dict[str, torch.Tensor] | None = None) -> None:
    """Write a run's state after ``step`` vector steps to ``path`` (atomically); ``rollouts``:
    the environments' state (``actions`` (step, envs, n) m/s², ``noise``, ``recent``)."""
    save_torch_atomic({"format": CHECKPOINT_FORMAT, "train_config": asdict(cfg),
                       "agent": agent.state_dict(), "actor_opt": agent.actor_opt.state_dict(),
                       "critic_opt": agent.critic_opt.state_dict(), "updates": agent.updates,
                       "buffer": buffer.state(), "numpy_rng": _rng_for_save(rng),
                       "torch_rng": torch.get_rng_state(), "step": step, "best": best,
                       "wall_s": wall_s, **({"rollouts": rollouts} if rollouts else {})}, path)


def read_checkpoint(path: Path) -> dict:
    """The stored state of a training checkpoint; InputError when it is not one."""
    state = load_torch(path, "checkpoint")
    if state.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path} is not a carl-sumo training checkpoint")
    return state


def restore_checkpoint(path: Path, cfg: TrainConfig, agent: Agent, rng: np.random.Generator,
                       rollouts: dict | None = None) -> tuple[ReplayBuffer, int, float, float]:
    """Load a checkpoint into ``agent`` and ``rng`` (and torch's random state) for a run of the
    same algorithm and platoon length; returns (replay buffer, step, best score, wall time s).
    ``rollouts`` (a dict) receives the stored state of the environments, where there is one."""
    state = read_checkpoint(path)
    if state["train_config"]["algo"] != cfg.algo or \
            state["train_config"]["n_vehicles"] != cfg.n_vehicles:
        raise InputError(f"checkpoint {path} is for {state['train_config']['algo']} with "
                         f"{state['train_config']['n_vehicles']} vehicles; resume with the "
                         "same --algo and --vehicles")
    agent.load_state_dict(state["agent"])
    agent.actor_opt.load_state_dict(state["actor_opt"])
    agent.critic_opt.load_state_dict(state["critic_opt"])
    agent.updates = int(state["updates"])
    rng.bit_generator.state = _decode_rng(state["numpy_rng"])
    torch.set_rng_state(state["torch_rng"])
    if rollouts is not None:  # and the random states as restored, for the rollouts' start
        rollouts.update(state.get("rollouts") or {}, numpy_rng=rng.bit_generator.state,
                        torch_rng=torch.get_rng_state())
    return (ReplayBuffer.from_state(state["buffer"]), int(state["step"]), float(state["best"]),
            float(state["wall_s"]))


def candidate_dir(out: Path) -> Path:
    """Where ``--gate-string-stable`` keeps every validated checkpoint of the run writing ``out``
    (one policy file per step, ``step000500.pt``)."""
    return Path(out).with_suffix(".candidates")


def save_candidate(cfg: TrainConfig, agent: Agent, out: Path, step: int, meta: dict) -> None:
    """With ``--gate-string-stable``: the actor as a candidate of the gate (see
    :func:`carl_sumo.experiments.string_stability.keep_string_stable`)."""
    if cfg.gate_string_stable is not None:
        candidate_dir(out).mkdir(exist_ok=True)
        save_policy(agent, candidate_dir(out) / f"step{step:06d}.pt", meta)

