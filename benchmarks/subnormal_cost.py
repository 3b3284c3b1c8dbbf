"""What subnormal floats cost on this CPU: the update's two kinds of work with and without them, side by side.

    python benchmarks/subnormal_cost.py [--json OUT]

1. Matmuls of one minibatch step's shapes (64 x 64 by 64 x 139, forward and both backward products), with 36
   rows / columns filled with 0, with 1e-40 (subnormal) and with 1e-44 (near the smallest subnormal).
2. A fused Adam step over 120,000 floats (about a two-teacher student's flat parameter buffer), 320 steps (one
   update), with 0 %, 10 % and 50 % of its moments subnormal and their gradients zero (as MIKT's unused
   parameters have).
Each with torch's flush-to-zero off and on, interleaved, the minimum of the repeats. Only ratios measured in
the same run mean anything (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch


def matmuls(fill: float, flush: bool, reps: int = 3000) -> float:
    a, w, g = torch.randn(64, 64), torch.randn(139, 64), torch.randn(64, 139)
    w[:36], g[:, :36] = fill, fill
    torch.set_flush_denormal(flush)
    try:
        start = time.perf_counter()
        for _ in range(reps):
            a @ w.T, g @ w, g.T @ a
        return time.perf_counter() - start
    finally:
        torch.set_flush_denormal(False)


def adam(fraction: float, flush: bool, n: int = 120_000, steps: int = 320) -> float:
    p = torch.nn.Parameter(torch.randn(n))
    p.grad = torch.randn(n) * 1e-3
    opt = torch.optim.Adam([p], lr=3e-4, eps=1e-5, fused=True)
    opt.step()
    k = int(n * fraction)
    opt.state[p]["exp_avg"][:k], opt.state[p]["exp_avg_sq"][:k], p.grad[:k] = 3e-45, 1e-43, 0.0
    torch.set_flush_denormal(flush)
    try:
        start = time.perf_counter()
        for _ in range(steps):
            opt.step()
        return time.perf_counter() - start
    finally:
        torch.set_flush_denormal(False)


def best(measure, *args, repeats: int) -> dict[str, float]:
    off, on = [], []
    for _ in range(repeats):
        off.append(measure(*args, False))
        on.append(measure(*args, True))
    return {"flush_off_s": min(off), "flush_on_s": min(on)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
           "matmul": {str(f): best(matmuls, f, repeats=args.repeats) for f in (0.0, 1e-40, 1e-44)},
           "adam_320_steps": {str(f): best(adam, f, repeats=args.repeats) for f in (0.0, 0.1, 0.5)}}
    base_mm, base_adam = out["matmul"]["0.0"]["flush_off_s"], out["adam_320_steps"]["0.0"]["flush_off_s"]
    out["ratios"] = {"matmul_subnormal_vs_zero": out["matmul"]["1e-40"]["flush_off_s"] / base_mm,
                     "adam_half_subnormal_vs_none": out["adam_320_steps"]["0.5"]["flush_off_s"] / base_adam}
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")


if __name__ == "__main__":
    main()
