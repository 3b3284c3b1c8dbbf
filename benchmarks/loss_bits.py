"""A single run's minibatch loss, logs and gradients on 15 configurations of PPO and MIKT, saved or compared
bit for bit: for a change meant to leave a single run's numbers exactly as they were (a refactor of the loss).

    python benchmarks/loss_bits.py save FILE    # at the commit before the change
    python benchmarks/loss_bits.py check FILE   # after it: prints every tensor that differs; exit 1 if any
"""
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
from miktcli.engine.policies import GaussianActorCritic
from miktcli.engine.ppo import PPOConfig, PPOTrainer
from miktcli.envs import make_env
from miktcli.methods.mikt import MiktActorCritic, MiktConfig


def agent(kind, mcfg):
    torch.manual_seed(100)
    if kind == "ppo":
        return GaussianActorCritic(11, 3)
    teachers = [GaussianActorCritic(13, 4).requires_grad_(False), GaussianActorCritic(7, 2).requires_grad_(False)]
    if kind == "mikt1":
        teachers = teachers[:1]
    torch.manual_seed(1)
    return MiktActorCritic(11, 3, teachers, MiktConfig(**mcfg))


CASES = {
    "ppo": ("ppo", {}, {}), "ppo-ent-kl": ("ppo", {}, dict(ent_coef=0.01, kl_coef=0.1)),
    "ppo-sb3": ("ppo", {}, dict(value_loss="sb3")), "ppo-noclip": ("ppo", {}, dict(clip_value_loss=False)),
    "m1": ("mikt1", dict(coupling_schedule="constant"), dict(kl_coef=0.1)),
    "m2": ("mikt2", dict(coupling_schedule="constant"), dict(kl_coef=0.1)),
    "m2-shared": ("mikt2", dict(coupling_schedule="constant", mixing="shared"), {}),
    "m2-proj": ("mikt2", dict(coupling_schedule="constant", lateral="projection"), {}),
    "m1-proj": ("mikt1", dict(coupling_schedule="constant", lateral="projection"), {}),
    "m2-noclamp-norl": ("mikt2", dict(coupling_schedule="constant", mi_log_std_clamp=False, rl_encoder_grad=False),
                        dict(value_loss="cat-zero-target")),
    "m2-3p-ramp": ("mikt2", dict(coupling_schedule="three-phase"), {}),  # PROGRESS places it in the ramp
    "m2-sw": ("mikt2", dict(coupling_schedule="three-phase", coupling_ramp="student-weight"), {}),
    "m2-distil": ("mikt2", dict(coupling_schedule="three-phase", handover="distil"), {}),
    "m2-fade": ("mikt2", dict(coupling_schedule="three-phase", handover="fade"), {}),
    "m2-free": ("mikt2", dict(coupling_schedule="three-phase"), {}),
}
PROGRESS = {"m2-3p-ramp": 0.6, "m2-sw": 0.6, "m2-distil": 0.87, "m2-fade": 0.87, "m2-free": 0.95}


def compute():
    out = {}
    for name, (kind, mcfg, pcfg) in CASES.items():
        a = agent(kind, mcfg)
        cfg = PPOConfig(n_steps=64, minibatch_size=64, epochs=1, **pcfg)
        t = PPOTrainer(a, lambda: make_env("hopper"), cfg, 6400, 0)
        t.agent.set_progress(PROGRESS.get(name, 0.0))
        b = t._values_and_targets(t.collect()[0])
        with torch.no_grad():  # away from the initial values, so every term has a gradient
            a.log_std.add_(0.1)
            if hasattr(a, "mix_logits_pi"):
                a.mix_logits_pi.add_(0.3)
        old = a.log_std.detach().clone() - 0.05
        loss, logs = t.loss(b, old)
        t.flat.zero_grad()
        loss.backward()
        out[name] = {"loss": loss.detach(), **{k: v.detach() for k, v in logs.items()},
                     "grad": t.flat.flat.grad.clone()}
        t.close()
    return out

def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("save", "check"):
        print(__doc__)
        return 2
    mode, path = argv
    res = compute()
    if mode == "save":
        torch.save(res, path)
        print(f"saved {len(res)} configurations to {path}")
        return 0
    ref = torch.load(path)
    bad = 0
    for name in ref:
        for key in ref[name]:
            if not torch.equal(ref[name][key], res[name][key]):
                bad += 1
                print(f"differs: {name} {key}, max abs {float((ref[name][key] - res[name][key]).abs().max()):.3g}")
    print(f"{len(ref)} configurations, {bad} tensors differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
