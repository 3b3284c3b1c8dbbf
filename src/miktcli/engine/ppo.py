"""The one PPO engine: rollout collection, GAE, the clipped loss and the update loop.

It knows nothing about teachers. A policy/value module (policies.ActorCritic) may add its own loss
terms through `evaluate_actions`; MIKT plugs in that way. Layout and names follow CleanRL's
ppo_continuous_action.py; every implementation detail that changes results is a field of PPOConfig and
is recorded with each checkpoint.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, ClassVar, Literal, NamedTuple

import gymnasium as gym
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from miktcli import compat
from miktcli.engine.adam import FusedAdam
from miktcli.engine.by_hand import HandGradients, ratio_logs, unsupported
from miktcli.engine.flatparams import FlatParameters
from miktcli.engine.nets import update_moments
from miktcli.engine.policies import ActorCritic, gaussian_kl, gaussian_log_prob
from miktcli.engine.rollout import Rollout, RolloutCollector
from miktcli.envs.vector import SyncEnvs
from miktcli.errors import MiktError


class PPOConfig(BaseModel):
    """The paper's hyper-parameters (Table A + the reference ppo2 defaults) and every decided detail."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # an inf or NaN coefficient poisons every loss

    n_steps: int = Field(2048, gt=0, description="env steps per env per rollout")
    num_envs: int = Field(1, gt=0, description="synchronous environments")
    epochs: int = Field(10, gt=0)
    minibatch_size: int = Field(64, gt=0)
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    learning_rate: float = 3e-4
    lr_schedule: str = Field("linear", pattern="^(linear|constant)$", description="linear decay to 0")
    adam_eps: float = 1e-5
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    clip_value_loss: bool = Field(True, description="clip the value prediction's change, same range as the policy")
    value_loss: Literal["ppo2", "sb3", "cat-zero-target"] = Field(
        "ppo2", description="ppo2 (the authors'): 0.5·max(unclipped², clipped²); sb3: the clipped prediction's "
        "squared error alone, no 0.5 (both then weighted by vf_coef). cat-zero-target: CAT's committed code "
        "(ppo2/model.py: vf_losses1 = square(vpred - 0)), 0.5·max(V², (V_clipped − R)²), whose unclipped "
        "term has the target 0: a bug that shrinks the value head; only to reproduce CAT's runs, never a default")
    normalize_advantage: bool = Field(True, description="per minibatch")
    obs_normalization: bool = Field(True, description="running mean/std, updated every step, clip ±10")
    reward_scaling: bool = Field(True, description="divide by running std of the discounted return")
    reward_clip: float = 10.0
    kl_coef: float = Field(0.0, ge=0, description="weight of KL(pi || pi_old) added to the loss")
    bootstrap_truncation: bool = Field(True, description="time-limit ends bootstrap V(final obs)")
    clip_actions_for_env: bool = Field(
        False, description="clip actions to the action space before env.step; off (the authors' ppo2): the raw "
        "Gaussian sample reaches the env, MuJoCo clamps ctrl itself and the control cost sees the raw action")
    log_std_init: float = 0.0
    lean_env: bool = Field(
        True, description="step this package's own env families (centipede, Ant-v4, Hopper-v5) straight over "
        "MuJoCo's arrays (envs/lean.py), bit-identical to the gymnasium env; off: every step through gymnasium")
    flush_denormal: bool = Field(
        True, description="flush subnormal floats to zero (FTZ/DAZ) in the networks' work outside the rollout "
        "(the value pass, the update, the statistics after it), as TensorFlow does in every kernel, so the "
        "authors' code did too. Off: subnormals are kept; MIKT's decoder rows for constant observation dims and "
        "Adam's moments of parameters without gradient decay into that range as a run trains, and on CPUs "
        "that take a microcode assist for each subnormal operand every op reading them slows down")
    torch_threads: int = Field(1, ge=1, le=256, description="torch's intra-op threads while training, set by the "
                               "trainer (the CLI and the Python API alike): results depend on it, since "
                               "reductions split differently; one is also the fastest on these small networks")
    compile_loss: bool = Field(
        False, description="run the minibatch loss and its gradient through torch.compile: the same maths to "
        "float rounding, faster updates on a CPU (measured in the project's throughput benchmark), a compile of "
        "~30 s at the start and after a resume; needs a C++ compiler")
    compile_reason: str = Field("", description="why compile_loss is on or off: asked (--compile, --no-compile) "
                                "or decided by auto from the run's size (see compile_choice.py)")
    gradients: Literal["autograd", "by-hand"] = Field(
        "autograd", description="how the update's gradient is computed: autograd (eager or compiled), or "
        "by-hand: the loss and its chain rule written out (engine/by_hand.py), the same maths to float rounding "
        "and several times fewer ops; only the plain actor-critic (PPO, VPG, MLPP, teacher training), one seed "
        "at a time, never compiled")

    @property
    def batch_size(self) -> int:
        return self.n_steps * self.num_envs

    # Decided by --compile/--no-compile (auto from the run's size), not set one by one.
    NOT_SETTABLE: ClassVar[frozenset[str]] = frozenset({"compile_loss", "compile_reason"})

    @classmethod
    def settable(cls) -> list[str]:
        """The settings `--ppo KEY=VALUE` and a grid method's `ppo = {…}` may change."""
        return [k for k in cls.model_fields if k not in cls.NOT_SETTABLE]

    @classmethod
    def with_settings(cls, settings: dict[str, Any], **base: Any) -> PPOConfig:
        """`base` (the command's own flags) with the user's settings on top; an unknown key or a bad value is
        one MiktError naming the valid keys or the field. A setting given twice (a flag and --ppo) is refused."""
        from pydantic import ValidationError

        from miktcli.errors import describe_validation_error

        unknown = sorted(set(settings) - set(cls.settable()))
        if unknown:
            raise MiktError(f"unknown PPO setting '{unknown[0]}'; the settings are: {', '.join(cls.settable())}")
        twice = sorted(k for k in settings if base.get(k) is not None)
        if twice:
            raise MiktError(f"PPO setting '{twice[0]}' is given twice (its own flag and --ppo / the grid's ppo)")
        try:
            return cls(**{k: v for k, v in base.items() if v is not None}, **settings)
        except ValidationError as err:
            raise MiktError(f"bad PPO setting: {describe_validation_error(err)}") from err

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> PPOConfig:
        """A config read back from a card or run, of any version (see compat.ppo_record)."""
        return cls.model_validate(compat.ppo_record(record))


class Minibatch(NamedTuple):
    obs: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor  # under the policy that collected the rollout
    means: torch.Tensor  # that policy's action means (for KL(pi || pi_old))
    advantages: torch.Tensor
    returns: torch.Tensor
    values: torch.Tensor  # that policy's value predictions (for value clipping)

    def take(self, index: torch.Tensor | slice) -> Minibatch:
        return Minibatch(*(t[index] for t in self))


class RewardScaler:
    """Scales rewards by the running std of the discounted return (baselines' VecNormalize)."""

    def __init__(self, num_envs: int, gamma: float, clip: float):
        self.gamma, self.clip = gamma, clip
        self.returns = np.zeros(num_envs)
        self.mean = np.zeros(1)
        self.var = np.ones(1)
        self.count = 0.0

    def __call__(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
        self.returns = self.returns * self.gamma + rewards
        self.count = update_moments(self.mean, self.var, self.count, self.returns[:, None])
        self.returns[dones] = 0.0
        return np.clip(rewards / np.sqrt(self.var + 1e-8), -self.clip, self.clip)

    def scale_one(self, reward: float, done: bool) -> float:
        """`self(...)` for one env, in Python floats: the same IEEE operations in the same order as the array
        path's (update_moments' one-sample branch), so the same bits, without ~8 µs of small-array numpy."""
        ret = float(self.returns[0]) * self.gamma + reward
        mean, var, count = float(self.mean[0]), float(self.var[0]), self.count
        total = count + 1.0
        delta = ret - mean
        mean += delta / total
        var = (var * count + delta * (ret - mean)) / total
        self.mean[0], self.var[0], self.count = mean, var, total
        self.returns[0] = 0.0 if done else ret
        return min(max(reward / math.sqrt(var + 1e-8), -self.clip), self.clip)

    def state(self) -> dict[str, torch.Tensor]:
        return {
            "returns": torch.from_numpy(self.returns.copy()),
            "moments": torch.tensor([self.mean[0], self.var[0], self.count], dtype=torch.float64),
        }

    def load(self, state: dict[str, torch.Tensor]) -> None:
        self.returns = state["returns"].numpy().copy()
        self.mean[0], self.var[0], self.count = (float(v) for v in state["moments"])

def compute_gae(
    rewards: np.ndarray, values: np.ndarray, next_values: np.ndarray, terminated: np.ndarray,
    dones: np.ndarray, gamma: float, lam: float,
) -> tuple[np.ndarray, np.ndarray]:
    """GAE over (T, N) arrays.

    next_values[t] is V of the state after step t: of the next observation while the episode goes on,
    of the final observation where it was truncated (bootstrap), anything where it terminated (masked).
    dones[t] (terminated or truncated) stops the advantage from flowing across an episode boundary.
    """
    advantages = np.zeros_like(rewards)
    last = np.zeros(rewards.shape[1])
    for t in range(rewards.shape[0] - 1, -1, -1):
        delta = rewards[t] + gamma * next_values[t] * (1.0 - terminated[t]) - values[t]
        last = delta + gamma * lam * (1.0 - dones[t]) * last
        advantages[t] = last
    return advantages, advantages + values


def compiled(loss: Callable[..., Any]) -> Callable[..., Any]:
    """`loss` through torch.compile (shapes fixed: every full minibatch has the same). A compile that fails
    (no C++ compiler, an unsupported build) is an error naming the option, never a silent eager fallback."""
    import torch._dynamo
    import torch._inductor.config

    # Compile in this process: no pool of compile-worker processes beside a trainer that owns one core (and
    # none left behind in a test session or a Ray worker).
    torch._inductor.config.compile_threads = 1
    # One graph per agent class, shape and schedule phase, shared by every trainer in the process (a serial
    # study's cells reuse them). Past the limit dynamo would fall back to eager without a word: raise instead.
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 64)
    torch._dynamo.config.fail_on_recompile_limit_hit = True
    fast = torch.compile(loss, dynamic=False)

    def call(*args: Any) -> Any:
        try:
            return fast(*args)
        except (torch._dynamo.exc.TorchDynamoException, torch._dynamo.exc.FailOnRecompileLimitHit) as err:
            reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise MiktError(f"compile_loss: torch.compile failed ({reason}); train without --compile: "
                            "--no-compile (a resume takes it too)") from err

    return call


def complete_state(module: ActorCritic, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """`state` with the module's optional tensors it lacks (an older checkpoint) at their initial values, and
    without those it has and the module ignores."""
    own = module.state_dict()
    kept = {k: v for k, v in state.items() if k in own or not module.ignores_state(k)}
    return {**{k: own[k] for k in module.optional_state() - state.keys()}, **kept}


@contextmanager
def flushing_denormals(on: bool) -> Iterator[None]:
    """Subnormal floats read and written as zero inside (this thread's FTZ/DAZ flags; torch's update runs on
    it: the engine sets one thread). Off outside, so the rollout and MuJoCo's physics keep IEEE arithmetic."""
    if not on:
        yield
        return
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def state_misfit(module: torch.nn.Module, state: dict[str, torch.Tensor]) -> str | None:
    """What keeps `state` from loading into `module` (missing, unexpected or mis-shaped tensors), or None.
    Checked before loading so that a checkpoint of another model is refused with its reason, not torch's."""
    wanted = module.state_dict()
    optional = module.optional_state() if isinstance(module, ActorCritic) else set()
    missing = sorted(wanted.keys() - state.keys() - optional)
    extra = sorted(k for k in state.keys() - wanted.keys()
                   if not (isinstance(module, ActorCritic) and module.ignores_state(k)))
    if missing or extra:
        return f"agent tensors do not fit this run's model: missing {missing[:3]}, unexpected {extra[:3]}"
    bad = [k for k, v in state.items() if k in wanted and v.shape != wanted[k].shape]
    if bad:
        return (f"agent tensor '{bad[0]}' has shape {tuple(state[bad[0]].shape)}, the model needs "
                f"{tuple(wanted[bad[0]].shape)}")
    return None


def update_metrics(means: dict[str, float], first_ratio_dev: float, batch: Minibatch) -> dict[str, float]:
    """An update's metrics row: the minibatch logs' means, the first minibatch's ratio deviation (0 unless
    the rollout's policy differs from the trained one) and the value function's explained variance."""
    returns, values = batch.returns, batch.values
    var_y = float(returns.var())
    return {**means, "first_minibatch_ratio_dev": first_ratio_dev,
            "explained_variance": float("nan") if var_y == 0 else 1 - float((returns - values).var()) / var_y}


def iterations_for(total_steps: int, config: PPOConfig) -> int:
    """How many iterations (rollout + update) a budget of `total_steps` trains: at least one."""
    return max(1, total_steps // config.batch_size)


class PPOTrainer:
    """Trains an ActorCritic on a vector of envs. Iterate `run()` to get one metrics dict per update."""

    def __init__(
        self,
        agent: ActorCritic,
        make_env: Callable[[], gym.Env],
        config: PPOConfig,
        total_steps: int,
        seed: int,
    ):
        self.agent, self.config, self.seed = agent, config, seed
        torch.set_num_threads(config.torch_threads)  # the same numbers from the CLI, a script or a notebook
        self.total_steps = total_steps
        self.num_iterations = iterations_for(total_steps, config)
        self.iteration = 0
        self.global_step = 0
        self.envs = SyncEnvs([make_env() for _ in range(config.num_envs)], seed,
                             clip_actions=config.clip_actions_for_env, lean=config.lean_env)
        self.rng = np.random.default_rng(seed)
        self.torch_gen = torch.Generator().manual_seed(seed)
        self.reward_scaler = RewardScaler(config.num_envs, config.gamma, config.reward_clip)
        self.agent.obs_normalizer.frozen = not config.obs_normalization
        with torch.no_grad():
            self.agent.log_std.fill_(config.log_std_init)
        self.flat = FlatParameters([p for p in agent.parameters() if p.requires_grad])
        self.optimizer = FusedAdam([self.flat.flat], lr=config.learning_rate, eps=config.adam_eps)
        self._minibatch_loss = compiled(self.loss) if config.compile_loss else self.loss
        self._by_hand = self._hand_gradients() if config.gradients == "by-hand" else None
        self.recent_returns: deque[float] = deque(maxlen=100)
        self.recent_lengths: deque[int] = deque(maxlen=100)
        self.episodes = 0

    def _hand_gradients(self) -> HandGradients:
        why = unsupported(self.agent)
        if why is not None:
            raise MiktError(f"gradients=by-hand: {why}; train with gradients=autograd")
        if self.config.compile_loss:
            raise MiktError("gradients=by-hand computes no loss to compile: train with --no-compile")
        return HandGradients(self.agent, self.config)

    # --- rollout ------------------------------------------------------------------------------------
    def rollout_collector(self, obs_in: np.ndarray | None = None) -> RolloutCollector:
        """This trainer's next rollout, a step at a time (the seeds-together rollout steps several at once)."""
        cfg = self.config
        return RolloutCollector(self.agent, self.envs, cfg.n_steps, self.rng,
                                self.reward_scaler if cfg.reward_scaling else None, obs_in)

    def finish_rollout(self, collector: RolloutCollector) -> tuple[Rollout, dict[str, float]]:
        """The collected rollout and its stats; its finished episodes join the recent returns."""
        for ret, length in collector.finished:
            self.recent_returns.append(ret)
            self.recent_lengths.append(length)
        self.episodes += len(collector.finished)
        return collector.finish()

    def collect(self) -> tuple[Rollout, dict[str, float]]:
        collector = self.rollout_collector()
        actor = self.agent.rollout_actor(torch.from_numpy(collector.obs_in))
        clock = time.perf_counter
        # inference_mode, not no_grad: nothing made here reaches autograd (it all goes to numpy buffers), and
        # it skips view and version tracking, a measurable share of a step this small.
        with torch.inference_mode():
            for _ in range(collector.steps):
                t0 = clock()
                collector.observe()
                mean = actor().numpy()
                collector.act(mean, clock() - t0)
        return self.finish_rollout(collector)

    # --- advantages ---------------------------------------------------------------------------------
    def _values_and_targets(self, ro: Rollout) -> Minibatch:
        cfg, agent = self.config, self.agent
        T, N = ro.rewards.shape
        obs = torch.from_numpy(ro.obs.reshape(T * N, -1))
        with torch.no_grad():
            # One batched pass after the rollout: the network did not change during it.
            mean, values = agent.mean_and_value(obs)
            values = values.numpy().reshape(T, N).astype(np.float64)
            last_values = agent.value(torch.from_numpy(ro.last_obs)).numpy().astype(np.float64)
            next_values = np.concatenate([values[1:], last_values[None]], axis=0)
            if ro.final_obs and cfg.bootstrap_truncation:
                keys = list(ro.final_obs)
                finals = agent.value(torch.from_numpy(np.stack([ro.final_obs[k] for k in keys])))
                for (t, i), v in zip(keys, finals.numpy(), strict=True):
                    next_values[t, i] = v
            elif ro.final_obs:
                for t, i in ro.final_obs:
                    ro.terminated[t, i] = 1.0  # treat the time limit as terminal, as asked
            actions = torch.from_numpy(ro.actions.reshape(T * N, -1))
            log_probs = gaussian_log_prob(actions, mean, agent.log_std)
        advantages, returns = compute_gae(
            ro.rewards, values, next_values, ro.terminated, ro.dones, cfg.gamma, cfg.gae_lambda
        )
        return Minibatch(
            obs=obs, actions=actions, log_probs=log_probs, means=mean,
            advantages=torch.from_numpy(advantages.reshape(-1).astype(np.float32)),
            returns=torch.from_numpy(returns.reshape(-1).astype(np.float32)),
            values=torch.from_numpy(values.reshape(-1).astype(np.float32)),
        )

    # --- update -------------------------------------------------------------------------------------
    def loss(self, mb: Minibatch, old_log_std: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The minibatch loss and what to log. Every weighted term is in `terms` once and the loss is their
        sum, so no term can be counted twice (the KL term once was); tests check each term's gradient.

        Every reduction is over the last (sample) dimension, so the same code takes a minibatch stacked over
        seeds, (S, B, ...), with the agent's parameters stacked likewise (miktcli.engine.together): then the
        loss and every log are (S,), one per seed."""
        cfg, agent = self.config, self.agent
        mean, value, extra = agent.evaluate_actions(mb.obs)
        new_logprob = gaussian_log_prob(mb.actions, mean, agent.log_std)
        logratio = new_logprob - mb.log_probs
        ratio = logratio.exp()
        mb_adv = mb.advantages
        if cfg.normalize_advantage and mb_adv.shape[-1] > 1:
            mb_adv = (mb_adv - mb_adv.mean(-1, keepdim=True)) / (mb_adv.std(-1, keepdim=True) + 1e-8)
        pg_loss = torch.max(-mb_adv * ratio,
                            -mb_adv * ratio.clamp(1 - cfg.clip_range, 1 + cfg.clip_range)).mean(-1)
        # CAT's unclipped term has no target (see PPOConfig.value_loss)
        v_error = value.square() if cfg.value_loss == "cat-zero-target" else (value - mb.returns).square()
        if cfg.clip_value_loss:
            v_clipped = mb.values + (value - mb.values).clamp(-cfg.clip_range, cfg.clip_range)
            v_clipped_error = (v_clipped - mb.returns).square()
            if cfg.value_loss in ("ppo2", "cat-zero-target"):
                v_loss = 0.5 * torch.max(v_error, v_clipped_error).mean(-1)
            else:  # SB3: with clip_range_vf set, only the clipped prediction's error, and no 0.5
                v_loss = v_clipped_error.mean(-1)
        else:
            v_loss = (1.0 if cfg.value_loss == "sb3" else 0.5) * v_error.mean(-1)
        terms = {"loss_policy": pg_loss, "loss_value_weighted": cfg.vf_coef * v_loss}
        if cfg.ent_coef:
            entropy = (agent.log_std + 0.5 * (1.0 + np.log(2 * np.pi))).sum(-1)
            terms["loss_entropy"] = -cfg.ent_coef * entropy
        if cfg.kl_coef:
            terms["loss_kl"] = cfg.kl_coef * gaussian_kl(mean, agent.log_std, mb.means, old_log_std).mean(-1)
        clash = terms.keys() & extra.keys()
        if clash:
            raise ValueError(f"the agent's extra loss terms reuse engine names: {sorted(clash)}")
        terms.update(extra)
        loss = torch.stack(list(terms.values())).sum(0)
        with torch.no_grad():
            logs = {
                **ratio_logs(pg_loss, v_loss, ratio, logratio, cfg.clip_range),
                **{k: v for k, v in terms.items() if k not in ("loss_policy", "loss_value_weighted")},
            }
        return loss, logs

    def update(self, batch: Minibatch) -> dict[str, float]:
        cfg, agent = self.config, self.agent
        old_log_std = agent.log_std.detach().clone()
        size = batch.obs.shape[0]
        logged: list[torch.Tensor] = []  # per-minibatch scalars, stacked once at the end (no sync per step)
        names: list[str] = []
        first_ratio_dev = 0.0
        for _epoch in range(cfg.epochs):
            # One gather per epoch; each minibatch is then a contiguous slice (a view, no copy).
            shuffled = batch.take(torch.randperm(size, generator=self.torch_gen))
            for start in range(0, size, cfg.minibatch_size):
                mb = shuffled.take(slice(start, start + cfg.minibatch_size))
                if self._by_hand is not None:
                    logs = self._by_hand(mb, old_log_std)  # writes every gradient itself
                else:
                    loss, logs = self._minibatch_loss(mb, old_log_std)
                    self.flat.zero_grad()
                    loss.backward()
                logs["grad_norm"] = self.flat.clip_grad_norm(cfg.max_grad_norm)
                self.optimizer.step()
                if not logged:
                    first_ratio_dev = float(logs["ratio_dev"])
                    names = [k for k in logs if k != "ratio_dev"]
                logged.append(torch.stack([logs[k].detach() for k in names]))
        return update_metrics(dict(zip(names, torch.stack(logged).mean(0).tolist(), strict=True)),
                              first_ratio_dev, batch)

    # --- the loop -----------------------------------------------------------------------------------
    def run(self) -> Iterator[dict[str, Any]]:
        while self.iteration < self.num_iterations:
            lr = self.begin_iteration()
            t_start = time.perf_counter()
            rollout, stats = self.collect()
            t_rollout = time.perf_counter() - t_start
            with flushing_denormals(self.config.flush_denormal):
                batch = self._values_and_targets(rollout)
                losses = self.update(batch)
                self.observe(batch)
            yield self.end_iteration(lr, stats, losses, t_rollout, time.perf_counter() - t_start - t_rollout)

    # The loop's pieces, which miktcli.engine.together also drives for several trainers in lock step.
    def begin_iteration(self) -> float:
        """Place the schedule and the learning rate for the next iteration; returns the learning rate."""
        cfg = self.config
        progress = self.iteration / self.num_iterations
        self.agent.set_progress(progress)
        lr = cfg.learning_rate * (1.0 - progress if cfg.lr_schedule == "linear" else 1.0)
        self.optimizer.lr = lr
        return lr

    def observe(self, batch: Minibatch) -> None:
        with torch.no_grad():
            self.agent.observe_rollout(batch.obs, (self.iteration + 1) / self.num_iterations)

    def end_iteration(self, lr: float, stats: dict[str, Any], losses: dict[str, float], t_rollout: float,
                      t_update: float) -> dict[str, Any]:
        """Count the iteration done; its metrics row."""
        cfg = self.config
        self.iteration += 1
        self.global_step += cfg.batch_size
        return {
            "iteration": self.iteration,
            "steps": self.global_step,
            "episodes": self.episodes,
            "return_mean": float(np.mean(self.recent_returns)) if self.recent_returns else float("nan"),
            "length_mean": float(np.mean(self.recent_lengths)) if self.recent_lengths else float("nan"),
            "lr": lr,
            "log_std_mean": float(self.agent.log_std.detach().mean()),
            "steps_per_sec": cfg.batch_size / (t_rollout + t_update),
            "time_rollout": t_rollout,
            "time_update": t_update,
            **stats,
            **losses,
            **self.agent.diagnostics(),
        }

    # --- state for checkpoints and resume -----------------------------------------------------------
    def state_tensors(self) -> dict[str, torch.Tensor]:
        state = {f"agent.{k}": v.detach().clone().contiguous() for k, v in self.agent.state_dict().items()}
        for k, v in self.optimizer.state_of(self.flat.flat).items():
            state[f"optim.{k}"] = v.clone().contiguous()
        for k, v in self.reward_scaler.state().items():
            state[f"reward_scaler.{k}"] = v
        env_arrays, _ = self.envs.state()
        for k, v in env_arrays.items():
            state[f"envs.{k}"] = torch.from_numpy(v)
        return state

    def progress_state(self) -> dict[str, Any]:
        return {
            "iteration": self.iteration, "global_step": self.global_step, "episodes": self.episodes,
            "recent_returns": list(self.recent_returns), "recent_lengths": list(self.recent_lengths),
            "numpy_rng": self.rng.bit_generator.state, "torch_rng": self.torch_gen.get_state().tolist(),
            "envs": self.envs.state()[1],
        }

    REQUIRED_PROGRESS = ("iteration", "global_step", "episodes", "recent_returns", "recent_lengths", "numpy_rng",
                         "torch_rng")

    def load_state(self, tensors: dict[str, torch.Tensor], progress: dict[str, Any]) -> None:
        """Restore a checkpoint. Raises ValueError naming what is missing or does not fit (nothing is
        changed then). A checkpoint without env state (mikt 0.1, see compat) starts fresh episodes."""
        def part(prefix: str) -> dict[str, torch.Tensor]:
            return {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}

        agent_state, opt_state, scaler_state = part("agent."), part("optim."), part("reward_scaler.")
        problem = state_misfit(self.agent, agent_state)
        if problem:
            raise ValueError(problem)
        flat = self.flat.flat
        for key in ("step", "exp_avg", "exp_avg_sq"):
            if key not in opt_state:
                raise ValueError(f"no optimiser state 'optim.{key}'")
        for key in ("exp_avg", "exp_avg_sq"):
            if opt_state[key].shape != flat.shape:
                raise ValueError(f"optimiser state 'optim.{key}' has shape {tuple(opt_state[key].shape)}, "
                                 f"the model has {flat.numel()} parameters")
        if set(scaler_state) != {"returns", "moments"}:
            raise ValueError("no reward-scaler state ('reward_scaler.returns', 'reward_scaler.moments')")
        lost = [k for k in self.REQUIRED_PROGRESS if k not in progress]
        if lost:
            raise ValueError(f"progress lacks '{lost[0]}'")
        env_arrays = {k: v.numpy() for k, v in part("envs.").items()}

        self.agent.load_state_dict(complete_state(self.agent, agent_state))  # in place: flat views survive
        self.optimizer.load_state_of(flat, opt_state)
        self.reward_scaler.load(scaler_state)
        self.iteration = progress["iteration"]
        self.global_step = progress["global_step"]
        self.episodes = progress["episodes"]
        self.recent_returns.extend(progress["recent_returns"])
        self.recent_lengths.extend(progress["recent_lengths"])
        self.rng.bit_generator.state = progress["numpy_rng"]
        self.torch_gen.set_state(torch.tensor(progress["torch_rng"], dtype=torch.uint8))
        if env_arrays and "envs" in progress:
            self.envs.load_state(env_arrays, progress["envs"])
        if self.iteration > 0:  # the schedule where the checkpoint's last iteration had it
            self.agent.restore_progress((self.iteration - 1) / self.num_iterations)

    def close(self) -> None:
        self.envs.close()
