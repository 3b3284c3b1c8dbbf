"""Where a run's update time goes when it grows as the run trains: subnormal floats.

Restores a run's last checkpoint into its trainer (the same code path as `--resume`), counts subnormal
(denormal) floats in the weights, the gradients of one update and Adam's state, and times one full update
(10 epochs x 32 minibatches) from that state with torch's flush-to-zero off and on, side by side.

    python benchmarks/subnormals.py RUN [--registry registry] [--repeats 3] [--json OUT]

It trains nothing that is kept: the run folder is only read.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from miktcli.registry.runs import open_run
from miktcli.workflows.session import Job


def subnormal_count(t: torch.Tensor) -> int:
    t = t.detach()
    tiny = torch.finfo(t.dtype).tiny  # the smallest normal float
    return int(((t != 0) & (t.abs() < tiny)).sum())


def where_subnormals(job: Job) -> dict[str, int]:
    """Subnormals per named parameter, in its gradient and in Adam's two moments (only non-zero counts)."""
    flat = job.trainer.flat
    state = job.trainer.optimizer.state[flat.flat]
    out: dict[str, int] = {}
    offsets, start = {}, 0
    for name, p in job.agent.named_parameters():
        if not p.requires_grad:
            continue
        offsets[name] = (start, start + p.numel())
        start += p.numel()
    for name, (a, b) in offsets.items():
        for what, tensor in (("weight", flat.flat.data), ("grad", flat.flat.grad), ("exp_avg", state["exp_avg"]),
                             ("exp_avg_sq", state["exp_avg_sq"])):
            n = subnormal_count(tensor[a:b])
            if n:
                out[f"{what}:{name}"] = n
    return out


def timed_update(job: Job, flush: bool) -> float:
    trainer = job.trainer
    saved = {k: v.clone() for k, v in trainer.state_tensors().items()}
    progress = trainer.progress_state()
    torch.set_flush_denormal(flush)
    try:
        trainer.agent.set_progress(trainer.iteration / trainer.num_iterations)
        rollout, _ = trainer.collect()
        batch = trainer._values_and_targets(rollout)
        start = time.perf_counter()
        trainer.update(batch)
        return time.perf_counter() - start
    finally:
        torch.set_flush_denormal(False)
        trainer.load_state(saved, progress)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--registry", type=Path, default=Path("registry"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    run = open_run(args.registry, args.run)
    with Job(run, args.registry) as job:
        job.trainer.config.compile_loss and print("note: timed eager (the compiled loss is not rebuilt here)",
                                                  file=sys.stderr)
        job.trainer._minibatch_loss = job.trainer.loss
        counts = where_subnormals(job)
        times = {"flush_off": [], "flush_on": []}
        for _ in range(args.repeats):  # interleaved, so drift in the machine's speed hits both alike
            times["flush_off"].append(timed_update(job, flush=False))
            times["flush_on"].append(timed_update(job, flush=True))
        # the gradients (and their subnormals) after one update from the checkpoint, flush off
        timed_update(job, flush=False)
        grads = where_subnormals(job)
    report = {
        "run": run.id, "steps": run.card.steps_done,
        "subnormals_at_checkpoint": counts,
        "subnormals_after_one_update": grads,
        "update_s": {k: sorted(v) for k, v in times.items()},
        "ratio_off_over_on": min(times["flush_off"]) / min(times["flush_on"]),
    }
    text = json.dumps(report, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
