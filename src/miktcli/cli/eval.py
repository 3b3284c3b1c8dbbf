"""`mikt eval`: evaluate a teacher or a run's student; optionally render an MP4 offscreen."""

from __future__ import annotations

from pathlib import Path

import typer

from miktcli import limits
from miktcli.cli.common import DEFAULT_REGISTRY, JsonOption, RegistryOption, setup_torch
from miktcli.cli.console import err, print_data, print_json
from miktcli.cli.progress import episode_progress

HELP = """Evaluate a teacher (NAME or NAME@vN) or a run's student (runN); with no target, the newest run (last).

Examples:

  mikt eval --render-offscreen

  mikt eval hopper --episodes 20

  mikt eval run3 --with-teacher

  mikt eval run3 --render-offscreen --video run3.mp4     # every episode, back to back, in real time

  mikt eval run3 --handover --episodes 50      # the hand-over at the teacher drop, measured again
"""


POSTER_SECONDS = 2.0  # the poster is the frame this far into the video: the body in motion, not at rest


class _EvaluationFailed(Exception):
    """An error of the evaluation itself, carried through the video writer, which would call it a failure to
    write the file."""


def eval_command(
    target: str = typer.Argument("last", help="Teacher NAME or NAME@vN, runN, or last (the newest run).",
                                 show_default=True),
    episodes: int = typer.Option(10, "--episodes", min=1, max=limits.MAX_EPISODES),
    seed: int = typer.Option(0, "--seed", min=0, max=2**32 - 1,
                             help="Seed of the first episode; episode i uses seed + i."),
    deterministic: bool = typer.Option(True, "--deterministic/--stochastic", help="Mean action or sampled."),
    with_teacher: bool = typer.Option(False, "--with-teacher", help="Runs: evaluate the student with its teacher."),
    handover: bool = typer.Option(False, "--handover", help="Runs with teachers: the hand-over at the drop again, "
                                  "from the checkpoint kept just before it: the mixed policy, then the run's "
                                  "hand-over and the teacher-free student, on the same --episodes (the run's "
                                  "own evaluation seeds, deterministic)."),
    render_offscreen: bool = typer.Option(False, "--render-offscreen", help="Write an MP4 of every episode, back "
                                          "to back, and a PNG poster."),
    video: Path = typer.Option(None, "--video", help="MP4 path (default: TARGET-eval.mp4); implies rendering."),
    video_frames: int = typer.Option(limits.MAX_VIDEO_FRAMES, "--video-frames", min=1, max=limits.MAX_VIDEO_FRAMES,
                                     help="Most frames in the video, all episodes together; recording stops "
                                     "there and the evaluation goes on."),
    as_json: JsonOption = False,
    registry: RegistryOption = DEFAULT_REGISTRY,
) -> None:
    from miktcli.engine.episodes import evaluation
    from miktcli.outfiles import prepare_output
    from miktcli.workflows.evaluate import load_policy

    setup_torch()
    if handover:
        clashes = [flag for flag, on in (("--with-teacher", with_teacher), ("--render-offscreen", render_offscreen),
                                         ("--video", video is not None), ("--stochastic", not deterministic),
                                         ("--seed", seed != 0)) if on]
        if clashes:
            raise typer.BadParameter(f"{clashes[0]} cannot be combined with --handover (it measures the run's own "
                                     "deterministic evaluation episodes)", param_hint="'--handover'")
        _handover(registry, target, episodes, as_json)
        return
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
    with evaluation(policy, env_name, episodes, seed, clip_actions, deterministic,
                    capture_episodes=episodes if render else 0, max_frames=video_frames) as ev:
        rate = ev.rate
        err.print(f"evaluating {label} on {env_name}: {episodes} episode(s)" + (
            f", recording {'every step' if rate.every == 1 else f'one step in {rate.every}'} at {rate.fps:.1f} "
            f"fps, real time (the model runs {rate.model_fps:.1f} steps a second)" if render else ""))
        with episode_progress(episodes, target, recording=render) as show:
            if render:
                poster = _record(ev, show, video)
            else:
                for event in ev.events():
                    show(event)
    res = ev.result
    summary = {"target": target, "policy": label, "env": env_name, "deterministic": deterministic,
               "clip_actions_for_env": clip_actions,
               **res.summary()}
    if render:
        recorded = sum(res.episode_frames)
        summary.update(video=str(video), poster=str(poster), video_frames=recorded,
                       video_episode_frames=res.episode_frames, video_fps=round(rate.fps, 3),
                       video_model_fps=round(rate.model_fps, 3), video_every=rate.every,
                       video_cut_in_episode=res.cut_in_episode)
        err.print(f"wrote {video} ({recorded:,} frames, {recorded / rate.fps:.1f} s at {rate.fps:.1f} fps: "
                  f"{_episodes_in(res)}) and {poster}")
        if res.cut_in_episode is not None:
            err.print(f"warning: the video stopped at {recorded:,} frames (--video-frames {video_frames:,}) in "
                      f"episode {res.cut_in_episode} of {episodes}; the evaluation went on. For every episode "
                      "whole, ask fewer --episodes" + (f" or up to --video-frames {limits.MAX_VIDEO_FRAMES:,}"
                                                       if video_frames < limits.MAX_VIDEO_FRAMES else ""))
    if as_json:
        print_json(summary)
        return
    moved = (f", forward {summary['distance_mean']:.2f} ± {summary['distance_std']:.2f} m "
             f"({summary['speed_mean']:.2f} m/s)" if "distance_mean" in summary else "")
    print_data(f"{label} on {env_name}: return {summary['return_mean']:.1f} ± {summary['return_std']:.1f}, "
               f"length {summary['length_mean']:.0f} ± {summary['length_std']:.0f}{moved} over {episodes} episodes")


def _handover(registry: Path, target: str, episodes: int, as_json: bool) -> None:
    from miktcli.workflows.evaluate import measure_handover

    err.print(f"evaluating {target} at the teacher drop with and without the teachers: {episodes} episode(s) each")
    res = measure_handover(registry, target, episodes)
    if as_json:
        print_json(res)
        return
    mixed, alone, kept = res["with_teachers"], res["without_teachers"], res["kept_fraction"]
    print_data(f"{res['run']} at the drop ({res['at_step']:,} steps, hand-over {res['handover']}) on {res['env']}, "
               f"{episodes} episodes: with the teachers {mixed['return_mean']:.1f} ± {mixed['return_std']:.1f}, "
               f"without {alone['return_mean']:.1f} ± {alone['return_std']:.1f}, kept "
               + ("n/a (the mixed policy's return is not positive)" if kept is None else f"{100 * kept:.1f} %"))
    recorded = res["recorded"]
    if recorded and recorded.get("kept_fraction") is not None:
        print_data(f"recorded in training: {recorded['with_teachers']['episodes']} episodes, kept "
                   f"{100 * recorded['kept_fraction']:.1f} %")


def _record(ev, show, video: Path) -> Path:
    """Stream the evaluation's frames into the MP4 as they are rendered (all episodes, back to back: a long
    video is never held in memory), then write the poster; returns the poster's path."""
    from miktcli.engine.episodes import EpisodeDone
    from miktcli.envs.frames import save_mp4, save_png

    poster_at, kept = round(POSTER_SECONDS * ev.rate.fps), []

    def frames():
        count = 0
        try:
            for event in ev.events():
                if isinstance(event, EpisodeDone):
                    show(event)
                    continue
                if count <= poster_at:  # the last frame of a shorter video
                    kept[:] = [event]
                count += 1
                yield event
        except (OSError, RuntimeError, ValueError) as error:  # what the writer would take for its own failure
            raise _EvaluationFailed from error

    try:
        save_mp4(frames(), video, fps=ev.rate.fps)
    except _EvaluationFailed as failed:
        raise failed.__cause__ from None
    return save_png(kept[0], video.with_suffix(".png"))


def _episodes_in(res) -> str:
    whole = len(res.episode_frames) if res.cut_in_episode is None else res.cut_in_episode - 1
    return f"{whole} whole episode(s)" + ("" if res.cut_in_episode is None else
                                           f" and part of episode {res.cut_in_episode}")
