"""Output paths: checked before any work by creating a file where the output
goes (os.access says yes to root and to /proc), and a command that fails leaves no folder it made behind."""

from pathlib import Path

import pytest

from helpers import mikt
from miktcli.errors import MiktError
from miktcli.outfiles import prepare_output

UNWRITABLE = Path("/proc/mikt-out")  # a folder no one can create files in, whatever os.access says


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_an_unwritable_video_is_refused_before_any_episode(registry):
    r = mikt("eval", "run1", "--video", UNWRITABLE / "v.mp4", code=1)
    assert f"cannot write {UNWRITABLE / 'v.mp4'}" in r.output and "no run" not in r.output


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_an_unwritable_frame_is_refused_before_the_env_is_built(registry):
    r = mikt("envs", "render", "hopper", "--out", Path("/proc") / "x.png", code=1)
    assert "cannot write /proc/x.png" in r.output


def test_a_failing_render_leaves_no_folder_it_made(tmp_path):
    r = mikt("envs", "render", "no-such-env", "--out", tmp_path / "new" / "deeper" / "x.png", code=1)
    assert "unknown environment" in r.output and not (tmp_path / "new").exists()


def test_the_check_creates_nothing_and_the_write_makes_the_folders(tmp_path):
    target = tmp_path / "a" / "b" / "x.png"
    assert prepare_output(target) == target and not (tmp_path / "a").exists()
    mikt("envs", "render", "hopper", "--out", target)
    assert target.is_file() and [p.name for p in target.parent.iterdir()] == ["x.png"]  # no probe left


def test_a_folder_is_not_an_output_file(tmp_path):
    with pytest.raises(MiktError, match="is a folder"):
        prepare_output(tmp_path)


@pytest.mark.parametrize("free, message", [(0, "No space left on device"),
                                           (10**12, "the video encoder (ffmpeg) stopped")])
def test_a_video_whose_encoder_stops_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, free, message):
    import shutil
    from collections import namedtuple

    from miktcli import outfiles
    from miktcli.errors import MiktError

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(1, 1, free))
    target = tmp_path / "v.mp4"
    with pytest.raises(MiktError) as caught:
        with outfiles.atomic_output(target, ".mp4"):
            raise OSError("[Errno 32] Broken pipe\n\nFFMPEG COMMAND:\nffmpeg -y …\n\nFFMPEG STDERR OUTPUT:\n")
    assert str(caught.value) == f"could not write {target}: {message}"
    assert sorted(p.name for p in tmp_path.iterdir()) == []
