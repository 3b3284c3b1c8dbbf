"""Several seeds of one cell trained in one process as one batched problem ("seeds together").

Each seed keeps its own PPOTrainer: its envs, generators, normalisers, reward scaler, Adam state, metrics and
checkpoints, so every run folder holds what a run trained alone writes. What the seeds share is the update:
their parameters become the rows of one (seeds, P) buffer, and every minibatch's loss and gradient are
computed for all seeds at once by one module call on stacked tensors. The agents have one shape, so seed 0's
agent is the function, and functional_call swaps in every parameter as a (seeds, *shape) view of the rows;
the minibatch is (seeds, B, ...). The engine's loss and the agents reduce over the last dimension only and
`nets.linear` turns a stacked weight into one batched matmul, so the loss comes back as one value per seed;
the frozen teachers, equal in every seed, are read once and broadcast. The gradient of the seeds' summed loss
is each seed's own (no parameter is shared). Each seed draws its minibatches from its own generator in the
order it would alone, its gradient is clipped by its own norm and its own Adam steps its row.

Why not torch.func.vmap over the single-seed loss (the first version): its batched kernels cost about as
much as the seeds one after another on these small networks (a 3-layer MLP, 5 seeds: 2.2-2.9 ms against
2.6-3.1 ms separate and 1.2-1.4 ms for the stacked matmuls, measured 2026-12-06 under load).

The numbers are a single-seed run's to float rounding, not bit for bit (a batched matmul sums in another
order), so the card records the mode (RunConfig.seeds_together).

The rollouts step in lock step: each step, every seed normalises its observation into its row of one
(seeds, envs, obs) buffer, one forward computes every seed's action mean (the agent's rollout_actor with the
parameters stacked, so a batched matmul a layer and the frozen teachers once over all the seeds' rows), then
each seed samples with its own generator and steps its own envs. The physics, most of a step, stays one
seed after another. (Under vmap this forward had cost more than five separate ones, 1.32 against 1.07 ms,
measured 2026-12-04; the stacked one needs no vmap.)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.func import functional_call

from miktcli.engine.ppo import Minibatch, PPOTrainer, compiled, flushing_denormals, update_metrics
from miktcli.engine.rollout import Rollout


class _RolloutActor(nn.Module):
    """The agent's rollout_actor as a module call, so functional_call can swap in the stacked parameters
    (the same `agent.` names as _TrainerLoss); the function it returns keeps views of them."""

    def __init__(self, agent: nn.Module):
        super().__init__()
        self.agent = agent

    def forward(self, obs: torch.Tensor) -> Callable[[], torch.Tensor]:
        return self.agent.rollout_actor(obs)


class _TrainerLoss(nn.Module):
    """A trainer's minibatch loss as a module call, so functional_call can swap its agent's parameters."""

    def __init__(self, trainer: PPOTrainer):
        super().__init__()
        self.agent = trainer.agent
        self.trainer = [trainer]  # in a list: not a submodule

    def forward(self, mb: Minibatch, old_log_std: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return self.trainer[0].loss(mb, old_log_std)


def check_alike(trainers: list[PPOTrainer]) -> None:
    """Seeds train together only where they are one problem: same settings, schedule position and shapes."""
    if len(trainers) < 2:
        raise ValueError("seeds together needs at least two trainers")
    first = trainers[0]
    shapes = [tuple(p.shape) for p in first.flat.params]
    for t in trainers[1:]:
        if t.config != first.config or t.num_iterations != first.num_iterations:
            raise ValueError("seeds trained together need the same PPO settings and budget")
        if t.iteration != first.iteration:
            raise ValueError(f"seeds trained together start at one iteration ({first.iteration} and {t.iteration})")
        if type(t.agent) is not type(first.agent) or [tuple(p.shape) for p in t.flat.params] != shapes:
            raise ValueError("seeds trained together need agents of one shape")
    if first.config.gradients != "autograd":  # the stacked update is autograd's; a card must say what ran
        raise ValueError(f"seeds together computes its gradients with autograd; these runs say "
                         f"gradients={first.config.gradients}")


class SeedsTogether:
    """Trains `trainers` (one per seed) in lock step; iterate `run()` for each iteration's metrics rows."""

    def __init__(self, trainers: list[PPOTrainer]):
        check_alike(trainers)
        self.trainers = trainers
        self.config = trainers[0].config
        size = trainers[0].flat.flat.numel()
        self.params = torch.zeros(len(trainers), size)
        self.grads = torch.zeros(len(trainers), size)
        for row, trainer in enumerate(trainers):
            trainer.flat.rebind(self.params[row], self.grads[row])
        self._grads = self._gradient_function()
        self._actor = _RolloutActor(trainers[0].agent)  # every seed's rollout forward at once

    def _gradient_function(self) -> Callable[..., Any]:
        lead = self.trainers[0]
        names = [name for name, p in lead.agent.named_parameters() if p.requires_grad]
        owned = [p for p in lead.agent.parameters() if p.requires_grad]
        if owned != lead.flat.params:  # the row's layout is FlatParameters' order, which is this one
            raise ValueError("the agent's trainable parameters are not in the flat buffer's order")
        # Each parameter as its own (seeds, *shape) view of the row buffers, passed to the gradient as a
        # dict: slicing one (seeds, P) input inside the function instead would make every slice's backward
        # write a full-size zero gradient (~40 of them a minibatch, most of the update's time).
        self.param_views: dict[str, torch.Tensor] = {}
        self.grad_views: dict[str, torch.Tensor] = {}
        seeds, offset = len(self.trainers), 0
        for name, p in zip(names, owned, strict=True):
            n = p.numel()
            self.param_views[f"agent.{name}"] = self.params[:, offset:offset + n].view(seeds, *p.shape)
            self.grad_views[f"agent.{name}"] = self.grads[:, offset:offset + n].view(seeds, *p.shape)
            offset += n
        module = _TrainerLoss(lead)

        def seeds_loss(params: dict[str, torch.Tensor], mb: Minibatch, old_log_std: torch.Tensor):
            loss, logs = functional_call(module, params, (mb, old_log_std))  # loss: (seeds,)
            return loss.sum(), logs

        # compiled like the single-seed loss: the forward (and its backward) through torch.compile, the
        # gradient call outside it
        loss_fn = compiled(seeds_loss) if self.config.compile_loss else seeds_loss

        def gradient(params: dict[str, torch.Tensor], mb: Minibatch, old_log_std: torch.Tensor):
            # fresh leaves on the rows' storage: they read the rows as Adam left them
            leaves = {name: view.detach().requires_grad_(True) for name, view in params.items()}
            total, logs = loss_fn(leaves, mb, old_log_std)
            grads = torch.autograd.grad(total, list(leaves.values()), allow_unused=True)
            return dict(zip(leaves, grads, strict=True)), logs

        return gradient

    # --- rollout ------------------------------------------------------------------------------------
    def collect(self) -> list[tuple[Rollout, dict[str, float], float]]:
        """One rollout a seed, in lock step with one batched forward a step; each seed's (rollout, stats,
        its share of the wall time)."""
        trainers, clock = self.trainers, time.perf_counter
        start = clock()
        envs = trainers[0].envs
        stacked = np.empty((len(trainers), *envs.obs.shape), np.float32)
        collectors = [t.rollout_collector(stacked[s]) for s, t in enumerate(trainers)]
        actor = functional_call(self._actor, self.param_views, (torch.from_numpy(stacked),))
        share = 1.0 / len(trainers)
        with torch.inference_mode():
            for _ in range(collectors[0].steps):
                t0 = clock()
                for c in collectors:
                    c.observe()
                means = actor().numpy()
                inference = (clock() - t0) * share
                for c, mean in zip(collectors, means, strict=True):
                    c.act(mean, inference)
        results = [t.finish_rollout(c) for t, c in zip(trainers, collectors, strict=True)]
        wall = (clock() - start) * share
        return [(rollout, stats, wall) for rollout, stats in results]

    # --- update -------------------------------------------------------------------------------------
    def update(self, batches: list[Minibatch]) -> list[dict[str, float]]:
        cfg, trainers = self.config, self.trainers
        seeds = len(trainers)
        batch = Minibatch(*(torch.stack(parts) for parts in zip(*batches, strict=True)))
        old_log_std = torch.stack([t.agent.log_std.detach().clone() for t in trainers])
        size = batch.obs.shape[1]
        rows = torch.arange(seeds)[:, None]
        logged: list[torch.Tensor] = []
        names: list[str] = []
        first_ratio_dev = torch.zeros(seeds)
        for _epoch in range(cfg.epochs):
            # each seed's own permutation, from its own generator: the order it would take alone
            order = torch.stack([torch.randperm(size, generator=t.torch_gen) for t in trainers])
            shuffled = Minibatch(*(part[rows, order] for part in batch))
            for start in range(0, size, cfg.minibatch_size):
                mb = Minibatch(*(part[:, start:start + cfg.minibatch_size] for part in shuffled))
                grads, logs = self._grads(self.param_views, mb, old_log_std)
                for name, g in grads.items():
                    if g is None:  # a parameter this phase's loss does not read: no gradient, as alone
                        self.grad_views[name].zero_()
                    else:
                        self.grad_views[name].copy_(g)
                norms = torch.linalg.vector_norm(self.grads, dim=1)
                self.grads.mul_(torch.clamp(cfg.max_grad_norm / (norms + 1e-6), max=1.0)[:, None])
                logs["grad_norm"] = norms
                for t in trainers:
                    t.optimizer.step()
                if not logged:
                    first_ratio_dev = logs["ratio_dev"].detach().clone()
                    names = [k for k in logs if k != "ratio_dev"]
                logged.append(torch.stack([logs[k].detach() for k in names], 1))
        means = torch.stack(logged).mean(0)  # (seeds, names)
        return [update_metrics(dict(zip(names, means[s].tolist(), strict=True)), float(first_ratio_dev[s]),
                               batches[s]) for s in range(seeds)]

    # --- the loop -----------------------------------------------------------------------------------
    def run(self) -> Iterator[list[dict[str, Any]]]:
        """One list of metrics rows (one per seed, in the trainers' order) per iteration. A row's update
        time is the batched update's share per seed."""
        trainers = self.trainers
        clock = time.perf_counter
        while trainers[0].iteration < trainers[0].num_iterations:
            lrs = [t.begin_iteration() for t in trainers]
            phases = {t.agent.phase(t.iteration / t.num_iterations) for t in trainers}
            if len(phases) > 1:  # one loss for all: the schedule must agree (it does for equal budgets)
                raise RuntimeError(f"seeds trained together are in different phases: {sorted(phases)}")
            collected = self.collect()
            start = clock()
            with flushing_denormals(self.config.flush_denormal):
                batches = [t._values_and_targets(rollout) for t, (rollout, _, _) in zip(trainers, collected,
                                                                                        strict=True)]
                losses = self.update(batches)
                for t, b in zip(trainers, batches, strict=True):
                    t.observe(b)
            share = (clock() - start) / len(trainers)
            yield [t.end_iteration(lr, stats, loss, t_rollout, share)
                   for t, lr, (_, stats, t_rollout), loss in zip(trainers, lrs, collected, losses, strict=True)]
