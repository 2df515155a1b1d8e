"""Would lower precision make the CA-TD3 update cheap? Times the two kinds of matrix product in
the update (10 followers, batch 128, hidden 64) in float32 and bfloat16 on one thread, best of 5
rounds of 2,000 products each.

    python benchmarks/bf16_matmul.py
"""

import time

import torch

SHAPES = {"1280x80 @ 80x64 (the input rows of all vehicles at once)": ((1280, 80), (80, 64)),
          "128x64 @ 64x64 (one vehicle's step of a message recurrence)": ((128, 64), (64, 64))}


def best_us(a: torch.Tensor, b: torch.Tensor, rounds: int = 5, repeat: int = 2000) -> float:
    """Best mean time of ``a @ b`` over ``rounds`` (µs)."""
    for _ in range(200):
        a @ b
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(repeat):
            a @ b
        best = min(best, (time.perf_counter() - start) / repeat)
    return best * 1e6


def main() -> None:
    torch.set_num_threads(1)
    for name, (shape_a, shape_b) in SHAPES.items():
        times = [best_us(torch.randn(*shape_a, dtype=dt), torch.randn(*shape_b, dtype=dt))
                 for dt in (torch.float32, torch.bfloat16)]
        print(f"{name}: float32 {times[0]:.1f} µs, bfloat16 {times[1]:.1f} µs, "
              f"{times[0] / times[1]:.2f}x")


if __name__ == "__main__":
    main()
