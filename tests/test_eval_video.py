"""`mikt eval --video`: every asked episode in one MP4, back to back, at the model's real rate (subsampled to at
most 60 fps, so a 125 Hz model's clip plays in real time), with progress on stderr and the frame cap told."""

import json
from types import SimpleNamespace

import imageio.v2 as imageio
import pytest

from helpers import mikt


def mp4_frames(path) -> tuple[int, float]:
    reader = imageio.get_reader(path)
    try:
        return reader.count_frames(), reader.get_meta_data()["fps"]
    finally:
        reader.close()


@pytest.mark.slow
def test_a_video_holds_every_episode_back_to_back_in_real_time(teacher, tmp_path):
    video = tmp_path / "v.mp4"
    r = mikt("eval", "tiny", "--episodes", 2, "--video", video, "--json")
    data = json.loads(r.stdout)
    per_episode = data["video_episode_frames"]
    assert len(per_episode) == 2 and all(n > 0 for n in per_episode)  # both episodes, not only the first
    assert data["video_frames"] == sum(per_episode) and data["video_cut_in_episode"] is None
    # hopper steps at 125 Hz (timestep 0.002 × frame_skip 4): one step in 3 is kept, 41.7 fps, real time
    assert (data["video_model_fps"], data["video_every"], data["video_fps"]) == (125.0, 3, 41.667)
    frames, fps = mp4_frames(video)
    assert frames == data["video_frames"] and fps == pytest.approx(41.67, abs=0.01)
    assert video.with_suffix(".png").is_file()
    # progress on stderr: what is recorded at which rate, then each episode as it ends
    assert "recording one step in 3 at 41.7 fps, real time (the model runs 125.0 steps a second)" in r.stderr
    for n in (1, 2):
        assert f"tiny: episode {n}/2, return " in r.stderr and f"{per_episode[n - 1]} frames recorded" in r.stderr
    assert f"wrote {video} ({data['video_frames']} frames" in r.stderr and "2 whole episode(s)" in r.stderr


def test_the_frame_cap_stops_the_video_not_the_evaluation(teacher, tmp_path):
    video = tmp_path / "v.mp4"
    r = mikt("eval", "tiny", "--episodes", 2, "--video", video, "--video-frames", 5, "--json")
    data = json.loads(r.stdout)
    assert data["episodes"] == 2  # both evaluated
    assert data["video_frames"] == 5 and data["video_episode_frames"] == [5, 0] and data["video_cut_in_episode"] == 1
    assert mp4_frames(video)[0] == 5
    assert ("warning: the video stopped at 5 frames (--video-frames 5) in episode 1 of 2; the evaluation went on. "
            "For every episode whole, ask fewer --episodes or up to --video-frames 3,000") in r.stderr


def test_an_evaluation_without_a_video_shows_progress(teacher):
    r = mikt("eval", "tiny", "--episodes", 2)
    assert "evaluating tiny@v1 on hopper: 2 episode(s)" in r.stderr and "recording" not in r.stderr
    assert "tiny: episode 1/2, return " in r.stderr and "tiny: episode 2/2, return " in r.stderr
    assert "frames recorded" not in r.stderr and "over 2 episodes" in r.stdout


def test_a_policy_failure_while_recording_is_not_called_a_write_failure(teacher, tmp_path, monkeypatch):
    from miktcli.engine.policies import ActorCritic

    calls = []
    act = ActorCritic.act

    def fails_later(self, obs, deterministic=True):
        calls.append(1)
        if len(calls) > 3:
            raise RuntimeError("the policy broke")
        return act(self, obs, deterministic)

    monkeypatch.setattr(ActorCritic, "act", fails_later)
    r = mikt("eval", "tiny", "--episodes", 1, "--video", tmp_path / "v.mp4", code=1)
    assert "RuntimeError: the policy broke" in r.output and "could not write" not in r.output
    assert list(tmp_path.glob("*.mp4")) == [] and list(tmp_path.glob(".*")) == []


@pytest.mark.parametrize("dt, every, fps", [(0.002, 9, 500 / 9),  # a Menagerie-style model stepped one by one
                                            (0.008, 3, 125 / 3),  # gymnasium's hopper
                                            (0.05, 1, 20.0),  # the centipedes
                                            (1 / 60, 1, 60.0)])  # exactly the ceiling: kept
def test_the_clip_rate_is_the_models_subsampled_to_at_most_60_fps(dt, every, fps):
    from miktcli.engine.episodes import video_rate

    env = SimpleNamespace(unwrapped=SimpleNamespace(dt=dt), metadata={"render_fps": 1})
    rate = video_rate(env)
    assert (rate.every, rate.fps) == (every, pytest.approx(fps)) and rate.fps <= 60
    assert video_rate(SimpleNamespace(unwrapped=SimpleNamespace(), metadata={"render_fps": 20})).fps == 20


def test_the_library_reports_each_episode_and_bounds_the_frames_it_keeps():
    from miktcli.engine.policies import GaussianActorCritic
    from miktcli.workflows.evaluate import evaluate_policy

    seen = []
    res = evaluate_policy(GaussianActorCritic(97, 10, [8], [8], "tanh"), "centipede-four", 2, 0, False,
                          capture_episodes=2, max_frames=30, on_episode=seen.append)
    assert [(e.number, e.episodes) for e in seen] == [(1, 2), (2, 2)]
    assert res.rate.every == 1 and res.fps == 20  # centipede: 0.01 s × 5, already real time
    assert len(res.frames) == sum(res.episode_frames) <= 30 and len(res.episode_frames) == 2
    assert [e.frames for e in seen] == res.episode_frames
