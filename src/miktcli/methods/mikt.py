"""MIKT (Wan, Gangwani, Peng, UAI 2020): the student, its encoders, lateral mixing, q_ω and the losses.

One encoder φ_k per teacher maps the (normalised) target observation to that teacher's state dimension.
The frozen teacher networks turn φ_k(s) into hidden pre-activations, which are mixed into the student's
at every hidden layer of both the policy and the value function (paper Eq. 2):

    h^j = tanh(p^j_student · z^j_student + Σ_k p^j_k · z^j_teacher_k),   p^j = softmax(logits^j)

(or, with `mixing = "shared"`, one teacher weight over Σ_k z^j_teacher_k: CAT's two logits per layer).

All losses are returned together so that one backward of their sum gives every parameter group exactly
Algorithm 1's gradient: θ, ψ ← L_PPO; φ ← L_PPO + L_MI; ω ← L_MI; p ← L_PPO + L_coupling; teachers ← none.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import nn
from torch.nn import functional as F

from miktcli.engine.adam import FusedAdam
from miktcli.engine.nets import MLP, ObsNormalizer, affine_into, linear, transposed
from miktcli.engine.policies import LOG_2PI, TEACHER_FREE, ActorCritic, GaussianActorCritic, gaussian_kl, over_rows
from miktcli.errors import MiktError
from miktcli.methods.base import Method
from miktcli.methods.mixing import student_key, teacher_key, teacher_sources

STUDENT_LOGIT_INIT = -0.1  # reference code: p_student starts at softmax([-0.1, 0.01])[0] = 0.4725
TEACHER_LOGIT_INIT = 0.01
AUTHORS_OUTPUT_GAIN = math.sqrt(2.0)  # the authors' init gain for the output layers of φ and q_ω
HANDOVER_WINDOW = "handover-window"  # the schedule's phase just before the drop


def lateral_projections(hidden: list[int]) -> nn.ModuleList:
    """One learnable square matrix per hidden layer (the authors' U: no bias, Glorot-uniform)."""
    layers = nn.ModuleList(nn.Linear(h, h, bias=False) for h in hidden)
    for layer in layers:
        nn.init.xavier_uniform_(layer.weight)
    return layers


class MiktConfig(BaseModel):
    """MIKT's own options; recorded in every run card."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # an inf or NaN coefficient poisons every loss

    coupling_schedule: Literal["constant", "three-phase"] = Field(
        "three-phase",
        description="constant: the paper's L_coupling throughout. three-phase (authors' code): coefficient 0 "
        "until 45% of training, linear ramp to its value until 90%, then the teacher is dropped (p = 1)",
    )
    coupling_pi_coef: float = Field(1.0, ge=0)
    coupling_vf_coef: float = Field(0.1, ge=0)
    mi: bool = Field(True, description="train the encoder with L_MI (off: the 'w/o MI' ablation)")
    mi_coef: float = Field(0.5, ge=0)
    mi_log_std_min: float = Field(-5.0, description="clamp of q's log-std; constant obs dims make L_MI unbounded")
    mi_log_std_clamp: bool = Field(True, description="clamp q's log-std at mi_log_std_min (ours). Off: no clamp, "
                                   "as in the authors' and CAT's code, where it drifts to about −9")
    rl_encoder_grad: bool = Field(True, description="PPO gradient into φ (off: 'w/o RL gradients' ablation)")
    ramp_start: float = Field(0.45, ge=0, le=1, description="fraction of training where the coupling ramp starts")
    drop_teacher_at: float = Field(0.90, ge=0, le=1, description="fraction where the ramp ends, teacher dropped")
    lateral: Literal["identity", "projection"] = Field(
        "identity",
        description="identity (the paper: no learnable matrix transforms the teacher representation); "
        "projection (the authors' code): each teacher pre-activation times a learnable square matrix U, no "
        "bias, Glorot-uniform init, before mixing")
    mixing: Literal["per-teacher", "shared"] = Field(
        "per-teacher",
        description="per-teacher (the authors' MIKT code): one logit per source, p = softmax([student, teacher 1 "
        "… K]), h = tanh(p_s z_s + Σ_k p_k z_k). shared (CAT's published checkpoints, inferred from their two "
        "logits per layer): p = softmax([student, teachers]), h = tanh(p_s z_s + p_t Σ_k z_k), one teacher "
        "share over the sum of the (projected) teacher pre-activations. With one teacher the two are the same")
    coupling_ramp: Literal["coefficient", "student-weight"] = Field(
        "coefficient",
        description="what the three-phase ramp r(t) (0 → 1) paces. coefficient (the authors' code): L_coupling's "
        "coefficient is c·r(t). student-weight: r(t) is a floor on every layer's student weight, L_coupling = "
        "c·mean_j max(0, log r(t) − log p^j), so the teacher is pushed out no faster than the ramp. Why: Adam "
        "normalises each parameter's step, so once L_coupling's gradient outweighs PPO's on a mixing logit, the "
        "logit moves at Adam's rate whatever c·r(t) is, and p^j reaches ~1 long before the ramp ends")
    handover: Literal["drop", "fold", "fold-linear", "fold-fit", "distil", "fade"] = Field(
        "drop",
        description="how the three-phase schedule hands the policy and value over to the student at the drop. "
        "drop (the authors' code): the teachers, encoders and q are removed and every layer computes "
        "tanh(z_student), whatever share p^j the teachers still had. fold: function-preserving to first order: "
        "each hidden layer's weights and bias are scaled by its student weight p^j and the teachers' mean "
        "contribution Σ_k p^j_k z^j_k (over recent rollouts) is added to its bias. fold-linear: as fold, but "
        "the teachers' contribution is replaced by its least-squares fit on the layer's input (a linear map "
        "plus a bias) instead of its mean. fold-fit: fold-linear, then the teacher-free policy and value "
        "(every layer) are regressed onto the mixed network's outputs on the observations of the last "
        "rollouts before the drop (fit_states of them, kept in the checkpoint): fit_steps of full-batch Adam, "
        "every 10th state held out, the best held-out weights kept, so it never ends worse than fold-linear "
        "on them; no extra environment steps. distil: over the handover_window before the drop, the teacher-free "
        "path is trained to match the mixed policy (KL of the mixed policy to it) and value, then dropped. "
        "fade: over the handover_window the teachers' weights are scaled down to 0 and the student's up to 1 "
        "(p_s + u(1 − p_s), (1 − u) p_k, u: 0 → 1 across the window) while PPO trains on, so the network at "
        "the drop is already (almost) the teacher-free student")
    handover_window: float = Field(
        0.05, gt=0, lt=1, description="distil: the fraction of training before the drop during which the "
        "teacher-free path is distilled; fold, fold-linear: unused (their statistics are a running mean over "
        "recent rollouts, half-life one rollout)")
    distil_coef: float = Field(1.0, ge=0, description="distil: weight of KL(mixed ‖ teacher-free) + "
                               "0.5·(V_teacher-free − V_mixed)² in the loss during the handover window")
    fit_states: int = Field(8192, ge=64, le=262_144, description="fold-fit: how many of the last rollouts' "
                            "observations the fit uses (a ring, in every checkpoint of a fold-fit run)")
    fit_steps: int = Field(400, ge=1, le=100_000, description="fold-fit: full-batch Adam steps of the fit")
    fit_lr: float = Field(1e-3, gt=0, le=1, description="fold-fit: the fit's Adam learning rate")

    @model_validator(mode="after")
    def _ramp_has_length(self) -> MiktConfig:
        # the ramp divides by its length: an empty or reversed one has no meaning
        if self.ramp_start >= self.drop_teacher_at:
            raise ValueError(f"ramp_start ({self.ramp_start}) must be below drop_teacher_at ({self.drop_teacher_at})")
        if self.coupling_ramp != "coefficient" and self.coupling_schedule != "three-phase":
            raise ValueError(f"coupling_ramp '{self.coupling_ramp}' paces the three-phase ramp; the constant "
                             "schedule has none")
        if self.handover != "drop" and self.coupling_schedule != "three-phase":
            raise ValueError(f"handover '{self.handover}' acts at the three-phase schedule's drop; the constant "
                             "schedule never drops the teachers")
        if self.handover == "distil" and self.handover_window > self.drop_teacher_at:
            raise ValueError(f"handover_window ({self.handover_window}) is longer than the training before the "
                             f"drop ({self.drop_teacher_at})")
        return self

    def phase(self, fraction: float) -> str:
        """The schedule's phase at a fraction of training; a run keeps a checkpoint at each change. The
        hand-over window (the ramp's last handover_window) is one for every hand-over, so that every run keeps
        the checkpoint a distil branch starts from; only distil trains differently in it."""
        if self.coupling_schedule == "constant":
            return "coupled"
        if fraction >= self.drop_teacher_at:
            return TEACHER_FREE
        if fraction >= self.drop_teacher_at - self.handover_window:
            return HANDOVER_WINDOW
        return "ramp" if fraction > self.ramp_start else "independent"


class GaussianDecoder(nn.Module):
    """q_ω(s | e): diagonal Gaussian, mean = MLP(e), state-independent learned log-std (clamped)."""

    def __init__(self, emb_dim: int, obs_dim: int, hidden: list[int], log_std_min: float | None):
        super().__init__()
        self.mean = MLP(emb_dim, hidden, obs_dim, out_gain=AUTHORS_OUTPUT_GAIN)
        self.log_std = nn.Parameter(torch.zeros(obs_dim))
        self.log_std_min = log_std_min

    def neg_log_prob(self, target: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        """−log q(target | emb) per sample, averaged over the observation dimensions.

        The mean over dimensions (and, in the caller, over the batch) is the authors' own choice (their
        `reduce_mean`), not a departure; it also keeps L_MI's scale independent of the target's size (97…181
        dims). The clamp of the log-std is ours: constant observation entries otherwise drive it to −∞."""
        log_std = self.log_std.clamp(min=self.log_std_min) if self.log_std_min is not None else self.log_std
        log_std = over_rows(log_std)
        z = (target - self.mean(emb)) * torch.exp(-log_std)
        return (0.5 * z.square() + log_std + 0.5 * LOG_2PI).mean(-1)


class MiktActorCritic(ActorCritic):
    def __init__(self, obs_dim: int, act_dim: int, teachers: list[GaussianActorCritic], config: MiktConfig):
        super().__init__()
        if not teachers:
            raise ValueError("MIKT needs at least one teacher")
        pi_hidden, vf_hidden = teachers[0].pi.hidden_sizes, teachers[0].vf.hidden_sizes
        for t in teachers[1:]:
            if t.pi.hidden_sizes != pi_hidden or t.vf.hidden_sizes != vf_hidden:
                raise ValueError("all teachers must have the same hidden sizes")
        self.config = config
        self.obs_normalizer = ObsNormalizer(obs_dim)
        self.pi = MLP(obs_dim, pi_hidden, act_dim, out_gain=0.01)
        self.vf = MLP(obs_dim, vf_hidden, 1, out_gain=1.0)
        self.log_std = nn.Parameter(torch.zeros(act_dim))
        self.teachers = nn.ModuleList(teachers)
        self.teachers.requires_grad_(False)
        # φ_k: target obs → 64 → tanh → 64 → tanh → linear to teacher k's state dimension.
        self.encoders = nn.ModuleList(
            MLP(obs_dim, [64, 64], t.pi.in_features, out_gain=AUTHORS_OUTPUT_GAIN) for t in teachers)
        self.decoders = nn.ModuleList(
            GaussianDecoder(t.pi.in_features, obs_dim, [64, 64],
                            config.mi_log_std_min if config.mi_log_std_clamp else None) for t in teachers
        )
        init = [STUDENT_LOGIT_INIT] + [TEACHER_LOGIT_INIT] * mixed_sources(len(teachers), config.mixing)
        self.mix_logits_pi = nn.Parameter(torch.tensor([init] * len(pi_hidden)))
        self.mix_logits_vf = nn.Parameter(torch.tensor([init] * len(vf_hidden)))
        if config.lateral == "projection":
            self.lateral_pi = nn.ModuleList(lateral_projections(pi_hidden) for _ in teachers)
            self.lateral_vf = nn.ModuleList(lateral_projections(vf_hidden) for _ in teachers)
        else:
            self.lateral_pi = self.lateral_vf = None
        self.teacher_active = True
        self.coupling_scale, self.coupling_on = 1.0, True
        self.distilling = False
        self._fraction: float | None = None  # the schedule's last position (None: not placed yet)
        # Kept by every three-phase run, whatever its hand-over, so that a fold can be tried later from its
        # checkpoints before the drop (mikt transfer --branch); gathered only over the rollouts just before it.
        self.keeps_fold_statistics = config.coupling_schedule == "three-phase"
        if self.keeps_fold_statistics:
            self._register_fold_statistics()
        if config.handover == "fold-fit":
            # the last rollouts' normalised observations, a ring; in the checkpoint, so that a resume or a
            # branch at before-teacher-free fits on the same states
            self.register_buffer("fit_obs", torch.zeros(config.fit_states, obs_dim))
            self.register_buffer("fit_count", torch.zeros((), dtype=torch.int64))
        self.handover_fit: dict[str, float] = {}  # what the last fold-fit measured (the card records it)
        # The ramp's value as a tensor the loss reads, so a compiled loss (PPOConfig.compile_loss) takes it
        # as an input instead of compiling again for every new value; not saved (set_progress sets it).
        self.register_buffer("coupling_weight", torch.tensor(1.0), persistent=False)
        self.fading = False  # handover "fade", inside the window: fade_weight (a tensor, as above) is u
        self.register_buffer("fade_weight", torch.tensor(0.0), persistent=False)

    # --- schedule -----------------------------------------------------------------------------------
    def set_progress(self, fraction: float) -> None:
        """Move the schedule on; crossing the drop applies the hand-over (a fold changes the weights)."""
        handing_over = self._fraction is not None and self.teacher_active
        self._place(fraction)
        if not (handing_over and not self.teacher_active):
            return
        if self.config.handover == "fold-fit":
            self.fit_teachers_into_student()
        elif self.config.handover in ("fold", "fold-linear"):
            self.fold_teachers_into_student()

    def restore_progress(self, fraction: float) -> None:
        """Put the schedule where a checkpoint left it, with no hand-over (its weights already have it)."""
        self._place(fraction)

    def phase(self, fraction: float) -> str:
        return self.config.phase(fraction)

    def _place(self, fraction: float) -> None:
        cfg = self.config
        if cfg.coupling_schedule == "constant":
            scale, self.teacher_active = 1.0, True
        else:
            ramp = (fraction - cfg.ramp_start) / (cfg.drop_teacher_at - cfg.ramp_start)
            scale, self.teacher_active = min(max(ramp, 0.0), 1.0), fraction < cfg.drop_teacher_at
        # The float is what diagnostics log; the bools and the tensor are what the loss reads (a compiled loss
        # guards on the bools, which change once each, and takes the tensor as an input).
        self.coupling_scale, self.coupling_on = scale, scale > 0
        self.coupling_weight.fill_(scale)
        in_window = cfg.phase(fraction) == HANDOVER_WINDOW
        self.distilling = cfg.handover == "distil" and in_window
        self.fading = cfg.handover == "fade" and in_window
        window_start = cfg.drop_teacher_at - cfg.handover_window
        self.fade_weight.fill_(min(max((fraction - window_start) / cfg.handover_window, 0.0), 1.0)
                               if self.fading else 0.0)
        self._fraction = fraction

    # --- hand-over by folding ------------------------------------------------------------------------
    FOLD_DECAY = 0.5  # weight of the older rollouts in the running statistics (half-life: one rollout)

    def _register_fold_statistics(self) -> None:
        # Buffers, so a checkpoint carries them and a resumed run folds exactly as an uninterrupted one.
        self.register_buffer("fold_rollouts", torch.zeros(()))
        for branch, net in (("pi", self.pi), ("vf", self.vf)):
            inputs = [net.in_features, *net.hidden_sizes[:-1]]
            for j, (n_in, width) in enumerate(zip(inputs, net.hidden_sizes, strict=True)):
                self.register_buffer(f"fold_{branch}{j}_c", torch.zeros(width))
                # second moments of u = [x, 1] and of u with the contribution c (for fold-linear)
                self.register_buffer(f"fold_{branch}{j}_uu", torch.zeros(n_in + 1, n_in + 1))
                self.register_buffer(f"fold_{branch}{j}_uc", torch.zeros(n_in + 1, width))

    def optional_state(self) -> set[str]:
        """Checkpoints written before mikt kept the fold statistics lack them: they load as none kept. A
        fold-fit run's kept states are optional too, so a run of another hand-over branches into fold-fit."""
        return {k for k in self.state_dict() if k.startswith(("fold_", "fit_"))}

    def ignores_state(self, key: str) -> bool:
        """A fold-fit checkpoint's kept states, where this run hands over another way (a branch)."""
        return key.startswith("fit_")

    def _layer_terms(self, student: MLP, obs: torch.Tensor, teacher_z: list[list[torch.Tensor]],
                     weights: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per hidden layer of the mixed network: (its input x^j, the teachers' part Σ_k p^j_k z^j_k of its
        pre-activation), as `_mixed` computes them."""
        terms, x = [], obs
        for j, (w, b) in enumerate(student.layer_params):
            c = sum(weights[j, k + 1] * tz[j] for k, tz in enumerate(teacher_z))
            terms.append((x, c))
            x = torch.tanh(weights[j, 0] * F.linear(x, w, b) + c)
        return terms

    def observe_rollout(self, obs: torch.Tensor, next_fraction: float) -> None:
        """Running statistics of the teachers' contribution at every layer, for the fold at the drop: over the
        rollouts of the hand-over window and the last one before the drop. With a half-life of one rollout,
        earlier ones would weigh nothing by then, so they are not gathered (the update loop is hot)."""
        if not (self.keeps_fold_statistics and self.teacher_active
                and self.config.phase(next_fraction) in (HANDOVER_WINDOW, TEACHER_FREE)):
            return
        embs = self.embeddings(obs)
        w_pi, w_vf = self.mixing_weights()
        first = bool(self.fold_rollouts == 0)
        keep = 0.0 if first else self.FOLD_DECAY
        for branch, net, nets, lateral, weights in (
                ("pi", self.pi, [t.pi for t in self.teachers], self.lateral_pi, w_pi),
                ("vf", self.vf, [t.vf for t in self.teachers], self.lateral_vf, w_vf)):
            tz = self._teacher_z(nets, embs, lateral)
            for j, (x, c) in enumerate(self._layer_terms(net, obs, tz, weights)):
                u = torch.cat([x, torch.ones(x.shape[0], 1)], 1)
                getattr(self, f"fold_{branch}{j}_c").lerp_(c.mean(0), 1.0 - keep)
                getattr(self, f"fold_{branch}{j}_uu").lerp_(u.T @ u / u.shape[0], 1.0 - keep)
                getattr(self, f"fold_{branch}{j}_uc").lerp_(u.T @ c / u.shape[0], 1.0 - keep)
        self.fold_rollouts += 1
        if self.config.handover == "fold-fit":
            self._keep_fit_states(obs)

    def _keep_fit_states(self, obs: torch.Tensor) -> None:
        capacity = self.fit_obs.shape[0]
        obs = obs[-capacity:]  # a rollout larger than the ring: its last rows
        rows = (int(self.fit_count) + torch.arange(obs.shape[0])) % capacity
        self.fit_obs[rows] = obs
        self.fit_count += obs.shape[0]

    @torch.no_grad()
    def fold_teachers_into_student(self) -> None:
        """Make the teacher-free student compute what the mixed network computed, to first order: layer j's
        pre-activation p_s (W x + b) + c(x) becomes (p_s W + A) x + (p_s b + a), where a is c's running mean
        (fold) or (A, a) its least-squares fit on x (fold-linear; ridge 1e-6 of the mean second moment)."""
        if not self.fold_rollouts:
            raise MiktError(f"handover '{self.config.handover}': the checkpoint holds no statistics of the "
                            "teachers' contribution to fold (written before mikt kept them)",
                            hint="use --handover drop, distil or fade for this run")
        w_pi, w_vf = self.mixing_weights()
        for branch, net, weights in (("pi", self.pi, w_pi), ("vf", self.vf, w_vf)):
            for j, (w, b) in enumerate(net.layer_params):
                p_student = weights[j, 0]
                if self.config.handover in ("fold-linear", "fold-fit"):  # fold-fit starts from fold-linear
                    uu = getattr(self, f"fold_{branch}{j}_uu").double()
                    uc = getattr(self, f"fold_{branch}{j}_uc").double()
                    ridge = 1e-6 * float(uu.diagonal().mean()) + 1e-12
                    fit = torch.linalg.solve(uu + ridge * torch.eye(uu.shape[0], dtype=uu.dtype), uc).float()
                    linear, offset = fit[:-1].T, fit[-1]
                else:
                    linear, offset = torch.zeros_like(w), getattr(self, f"fold_{branch}{j}_c")
                # in place: the parameters are views into the optimiser's flat buffer
                w.mul_(p_student).add_(linear)
                b.mul_(p_student).add_(offset)

    FIT_HOLDOUT_EVERY = 10  # every 10th kept state is held out: the fit keeps the weights best on them

    @torch.no_grad()
    def fit_teachers_into_student(self) -> None:
        """fold-fit: fold-linear, then regress the teacher-free policy mean and value onto the mixed network's
        on the kept states. Policy error in units of the policy's std (½ Σ ((μ − μ*)/σ)², the KL of two
        Gaussians with that std), value error in units of the targets' variance."""
        filled = min(int(self.fit_count), self.fit_obs.shape[0])
        if filled < 2 * self.FIT_HOLDOUT_EVERY:
            raise MiktError("handover 'fold-fit': the checkpoint holds no observations to fit on (it was "
                            "written before the hand-over window, or by a run of another hand-over)",
                            hint="branch at before-handover-window, so the window's rollouts are kept")
        obs = self.fit_obs[:filled]
        embs = self.embeddings(obs)
        w_pi, w_vf = self.forward_weights()
        targets = {"pi": self._policy(obs, embs, w_pi), "vf": self._value(obs, embs, w_vf).unsqueeze(-1)}
        self.fold_teachers_into_student()
        scale = {"pi": torch.exp(self.log_std).square().reciprocal(),
                 "vf": targets["vf"].var().clamp(min=1e-8).reciprocal().expand(1)}
        held = torch.arange(filled) % self.FIT_HOLDOUT_EVERY == 0
        report = {"states": float(filled), "steps": float(self.config.fit_steps)}
        for branch, net in (("pi", self.pi), ("vf", self.vf)):
            before, after = fit_network(net, obs, targets[branch], scale[branch], held, self.config.fit_steps,
                                        self.config.fit_lr)
            report[f"{branch}_heldout_error_fold_linear"], report[f"{branch}_heldout_error_fit"] = before, after
        self.handover_fit = report

    def handover_details(self) -> dict[str, float]:
        return dict(self.handover_fit)

    # --- forward ------------------------------------------------------------------------------------
    def mixing_weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(layers, 1 + K) softmax weights for policy and value; column 0 is the student. What the mixing
        logits say (the coupling loss and the logs read these), before any fade."""
        return torch.softmax(self.mix_logits_pi, -1), torch.softmax(self.mix_logits_vf, -1)

    def _faded(self, weights: torch.Tensor) -> torch.Tensor:
        """The weights the network mixes with: as learned, or moved towards the student by the fade."""
        if not self.fading:
            return weights
        u = self.fade_weight
        return torch.cat([weights[..., :1] + u * (1.0 - weights[..., :1]), (1.0 - u) * weights[..., 1:]], -1)

    def forward_weights(self) -> tuple[torch.Tensor, torch.Tensor]:
        w_pi, w_vf = self.mixing_weights()
        return self._faded(w_pi), self._faded(w_vf)

    def embeddings(self, obs: torch.Tensor) -> list[torch.Tensor]:
        return [enc(obs) for enc in self.encoders]

    @staticmethod
    def _mixed(student: MLP, obs: torch.Tensor, teacher_z: list[list[torch.Tensor]],
               weights: torch.Tensor) -> torch.Tensor:
        x = obs
        if len(teacher_z) == 1:
            # p·z_s + (1 − p)·z_t as one lerp: fewer autograd nodes, and exactly z_s when p = 1.
            for j, (w, b) in enumerate(student.layer_params):
                x = torch.tanh(torch.lerp(teacher_z[0][j], linear(x, w, b), _layer_weight(weights, j, 0)))
            return linear(x, *student.head_params)
        for j, (w, b) in enumerate(student.layer_params):
            z = _layer_weight(weights, j, 0) * linear(x, w, b) + sum(
                _layer_weight(weights, j, k + 1) * tz[j] for k, tz in enumerate(teacher_z))
            x = torch.tanh(z)
        return linear(x, *student.head_params)

    def _teacher_input(self, emb: torch.Tensor) -> torch.Tensor:
        # "w/o RL gradients": the PPO loss may not shape φ; L_MI still reaches it through `emb`.
        return emb if self.config.rl_encoder_grad else emb.detach()

    def _teacher_z(self, nets: list[MLP], embs: list[torch.Tensor],
                   lateral: nn.ModuleList | None) -> list[list[torch.Tensor]]:
        """Each teacher's hidden pre-activations on its embedding, projected by U where the option asks."""
        tz = [net.preactivations(self._teacher_input(e)) for net, e in zip(nets, embs, strict=True)]
        if lateral is not None:
            tz = [[linear(z, u.weight) for z, u in zip(zs, us, strict=True)] for zs, us in zip(tz, lateral,
                                                                                                    strict=True)]
        if self.config.mixing == "shared" and len(tz) > 1:  # one source for the mix: Σ_k z_k per layer
            tz = [[sum(layer) for layer in zip(*tz, strict=True)]]
        return tz

    def _policy(self, obs: torch.Tensor, embs: list[torch.Tensor], weights: torch.Tensor) -> torch.Tensor:
        tz = self._teacher_z([t.pi for t in self.teachers], embs, self.lateral_pi)
        return self._mixed(self.pi, obs, tz, weights)

    def _value(self, obs: torch.Tensor, embs: list[torch.Tensor], weights: torch.Tensor) -> torch.Tensor:
        tz = self._teacher_z([t.vf for t in self.teachers], embs, self.lateral_vf)
        return self._mixed(self.vf, obs, tz, weights).squeeze(-1)

    def action_mean(self, obs: torch.Tensor) -> torch.Tensor:
        if not self.teacher_active:
            return self.pi(obs)
        return self._policy(obs, self.embeddings(obs), self._faded(torch.softmax(self.mix_logits_pi, -1)))

    def rollout_actor(self, obs: torch.Tensor) -> Callable[[], torch.Tensor]:
        """`action_mean(obs)` for the rollout's fixed input, op for op as `embeddings`, `_teacher_z` and
        `_mixed` compute it (the same kernels, so the same bits; tests/test_mikt.py checks), into buffers made
        once per rollout. The mixing weights are taken now: they only change in the update. Per step this
        saves the allocations and module calls of ~35 small ops (the MIKT rollout forward was 4-8× PPO's).
        With the parameters stacked over seeds (functional_call, miktcli.engine.together) `obs` is (S, N, in):
        every seed's rows in one batched matmul a layer, the frozen teachers once over all of them."""
        if not self.teacher_active:
            return self.pi.rollout_forward(obs)
        n = obs.shape[:-1]  # the buffers' leading shape: (N,), or (S, N)
        embed = [enc.rollout_forward(obs) for enc in self.encoders]
        with torch.no_grad():
            weights = self._faded(torch.softmax(self.mix_logits_pi, -1))
        teachers = [_RolloutPreactivations(t.pi, n) for t in self.teachers]
        lateral = ([[transposed(u.weight) for u in us] for us in self.lateral_pi]
                   if self.lateral_pi is not None else None)
        student = [(transposed(w), b.detach()) for w, b in self.pi.layer_params]
        head_w, head_b = transposed(self.pi.head_params[0]), self.pi.head_params[1].detach()
        width = [w.shape[-1] for w, _ in student]
        lin, mixed = [torch.empty(*n, h) for h in width], [torch.empty(*n, h) for h in width]
        proj = [[torch.empty(*n, h) for h in width] for _ in teachers]
        acc, term = [torch.empty(*n, h) for h in width], [torch.empty(*n, h) for h in width]
        zeros = [torch.zeros(*n, h) for h in width]
        out = torch.empty(*n, head_w.shape[-1])
        # mixing = "shared": one source per layer, Σ_k z_k (as _teacher_z sums them), then mixed as one teacher
        shared = self.config.mixing == "shared" and len(teachers) > 1
        summed = [torch.empty(*n, h) for h in width] if shared else []
        k_teachers = 1 if shared else len(teachers)
        w_rows = [[_layer_weight(weights, j, k) for k in range(weights.shape[-1])] for j in range(len(width))]
        p_student = [row[0] for row in w_rows]

        def run() -> torch.Tensor:
            tz = [t(e()) for t, e in zip(teachers, embed, strict=True)]
            if lateral is not None:
                tz = [[affine_into(z, u_t, None, buf) for z, u_t, buf in zip(zs, us, bufs, strict=True)]
                      for zs, us, bufs in zip(tz, lateral, proj, strict=True)]
            if shared:  # sum() starts at 0, as zeros + z_0 does (see below)
                tz = [[_sum_into(buf, zero, layer) for buf, zero, layer in zip(summed, zeros, zip(*tz, strict=True),
                                                                              strict=True)]]
            x = obs
            for j, (w_t, b) in enumerate(student):
                z = affine_into(x, w_t, b, lin[j])
                if k_teachers == 1:
                    x = torch.tanh_(torch.lerp(tz[0][j], z, p_student[j], out=mixed[j]))
                    continue
                w = w_rows[j]
                # sum() starts at 0: 0 + a is a, except that -0.0 becomes +0.0; a tensor of zeros does the
                # same (and costs less than adding a Python scalar)
                s = torch.add(zeros[j], torch.mul(tz[0][j], w[1], out=term[j]), out=acc[j])
                for k in range(1, k_teachers):
                    s.add_(torch.mul(tz[k][j], w[k + 1], out=term[j]))
                x = torch.tanh_(torch.add(torch.mul(z, w[0], out=mixed[j]), s, out=mixed[j]))
            return affine_into(x, head_w, head_b, out)

        return run

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        if not self.teacher_active:
            return self.vf(obs).squeeze(-1)
        return self._value(obs, self.embeddings(obs), self._faded(torch.softmax(self.mix_logits_vf, -1)))

    def mean_and_value(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # evaluate_actions's mean and value, the encoders run once, no L_MI or coupling (nothing reads them)
        if not self.teacher_active:
            return self.pi(obs), self.vf(obs).squeeze(-1)
        embs = self.embeddings(obs)
        w_pi, w_vf = self.forward_weights()
        return self._policy(obs, embs, w_pi), self._value(obs, embs, w_vf)

    def evaluate_actions(self, obs: torch.Tensor):
        if not self.teacher_active:  # the last phase: a plain MLP student, no extra losses
            return self.pi(obs), self.vf(obs).squeeze(-1), {}
        embs = self.embeddings(obs)
        w_pi, w_vf = self.mixing_weights()
        f_pi, f_vf = self._faded(w_pi), self._faded(w_vf)
        mean, value = self._policy(obs, embs, f_pi), self._value(obs, embs, f_vf)
        cfg = self.config
        losses = {}
        if self.coupling_on and (cfg.coupling_pi_coef or cfg.coupling_vf_coef):
            if cfg.coupling_ramp == "student-weight":  # the ramp is a floor on p^j: push only the layers below it
                floor = torch.log(self.coupling_weight)
                coupling = (cfg.coupling_pi_coef * (floor - torch.log(w_pi[..., 0])).clamp(min=0).mean(-1)
                            + cfg.coupling_vf_coef * (floor - torch.log(w_vf[..., 0])).clamp(min=0).mean(-1))
                losses["loss_coupling"] = coupling
            else:
                coupling = (cfg.coupling_pi_coef * -torch.log(w_pi[..., 0]).mean(-1)
                            + cfg.coupling_vf_coef * -torch.log(w_vf[..., 0]).mean(-1))
                losses["loss_coupling"] = self.coupling_weight * coupling
        if cfg.mi and cfg.mi_coef:
            mi = sum(dec.neg_log_prob(obs, e).mean(-1) for dec, e in zip(self.decoders, embs, strict=True))
            losses["loss_mi"] = cfg.mi_coef * mi
        if self.distilling and cfg.distil_coef:
            # The teacher-free path learns what the mixed network does (targets fixed), with the shared
            # log-std left out: KL(mixed ‖ teacher-free) of two Gaussians with one std is the means' term alone.
            log_std = self.log_std.detach()
            kl = gaussian_kl(mean.detach(), log_std, self.pi(obs), log_std).mean(-1)
            value_error = 0.5 * (self.vf(obs).squeeze(-1) - value.detach()).square().mean(-1)
            losses["loss_distil"] = cfg.distil_coef * (kl + value_error)
        return mean, value, losses

    def diagnostics(self) -> dict[str, float]:
        with torch.no_grad():
            p_pi, p_vf = self.mixing_weights()
        if not self.teacher_active:
            p_pi, p_vf = torch.ones_like(p_pi[:, :1]), torch.ones_like(p_vf[:, :1])
        out = {"teacher_active": float(self.teacher_active), "coupling_scale": self.coupling_scale}
        for branch, p in (("pi", p_pi), ("vf", p_vf)):
            for j in range(p.shape[0]):
                out[student_key(branch, j)] = float(p[j, 0])
        if len(self.teachers) > 1:
            # the teachers' own weights (one teacher's is 1 − p, so single-teacher metrics stay as they were);
            names = teacher_sources(mixed_sources(len(self.teachers), self.config.mixing),
                                    shared=self.config.mixing == "shared")
            for branch, p in (("pi", p_pi), ("vf", p_vf)):
                for j in range(p.shape[0]):
                    for k, name in enumerate(names):
                        out[teacher_key(branch, j, name)] = float(p[j, k + 1]) if self.teacher_active else 0.0
        return out

    # --- the teacher-free student -------------------------------------------------------------------
    def student_only(self) -> GaussianActorCritic:
        """A plain actor-critic holding the student's own weights: what the student is at p = 1."""
        plain = GaussianActorCritic(self.obs_normalizer.mean.shape[0], self.log_std.shape[0],
                                    self.pi.hidden_sizes, self.vf.hidden_sizes)
        keep = ("obs_normalizer.", "pi.", "vf.", "log_std")
        plain.load_state_dict({k: v for k, v in self.state_dict().items() if k.startswith(keep)})  # copies
        return plain


class _RolloutPreactivations:
    """`MLP.preactivations` of a frozen teacher stack into buffers made once (the rollout's batch size)."""

    def __init__(self, net: MLP, rows: tuple[int, ...]):
        self.tanh = net.activation == "tanh"
        self.act_ = {"tanh": torch.tanh_, "relu": torch.relu_}[net.activation]
        self.layers = [(transposed(w), b.detach()) for w, b in net.layer_params]
        self.z = [torch.empty(*rows, w.shape[-1]) for w, _ in self.layers]
        self.h = [torch.empty(*rows, w.shape[-1]) for w, _ in self.layers]

    def __call__(self, x: torch.Tensor) -> list[torch.Tensor]:
        for (w_t, b), z, h in zip(self.layers, self.z, self.h, strict=True):
            affine_into(x, w_t, b, z)
            x = torch.tanh(z, out=h) if self.tanh else self.act_(h.copy_(z))
        return self.z


@torch.no_grad()
def fit_network(net: MLP, obs: torch.Tensor, target: torch.Tensor, scale: torch.Tensor, held: torch.Tensor,
                steps: int, lr: float) -> tuple[float, float]:
    """Full-batch Adam on ½ mean Σ scale·(net(obs) − target)² over the rows not held out, into `net`'s
    parameters in place (views into the trainer's flat buffer: copied into, never replaced); keeps the
    weights with the lowest error on the held-out rows, checked every 10 steps. Returns the held-out error
    before and after."""
    own = dict(net.named_parameters())
    live = {name: p.detach().clone().requires_grad_(True) for name, p in own.items()}

    def error(rows: torch.Tensor) -> torch.Tensor:
        out = torch.func.functional_call(net, live, (obs[rows],))
        return 0.5 * ((out - target[rows]).square() * scale).sum(-1).mean()

    def snapshot() -> dict[str, torch.Tensor]:
        return {name: t.detach().clone() for name, t in live.items()}

    first = best = float(error(held))
    kept = snapshot()
    with torch.enable_grad():
        optimiser = FusedAdam(list(live.values()), lr=lr)
        for step in range(1, steps + 1):
            optimiser.zero_grad()
            error(~held).backward()
            optimiser.step()
            if step % 10 == 0 or step == steps:
                with torch.no_grad():
                    now = float(error(held))
                if now < best:
                    best, kept = now, snapshot()
    for name, param in own.items():
        param.copy_(kept[name])
    return first, best


def _layer_weight(weights: torch.Tensor, j: int, k: int) -> torch.Tensor:
    """Layer j's mixing weight of source k (0: the student) from (layers, sources) weights: a scalar; from
    weights stacked over seeds (S, layers, sources), (S, 1, 1), to meet each seed's rows (S, B, width)."""
    w = weights[..., j, k]
    return w if w.dim() == 0 else w[:, None, None]


def _sum_into(out: torch.Tensor, zeros: torch.Tensor, terms: tuple[torch.Tensor, ...]) -> torch.Tensor:
    """sum(terms) into `out`, bit for bit as Python's sum (which starts at 0)."""
    torch.add(zeros, terms[0], out=out)
    for t in terms[1:]:
        out.add_(t)
    return out


def mixed_sources(num_teachers: int, mixing: str = "per-teacher") -> int:
    """Teacher logits per layer: one per teacher, or one shared by all."""
    return 1 if mixing == "shared" else num_teachers


def initial_student_weight(num_teachers: int = 1, mixing: str = "per-teacher") -> float:
    logits = [STUDENT_LOGIT_INIT] + [TEACHER_LOGIT_INIT] * mixed_sources(num_teachers, mixing)
    return math.exp(logits[0]) / sum(math.exp(v) for v in logits)


def build(obs_dim: int, act_dim: int, teachers: list[GaussianActorCritic],
          hidden: tuple[list[int], list[int]], options: BaseModel | None) -> MiktActorCritic:
    assert isinstance(options, MiktConfig)
    return MiktActorCritic(obs_dim, act_dim, teachers, options)


def with_teachers(agent: ActorCritic) -> MiktActorCritic:
    """The agent mixing its teachers in with its learned weights, also after the three-phase schedule
    dropped them."""
    assert isinstance(agent, MiktActorCritic)
    agent.teacher_active = True
    return agent


def student(agent: ActorCritic) -> GaussianActorCritic:
    assert isinstance(agent, MiktActorCritic)
    return agent.student_only()


METHOD = Method(name="mikt", summary="MIKT (Algorithm 1): lateral mixing, coupling, L_MI", min_teachers=1,
                max_teachers=None, default_kl_coef=0.05, options=MiktConfig, build=build, student=student,
                with_teachers=with_teachers, encoder_per_teacher=True)
