"""Runs a policy for a number of episodes (the low-level loop), optionally capturing frames for a video."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch

from miktcli import limits
from miktcli.engine.policies import ActorCritic
from miktcli.envs import make_env
from miktcli.envs.factory import forward_position
from miktcli.envs.failures import env_failure
from miktcli.envs.frames import render_frame
from miktcli.limits import check_count


@dataclass
class EvalResult:
    returns: list[float]
    lengths: list[int]
    frames: list[np.ndarray] = field(default_factory=list)
    fps: int = 20  # the env's render rate, for a video of the frames
    distances: list[float] = field(default_factory=list)  # forward progress of each episode (env units, m)
    speeds: list[float] = field(default_factory=list)  # distance / simulated time

    def summary(self) -> dict[str, float]:
        out = {
            "episodes": len(self.returns),
            "return_mean": float(np.mean(self.returns)), "return_std": float(np.std(self.returns)),
            "length_mean": float(np.mean(self.lengths)), "length_std": float(np.std(self.lengths)),
        }
        if self.distances:  # walking and standing can score alike where a survival bonus pays: say which
            out.update(distance_mean=float(np.mean(self.distances)), distance_std=float(np.std(self.distances)),
                       speed_mean=float(np.mean(self.speeds)))
        return out


def run_episodes(
    act: Callable[[torch.Tensor], torch.Tensor], env: gym.Env, episodes: int, seed: int,
    capture_episodes: int = 0, frame_every: int = 1, clip_actions: bool = False, max_frames: int | None = None,
) -> EvalResult:
    """`act` maps a raw observation batch (1, obs_dim) to actions; frames come from the first episodes.

    Actions reach the env as the policy gives them unless `clip_actions` (the authors' ppo2 passed raw actions:
    MuJoCo clamps `ctrl` to the actuator range itself, and the control cost is computed on the raw action)."""
    result = EvalResult([], [], fps=int(env.metadata.get("render_fps", 20)))
    low, high = env.action_space.low, env.action_space.high
    for ep in range(episodes):
        try:
            obs, _ = env.reset(seed=seed + ep)
        except Exception as err:  # noqa: BLE001 - as for step below
            raise env_failure(env, err, "reset") from err
        total, length, done = 0.0, 0, False
        start = forward_position(env)
        while not done:
            if ep < capture_episodes and length % frame_every == 0 \
                    and (max_frames is None or len(result.frames) < max_frames):
                result.frames.append(render_frame(env))
            with torch.inference_mode():  # actions go straight to numpy
                action = act(torch.as_tensor(obs, dtype=torch.float32)[None])[0].numpy()
            try:
                obs, reward, terminated, truncated, _ = env.step(np.clip(action, low, high) if clip_actions
                                                                 else action)
            except Exception as err:  # noqa: BLE001 - an env's own code: name its spec, not a mikt bug
                raise env_failure(env, err, "step") from err
            total += float(reward)
            length += 1
            done = terminated or truncated
        result.returns.append(total)
        result.lengths.append(length)
        end = forward_position(env)
        if start is not None and end is not None:
            result.distances.append(end - start)
            result.speeds.append((end - start) / (length * float(getattr(env.unwrapped, "dt", 1.0))))
    return result


def evaluate_policy(policy: ActorCritic, env_name: str, episodes: int, seed: int, clip_actions: bool,
                    deterministic: bool = True, capture_episodes: int = 0,
                    max_frames: int = limits.MAX_VIDEO_FRAMES) -> EvalResult:
    """Run the policy (normaliser frozen) on fresh episodes; frames from the first `capture_episodes`, at
    most `max_frames` of them (they are held in memory)."""
    check_count("episodes", episodes, limits.MAX_EPISODES)
    check_count("video frames", max_frames, limits.MAX_VIDEO_FRAMES)
    env = make_env(env_name, render_mode="rgb_array" if capture_episodes else None)
    policy.obs_normalizer.frozen = True
    torch.manual_seed(seed)
    try:
        with torch.no_grad():
            return run_episodes(lambda o: policy.act(o, deterministic), env, episodes, seed,
                                capture_episodes=capture_episodes, clip_actions=clip_actions, max_frames=max_frames)
    finally:
        env.close()


def evaluation_summary(policy: ActorCritic, env_name: str, episodes: int, seed: int,
                       clip_actions: bool) -> dict[str, float]:
    return evaluate_policy(policy, env_name, episodes, seed, clip_actions).summary()
