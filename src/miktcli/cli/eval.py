"""`mikt eval`: evaluate a teacher or a run's student; optionally render an MP4 offscreen."""

from __future__ import annotations

from pathlib import Path

import typer

from miktcli import limits
from miktcli.cli.common import DEFAULT_REGISTRY, JsonOption, RegistryOption, setup_torch
from miktcli.cli.console import err, print_data, print_json

HELP = """Evaluate a teacher (NAME or NAME@vN) or a run's student (runN); with no target, the newest run (last).

Examples:

  mikt eval --render-offscreen

  mikt eval hopper --episodes 20

  mikt eval run3 --with-teacher

  mikt eval run3 --render-offscreen --video run3.mp4
"""


def eval_command(
    target: str = typer.Argument("last", help="Teacher NAME or NAME@vN, runN, or last (the newest run).",
                                 show_default=True),
    episodes: int = typer.Option(10, "--episodes", min=1, max=limits.MAX_EPISODES),
    seed: int = typer.Option(0, "--seed", min=0, max=2**32 - 1,
                             help="Seed of the first episode; episode i uses seed + i."),
    deterministic: bool = typer.Option(True, "--deterministic/--stochastic", help="Mean action or sampled."),
    with_teacher: bool = typer.Option(False, "--with-teacher", help="Runs: evaluate the student with its teacher."),
    render_offscreen: bool = typer.Option(False, "--render-offscreen", help="Write an MP4 and a PNG poster."),
    video: Path = typer.Option(None, "--video", help="MP4 path (default: TARGET-eval.mp4); implies rendering."),
    video_frames: int = typer.Option(300, "--video-frames", min=1, max=limits.MAX_VIDEO_FRAMES,
                                     help="Frames to record from episode 1."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.envs.frames import save_mp4, save_png
    from miktcli.outfiles import prepare_output
    from miktcli.workflows.evaluate import evaluate_policy, load_policy

    setup_torch()
    if target == "last":  # name the newest run, so its video file and the summary say which run it was
        from miktcli.registry.runs import open_run

        target = open_run(registry, "last").id
    if seed + episodes - 1 > 2**32 - 1:
        raise typer.BadParameter(f"episode seeds run from {seed} to {seed + episodes - 1}, past 2³²−1",
                                 param_hint="'--seed'")
    render = render_offscreen or video is not None
    if video is not None and video.suffix.lower() != ".mp4":  # its poster goes beside it as .png
        raise typer.BadParameter(f"{video} is not an .mp4 path (the video is MP4; its poster is written beside "
                                 "it as .png)", param_hint="'--video'")
    if render:  # refuse an unwritable path before the episodes, not after them
        video = prepare_output(video or Path(f"{target.replace('@', '-')}-eval.mp4"))
        prepare_output(video.with_suffix(".png"))
    policy, env_name, label, clip_actions = load_policy(registry, target, with_teacher)
    res = evaluate_policy(policy, env_name, episodes, seed, clip_actions, deterministic,
                          capture_episodes=1 if render else 0, max_frames=video_frames)
    summary = {"target": target, "policy": label, "env": env_name, "deterministic": deterministic,
               "clip_actions_for_env": clip_actions,
               **res.summary()}
    if render:
        frames = res.frames[:video_frames]
        save_mp4(frames, video, fps=res.fps)
        poster = save_png(frames[len(frames) // 2], video.with_suffix(".png"))
        summary.update(video=str(video), poster=str(poster))
        err.print(f"wrote {video} ({len(frames)} frames) and {poster}")
    if as_json:
        print_json(summary)
        return
    moved = (f", forward {summary['distance_mean']:.2f} ± {summary['distance_std']:.2f} m "
             f"({summary['speed_mean']:.2f} m/s)" if "distance_mean" in summary else "")
    print_data(f"{label} on {env_name}: return {summary['return_mean']:.1f} ± {summary['return_std']:.1f}, "
               f"length {summary['length_mean']:.0f} ± {summary['length_std']:.0f}{moved} over {episodes} episodes")
