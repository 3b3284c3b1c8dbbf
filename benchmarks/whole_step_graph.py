"""Does compiling more of the minibatch step than the loss pay? (issue 33: "try the whole minibatch step as one
graph"). Side by side in one process, µs per minibatch (64 samples), min of repeats, alternated:

    python benchmarks/whole_step_graph.py [--repeats 7] [--calls 100]

- eager: the loss, backward, the gradient-norm clip and fused Adam, as `--no-compile` runs;
- compiled loss: today's `--compile` (the loss and its backward through torch.compile/AOTAutograd; clip and
  fused Adam eager), split into its forward, its backward and the clip + Adam that follow;
- compiled loss + compiled clip/Adam: the clip and an Adam written as tensor ops (over the optimizer's own
  state, so a checkpoint would not change) as a second graph;
- the whole step as one torch.compile, with compiled autograd tracing `backward()` (measured after the
  others, since compiled autograd is a process-wide switch).

Every variant runs the same minibatch of a short rollout, on PPO (Ant) and two-teacher MIKT (four + six →
eight). Figures drift with the machine's load; only the ratios of one run count. Nothing here is used by the
engine: it is the measurement behind docs/performance.md's "What was tried".
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from throughput import mikt_agent  # noqa: E402

from miktcli.engine.policies import GaussianActorCritic  # noqa: E402
from miktcli.engine.ppo import PPOConfig, PPOTrainer  # noqa: E402
from miktcli.envs import make_env  # noqa: E402

SETUPS = {"PPO, Ant": ("ant", None), "MIKT 2 teachers (four + six → eight)": (
    "centipede-eight", ["centipede-four", "centipede-six"])}


def trainer_for(env: str, teachers: list[str] | None, compile_loss: bool) -> PPOTrainer:
    torch.manual_seed(0)
    agent = GaussianActorCritic(111, 8) if teachers is None else mikt_agent(env, teachers)
    config = PPOConfig(n_steps=256, epochs=1, compile_loss=compile_loss, kl_coef=0.0 if teachers is None else 0.05)
    return PPOTrainer(agent, lambda: make_env(env), config, 10**6, 0)


def step_functions(tr: PPOTrainer) -> dict[str, Callable[[], object]]:
    """The minibatch step and its parts, over one fixed minibatch of `tr`'s own rollout."""
    batch = tr._values_and_targets(tr.collect()[0])
    mb, old = batch.take(slice(0, 64)), tr.agent.log_std.detach().clone()
    cfg = tr.config

    def forward():
        return tr._minibatch_loss(mb, old)

    def forward_backward():
        loss, logs = forward()
        tr.flat.zero_grad()
        loss.backward()
        return logs

    def clip_adam():
        norm = tr.flat.clip_grad_norm(cfg.max_grad_norm)
        tr.optimizer.step()
        return norm

    def full():
        logs = forward_backward()
        logs["grad_norm"] = clip_adam()
        return torch.stack([v.detach() for k, v in logs.items() if k != "ratio_dev"])

    return {"forward": forward, "backward + forward": forward_backward, "clip + Adam": clip_adam, "step": full}


def compiled_clip_adam(tr: PPOTrainer) -> Callable[[], torch.Tensor]:
    """The clip and Adam (PyTorch's update rule, no weight decay) as one compiled graph over the optimizer's
    state tensors; lr and the step count are tensors, so nothing recompiles as they change."""
    tr.optimizer.step()  # creates the state
    state = tr.optimizer.state[tr.flat.flat]
    flat, grad = tr.flat.flat.data, tr.flat.flat.grad
    m, v, count = state["exp_avg"], state["exp_avg_sq"], state["step"]
    opt = tr.optimizer
    (b1, b2), eps = opt.betas, opt.eps
    lr, max_norm = torch.tensor(float(opt.lr)), torch.tensor(float(tr.config.max_grad_norm))

    def post(flat, grad, m, v, count, lr, max_norm):
        norm = torch.linalg.vector_norm(grad)
        grad.mul_(torch.clamp(max_norm / (norm + 1e-6), max=1.0))
        count.add_(1)
        m.lerp_(grad, 1 - b1)
        v.mul_(b2).addcmul_(grad, grad, value=1 - b2)
        denom = (v.sqrt() / (1 - b2 ** count).sqrt()).add_(eps)
        flat.sub_(lr / (1 - b1 ** count) * m / denom)
        return norm

    fast = torch.compile(post, dynamic=False)
    return lambda: fast(flat, grad, m, v, count, lr, max_norm)


def best_us(fns: dict[str, Callable[[], object]], calls: int, repeats: int) -> dict[str, float]:
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            for _ in range(calls):
                fn()
            best[name] = min(best[name], 1e6 * (time.perf_counter() - t) / calls)
    return best


def warm(fn: Callable[[], object]) -> float:
    t = time.perf_counter()
    fn()
    fn()
    return time.perf_counter() - t


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--calls", type=int, default=100)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    torch._inductor.config.compile_threads = 1
    warnings.filterwarnings("ignore")
    print(f"Measured {dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC with `python benchmarks/whole_step_graph.py"
          f"{''.join(' ' + a for a in (argv if argv is not None else sys.argv[1:]))}` (torch {torch.__version__}, "
          f"1 thread; µs per 64-sample minibatch, min of {args.repeats} × {args.calls} calls)\n")
    print("| system | eager step | compiled loss: step (forward / backward / clip + Adam) "
          "| + compiled clip and Adam | whole step as one graph | compile s (loss / post / whole) |")
    print("|---|---|---|---|---|---|")
    rows = {}
    for label, (env, teachers) in SETUPS.items():
        # one compiled trainer for both compiled variants: a second one would add a second set of guards to
        # the same compiled code (its cost is not the engine's, which has one trainer)
        eager, comp = trainer_for(env, teachers, False), trainer_for(env, teachers, True)
        e, c = step_functions(eager), step_functions(comp)
        p, post_fn = c, compiled_clip_adam(comp)

        def post_step(p=p, post_fn=post_fn):
            logs = p["backward + forward"]()
            logs["grad_norm"] = post_fn()
            return torch.stack([v.detach() for k, v in logs.items() if k != "ratio_dev"])

        warm(e["step"])
        t_loss, t_post = warm(c["step"]), warm(post_step)
        us = best_us({"eager": e["step"], "compiled": c["step"], "fwd": c["forward"],
                      "fwdbwd": c["backward + forward"], "clip_adam": c["clip + Adam"], "post": post_step},
                     args.calls, args.repeats)
        rows[label] = (env, teachers, us, t_loss, t_post)
    torch._dynamo.config.compiled_autograd = True  # process-wide: the whole-step variant goes last
    for label, (env, teachers, us, t_loss, t_post) in rows.items():
        whole_tr = trainer_for(env, teachers, False)
        whole = torch.compile(step_functions(whole_tr)["step"], dynamic=False)
        t_whole = warm(whole)
        us["whole"] = best_us({"whole": whole}, args.calls, args.repeats)["whole"]
        print(f"| {label} | {us['eager']:.0f} | {us['compiled']:.0f} ({us['fwd']:.0f} / "
              f"{us['fwdbwd'] - us['fwd']:.0f} / {us['clip_adam']:.0f}) | {us['post']:.0f} | {us['whole']:.0f} | "
              f"{t_loss:.0f} / {t_post:.0f} / {t_whole:.0f} |")


if __name__ == "__main__":
    main()
