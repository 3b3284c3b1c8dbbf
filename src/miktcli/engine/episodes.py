"""Runs a policy for a number of episodes (the low-level loop), optionally capturing frames for a video at the
model's real rate."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
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

# A clip plays in real time at the model's own rate, 1 / (timestep × frame_skip), up to this many frames a second
# (what players and screens show); a faster model (125 Hz and more, as Menagerie's) keeps every n-th step rather
# than writing a 125 fps file.
MAX_VIDEO_FPS = 60


@dataclass(frozen=True)
class VideoRate:
    model_fps: float  # env steps per simulated second: 1 / (timestep × frame_skip)
    every: int  # one frame every `every` env steps

    @property
    def fps(self) -> float:
        """The clip's rate: real time."""
        return self.model_fps / self.every


def video_rate(env: gym.Env, every: int | None = None) -> VideoRate:
    """The env's real step rate and the subsampling that keeps its clip at or under MAX_VIDEO_FPS (or `every`)."""
    dt = getattr(env.unwrapped, "dt", None)
    model_fps = 1.0 / float(dt) if dt else float(env.metadata.get("render_fps", 20))
    return VideoRate(model_fps, every or max(1, math.ceil(model_fps / MAX_VIDEO_FPS - 1e-9)))


@dataclass(frozen=True)
class EpisodeDone:
    """Progress: episode `number` (1-based) of `episodes` ended; `frames` of it are in the video."""
    number: int
    episodes: int
    ret: float
    length: int
    frames: int


@dataclass
class EvalResult:
    returns: list[float]
    lengths: list[int]
    frames: list[np.ndarray] = field(default_factory=list)  # empty where the frames were streamed (`events`)
    rate: VideoRate = VideoRate(20.0, 1)  # of the frames: the env's real rate and the subsampling
    episode_frames: list[int] = field(default_factory=list)  # frames recorded of each episode, in order
    cut_in_episode: int | None = None  # the episode (1-based) where max_frames stopped the recording
    distances: list[float] = field(default_factory=list)  # forward progress of each episode (env units, m)
    speeds: list[float] = field(default_factory=list)  # distance / simulated time

    @property
    def fps(self) -> float:
        """The frames' rate for a video that plays in real time."""
        return self.rate.fps

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


def iter_episodes(
    act: Callable[[torch.Tensor], torch.Tensor], env: gym.Env, episodes: int, seed: int, result: EvalResult,
    capture_episodes: int = 0, clip_actions: bool = False, max_frames: int | None = None,
) -> Iterator[np.ndarray | EpisodeDone]:
    """The episode loop as a stream: each recorded frame (of the first `capture_episodes`, one every
    `result.rate.every` steps, at most `max_frames` in all) as it is rendered, and an EpisodeDone as each
    episode ends; returns, lengths and distances go into `result`. Streamed, so a long video is never held in
    memory (a 480×480 frame takes 0.7 MB).

    Actions reach the env as the policy gives them unless `clip_actions` (the authors' ppo2 passed raw actions:
    MuJoCo clamps `ctrl` to the actuator range itself, and the control cost is computed on the raw action)."""
    low, high = env.action_space.low, env.action_space.high
    every, recorded = result.rate.every, sum(result.episode_frames)
    for ep in range(episodes):
        try:
            obs, _ = env.reset(seed=seed + ep)
        except Exception as err:  # noqa: BLE001 - as for step below
            raise env_failure(env, err, "reset") from err
        total, length, done, frames = 0.0, 0, False, 0
        start = forward_position(env)
        while not done:
            if ep < capture_episodes and length % every == 0:
                if max_frames is None or recorded < max_frames:
                    frames, recorded = frames + 1, recorded + 1
                    yield render_frame(env)
                elif result.cut_in_episode is None:
                    result.cut_in_episode = ep + 1
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
        if ep < capture_episodes:
            result.episode_frames.append(frames)
        end = forward_position(env)
        if start is not None and end is not None:
            result.distances.append(end - start)
            result.speeds.append((end - start) / (length * float(getattr(env.unwrapped, "dt", 1.0))))
        yield EpisodeDone(ep + 1, episodes, total, length, frames)


def run_episodes(
    act: Callable[[torch.Tensor], torch.Tensor], env: gym.Env, episodes: int, seed: int,
    capture_episodes: int = 0, frame_every: int | None = None, clip_actions: bool = False,
    max_frames: int | None = None, on_episode: Callable[[EpisodeDone], None] | None = None,
) -> EvalResult:
    """`act` maps a raw observation batch (1, obs_dim) to actions; the frames of the first `capture_episodes`
    (one every `frame_every` steps; by default the real-time subsampling of `video_rate`) are kept in
    `frames`. See `iter_episodes`."""
    result = EvalResult([], [], rate=video_rate(env, frame_every))
    for event in iter_episodes(act, env, episodes, seed, result, capture_episodes, clip_actions, max_frames):
        if isinstance(event, EpisodeDone):
            if on_episode is not None:
                on_episode(event)
        else:
            result.frames.append(event)
    return result


class Evaluation:
    """A policy's evaluation on a made env, whose frames can stream into a video while it runs (`events`)."""

    def __init__(self, policy: ActorCritic, env: gym.Env, episodes: int, seed: int, clip_actions: bool,
                 deterministic: bool, capture_episodes: int, max_frames: int):
        self.policy, self.env, self.episodes, self.seed = policy, env, episodes, seed
        self.clip_actions, self.deterministic = clip_actions, deterministic
        self.capture_episodes, self.max_frames = capture_episodes, max_frames
        self.result = EvalResult([], [], rate=video_rate(env))

    @property
    def rate(self) -> VideoRate:
        return self.result.rate

    def events(self) -> Iterator[np.ndarray | EpisodeDone]:
        """The frames and the ends of episodes as they come (see `iter_episodes`); `result` fills meanwhile."""
        return iter_episodes(lambda o: self.policy.act(o, self.deterministic), self.env, self.episodes, self.seed,
                             self.result, self.capture_episodes, self.clip_actions, self.max_frames)


@contextmanager
def evaluation(policy: ActorCritic, env_name: str, episodes: int, seed: int, clip_actions: bool,
               deterministic: bool = True, capture_episodes: int = 0,
               max_frames: int = limits.MAX_VIDEO_FRAMES) -> Iterator[Evaluation]:
    """An Evaluation on fresh episodes (normaliser frozen), its env closed after the block; frames from the
    first `capture_episodes`, at most `max_frames` of them."""
    check_count("episodes", episodes, limits.MAX_EPISODES)
    check_count("video frames", max_frames, limits.MAX_VIDEO_FRAMES)
    env = make_env(env_name, render_mode="rgb_array" if capture_episodes else None)
    policy.obs_normalizer.frozen = True
    torch.manual_seed(seed)
    try:
        yield Evaluation(policy, env, episodes, seed, clip_actions, deterministic, capture_episodes, max_frames)
    finally:
        env.close()


def evaluate_policy(policy: ActorCritic, env_name: str, episodes: int, seed: int, clip_actions: bool,
                    deterministic: bool = True, capture_episodes: int = 0,
                    max_frames: int = limits.MAX_VIDEO_FRAMES,
                    on_episode: Callable[[EpisodeDone], None] | None = None) -> EvalResult:
    """Run the policy on fresh episodes; the frames of the first `capture_episodes` (at most `max_frames`,
    held in memory: stream them with `evaluation` instead for a long video) in `frames`."""
    with evaluation(policy, env_name, episodes, seed, clip_actions, deterministic, capture_episodes,
                    max_frames) as ev:
        for event in ev.events():
            if isinstance(event, EpisodeDone):
                if on_episode is not None:
                    on_episode(event)
            else:
                ev.result.frames.append(event)
        return ev.result


def evaluation_summary(policy: ActorCritic, env_name: str, episodes: int, seed: int,
                       clip_actions: bool) -> dict[str, float]:
    return evaluate_policy(policy, env_name, episodes, seed, clip_actions).summary()
