"""`carl-sumo bench --training`: both rates and the update time for each platoon size; the replay
buffer's tensors sample what the numpy buffer sampled."""

import numpy as np
import torch

from carl_sumo.cli import main
from carl_sumo.learn.replay_buffer import ReplayBuffer

from conftest import NET


def test_training_bench_prints_rates_and_update_time_per_size(capsys):
    code = main(["bench", "--training", "--net", str(NET), "--vehicles", "2,3", "--envs", "1",
                 "--steps", "8"])
    out = capsys.readouterr().out.strip().splitlines()
    assert code == 0 and "update (ms)" in out[0]
    rows = [line.split() for line in out[2:]]
    assert [int(r[1]) for r in rows] == [2, 3]
    for r in rows:
        no_updates, with_updates, update_ms = float(r[3]), float(r[4]), float(r[5])
        assert no_updates > 0 and with_updates > 0 and update_ms > 0


def test_replay_buffer_wraps_and_samples_the_numpy_buffers_transitions():
    rng = np.random.default_rng(0)
    buf = ReplayBuffer(5, 3)
    rows = []
    for _ in range(4):  # 8 transitions into 5 slots: the first 3 are overwritten
        obs, nxt = rng.normal(size=(2, 3, 4)), rng.normal(size=(2, 3, 4))
        act, rew, done = rng.normal(size=(2, 3)), rng.normal(size=(2, 3)), np.array([0.0, 1.0])
        buf.add(obs, act, rew, nxt, done)
        rows += [(obs[i], act[i], rew[i], nxt[i], done[i]) for i in range(2)]
    assert buf.size == 5 and buf.pos == 3
    kept = rows[5:] + rows[3:5]  # slot order after wrapping: 5, 6, 7, then 3, 4
    idx = np.random.default_rng(1).integers(0, 5, size=16)
    batch = buf.sample(16, np.random.default_rng(1))
    for name, k in (("obs", 0), ("action", 1), ("reward", 2), ("next_obs", 3), ("done", 4)):
        want = np.stack([np.asarray(kept[j][k], dtype=np.float32) for j in idx])
        np.testing.assert_array_equal(batch[name].numpy(), want)
        assert batch[name].dtype == torch.float32
    assert batch["mask"].shape == (16, 3) and bool(batch["mask"].all())
    restored = ReplayBuffer.from_state(buf.state())
    assert restored.size == 5 and restored.pos == 3
    assert torch.equal(restored.sample(16, np.random.default_rng(1))["obs"], batch["obs"])
