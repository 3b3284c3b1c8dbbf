"""Where an eager two-teacher MIKT minibatch step spends its time, op by op (torch.profiler, CPU).

    python benchmarks/profile_update.py [--steps 50] [--rows 25]

The minibatch step of four + six → centipede-eight (loss, backward, clip, Adam; 64 samples; the teachers
active and coupled). Prints the aten ops per step, the matmuls' share of the self time and the top ops.
The profiler's own overhead inflates the times; read the counts and shares (docs/performance.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, str(Path(__file__).resolve().parent))

from throughput import mikt_agent  # noqa: E402

from miktcli.engine.ppo import PPOConfig, PPOTrainer  # noqa: E402
from miktcli.envs import make_env  # noqa: E402

MATMULS = ("aten::addmm", "aten::mm", "aten::bmm", "aten::matmul")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--rows", type=int, default=25)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(0)
    agent = mikt_agent("centipede-eight", ["centipede-four", "centipede-six"])
    trainer = PPOTrainer(agent, lambda: make_env("centipede-eight"), PPOConfig(n_steps=256, epochs=1, kl_coef=0.05),
                         10**6, 0)
    batch = trainer._values_and_targets(trainer.collect()[0])
    mb, old = batch.take(slice(0, 64)), agent.log_std.detach().clone()

    def step() -> None:
        loss, _ = trainer.loss(mb, old)
        trainer.flat.zero_grad()
        loss.backward()
        trainer.flat.clip_grad_norm(trainer.config.max_grad_norm)
        trainer.optimizer.step()

    for _ in range(10):
        step()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(args.steps):
            step()
    trainer.close()
    events = prof.key_averages()
    total = sum(e.self_cpu_time_total for e in events)
    matmul = sum(e.self_cpu_time_total for e in events if e.key in MATMULS)
    ops = sum(e.count for e in events if e.key.startswith("aten::"))
    print(f"aten ops per minibatch step: {ops / args.steps:,.0f}; matmuls' share of the self time: "
          f"{matmul / total:.0%}")
    print(events.table(sort_by="self_cpu_time_total", row_limit=args.rows))


if __name__ == "__main__":
    main()
