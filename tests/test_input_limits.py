"""Bounded inputs: every user file has a size limit checked against the size it declares and
while it is read, and every budget (steps, envs, episodes, frames) has a bound checked before any run folder
exists. The limits live in miktcli/limits.py."""

import io
import json
import os
import re
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest
import torch

from helpers import FIXTURE, cleanrl_agent, fixture_with, mikt
from miktcli import limits
from miktcli.errors import MiktError


def no_runs(registry: Path) -> bool:
    return not (registry / "runs").exists() or not any((registry / "runs").iterdir())


@pytest.fixture(scope="module")
def zip_bomb(tmp_path_factory) -> Path:
    """An SB3-looking zip of 1.6 MB whose `data` inflates to 1.6 GB (a reported case)."""
    path = tmp_path_factory.mktemp("bomb") / "bomb.zip"
    chunk = b" " * (16 << 20)
    with zipfile.ZipFile(FIXTURE) as z, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as out:
        with out.open("data", "w") as f:
            for _ in range(100):
                f.write(chunk)
        out.writestr("policy.pth", z.read("policy.pth"))
    assert path.stat().st_size < 2_000_000
    return path


@pytest.mark.slow
def test_a_member_inflating_to_gigabytes_is_refused_within_bounded_memory(zip_bomb, tmp_path):
    # in a child process, to measure its peak memory: the member is refused from its declared size
    script = textwrap.dedent(f"""
        import resource, sys
        from miktcli.cli.app import main
        sys.argv = ["mikt", "teacher", "import", {str(zip_bomb)!r}, "--env", "hopper",
                    "--registry", {str(tmp_path / "reg")!r}]
        try:
            main()
        except SystemExit as e:
            print("exit", e.code, "peak_kb", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src")}, timeout=300)
    assert "Error: " in r.stderr and "member 'data'" in r.stderr and "1,677,721,600 bytes" in r.stderr, r.stderr
    exit_line = next(ln for ln in r.stderr.splitlines() if ln.startswith("exit"))
    assert exit_line.split()[1] == "1"
    assert int(exit_line.split()[3]) < 1_000_000  # kB: well under the 1.6 GB the member would take
    assert not (tmp_path / "reg" / "teachers").exists() or not any((tmp_path / "reg" / "teachers").iterdir())


def test_a_member_whose_header_understates_it_stops_at_the_limit_while_inflating(registry, tmp_path, monkeypatch):
    # the second guard alone: even without the declared-size check, reading stops one byte past the limit
    path = fixture_with(tmp_path, "big.zip", data=b" " * 200_000, compress=zipfile.ZIP_DEFLATED)
    monkeypatch.setattr(limits, "MAX_SB3_DATA_BYTES", 100_000)
    monkeypatch.setattr(limits, "check_declared_size", lambda *a: None)
    reads = []
    original = limits.read_bounded

    def spy(stream, what, maximum):
        if "member 'data'" in what:
            reads.append(maximum)
        return original(stream, what, maximum)

    monkeypatch.setattr(limits, "read_bounded", spy)
    r = mikt("teacher", "import", path, "--env", "hopper", code=1)
    assert "member 'data': more than the 100,000 bytes" in r.output and reads == [100_000]


def test_an_oversized_policy_pth_is_refused_before_torch_loads_it(registry, tmp_path, monkeypatch):
    loads = []
    monkeypatch.setattr(torch, "load", lambda *a, **k: loads.append(1))
    monkeypatch.setattr(limits, "MAX_TENSOR_FILE_BYTES", 1000)  # the fixture's policy.pth is larger
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", code=1)
    assert "member 'policy.pth'" in r.output and "1,000 this kind of file may take" in r.output
    assert loads == [] and not (registry / "teachers").exists() or not any((registry / "teachers").iterdir())


def test_a_torch_file_with_compressed_storages_is_refused_before_loading(registry, tmp_path, monkeypatch):
    # torch.save never compresses; a deflated storage could inflate inside torch.load, past every limit
    buffer = io.BytesIO()
    torch.save(cleanrl_agent(11, 3).state_dict(), buffer)
    packed = tmp_path / "packed.cleanrl_model"
    with zipfile.ZipFile(buffer) as src, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as out:
        for info in src.infolist():
            out.writestr(info.filename, src.read(info))
    loads = []
    monkeypatch.setattr(torch, "load", lambda *a, **k: loads.append(1))
    r = mikt("teacher", "import", packed, "--format", "cleanrl", "--env", "hopper", code=1)
    assert "is compressed; torch.save stores its tensors uncompressed" in r.output and loads == []


def test_an_oversized_cleanrl_model_is_refused_from_its_file_size(registry, tmp_path, monkeypatch):
    path = tmp_path / "m.cleanrl_model"
    torch.save(cleanrl_agent(11, 3).state_dict(), path)
    monkeypatch.setattr(limits, "MAX_TENSOR_FILE_BYTES", path.stat().st_size - 1)
    r = mikt("teacher", "import", path, "--format", "cleanrl", "--env", "hopper", code=1)
    assert f"{path.stat().st_size:,} bytes, more than the" in r.output


def test_an_oversized_teacher_file_is_refused_before_it_is_read(registry, monkeypatch):
    mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "small")
    teacher_file = next((registry / "teachers").rglob("*.safetensors"))
    monkeypatch.setattr(limits, "MAX_TENSOR_FILE_BYTES", teacher_file.stat().st_size - 1)
    r = mikt("eval", "small", "--episodes", 1, code=1)
    assert "more than the" in r.output and teacher_file.name in r.output


def test_obs_stats_from_dev_zero_are_refused_without_reading_them(registry):
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--obs-stats", "/dev/zero", code=1)
    assert "/dev/zero: a device, not a regular file" in r.output


def test_an_oversized_stats_file_is_refused_from_its_size(registry, tmp_path, monkeypatch):
    stats = tmp_path / "stats.json"
    stats.write_text(json.dumps({"mean": [0.0] * 11, "var": [1.0] * 11}))
    monkeypatch.setattr(limits, "MAX_JSON_BYTES", 10)
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--obs-stats", stats, code=1)
    assert "bytes, more than the 10 this kind of file may take" in r.output


def test_json_true_is_not_a_number_in_obs_stats(registry, tmp_path):
    stats = tmp_path / "stats.json"
    stats.write_text(json.dumps({"mean": [True] + [0.0] * 10, "var": [1.0] * 11}))
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--obs-stats", stats, code=1)
    assert "'mean' holds true or false, not a number" in r.output


# budgets ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("args", [
    ("--num-envs", 100_000), ("--steps", 10**23), ("--eval-episodes", 10**9),
])
def test_absurd_budgets_are_usage_errors_before_any_run(registry, args):
    r = mikt("transfer", "--to", "hopper", "--method", "vpg", *args, code=2)
    assert args[0] in r.output and no_runs(registry)


def test_teacher_training_bounds_its_budget_too(registry):
    mikt("teacher", "train", "hopper", "--num-envs", 100_000, code=2)
    assert no_runs(registry)


@pytest.mark.parametrize("kwargs,message", [
    ({"num_envs": 100_000}, "--num-envs 100000: must be a whole number from 1 to 256"),
    ({"steps": 10**23}, "--steps 100000000000000000000000: must be a whole number"),
    ({"steps": 2048.5}, "--steps 2048.5: must be a whole number"),
    ({"eval_episodes": 0}, "--eval-episodes 0"),
    ({"steps": 5}, "--steps 5 would train 2,048 steps"),
    ({"steps": 1000}, "--steps 1,000 would train 2,048 steps"),
])
def test_the_library_refuses_budgets_before_a_run_folder_exists(registry, kwargs, message):
    from miktcli.workflows.transfer import start_transfer

    call = {"to": "hopper", "method": "vpg", "teacher_refs": [], "steps": 2048, "seed": 0, "command": "t", **kwargs}
    with pytest.raises(MiktError, match=message.replace("(", r"\(")):
        start_transfer(registry, **call)
    assert no_runs(registry)


def test_a_rounding_that_at_most_doubles_the_request_is_accepted(registry):
    r = mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 1024, "--eval-episodes", 1)
    assert "training 2,048 steps" in r.output


def test_a_rounding_that_more_than_doubles_the_request_is_one_line(registry):
    r = mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 5, code=1)
    assert "--steps 5 would train 2,048 steps" in r.output and "at least 1,024" in r.output and no_runs(registry)


@pytest.mark.parametrize("args", [("--episodes", 10**6), ("--video-frames", 10**6)])
def test_eval_bounds_episodes_and_frames(registry, args):
    assert args[0] in mikt("eval", "run1", *args, code=2).output


def test_the_library_bounds_evaluation_episodes_and_frames():
    from miktcli.engine.policies import GaussianActorCritic
    from miktcli.workflows.evaluate import evaluate_policy

    policy = GaussianActorCritic(11, 3, [8], [8], "tanh")
    with pytest.raises(MiktError, match="episodes 1000000"):
        evaluate_policy(policy, "hopper", 10**6, 0, False)
    with pytest.raises(MiktError, match="video frames 1000000"):
        evaluate_policy(policy, "hopper", 1, 0, False, capture_episodes=1, max_frames=10**6)


def test_every_limit_is_named_with_its_reason_in_one_module():
    source = Path(limits.__file__).read_text()
    names = [n for n in vars(limits) if n.startswith("MAX_")]
    assert len(names) >= 9
    for name in names:
        line = next(ln for ln in source.splitlines() if ln.startswith(f"{name} ="))
        assert "#" in line and len(line.split("#", 1)[1].strip()) > 20, line


def test_layer_sizes_past_the_limit_are_refused_before_a_run_exists(registry):
    out = mikt("teacher", "train", "hopper", "--steps", 2048, "--hidden", "100000,100000", code=1).output
    assert f"at most {limits.MAX_LAYERS} layers of at most {limits.MAX_LAYER_WIDTH:,} units" in out
    out = mikt("teacher", "train", "hopper", "--steps", 2048, "--hidden", "4096,4096,4096,4096", code=1).output
    assert "parameters on a 11-dim observation" in out
    assert no_runs(registry)


def test_a_spec_time_limit_past_the_bound_and_a_deeply_nested_spec_are_one_line(tmp_path, monkeypatch):
    from helpers import spec_dir

    hopper = (Path(__file__).resolve().parents[1] / "envspecs" / "hopper.toml").read_text()
    long_limit = re.sub(r"max_episode_steps = \d+", f"max_episode_steps = {10 ** 12}",
                        hopper.replace('name = "hopper"', 'name = "long"'))
    spec_dir(tmp_path, monkeypatch, long=long_limit, nested='name = "nested"\nx = ' + "[" * 5000 + "]" * 5000 + "\n")
    out = mikt("envs", code=1).output
    assert "nested.toml: not valid TOML: nested too deeply" in out
    assert "long.toml: field 'max_episode_steps'" in out and "internal error" not in out


def test_a_deeply_nested_grid_is_one_line(registry, tmp_path):
    grid = tmp_path / "deep.toml"
    grid.write_text('name = "deep"\nsteps = 2048\nseeds = ' + "[" * 5000 + "]" * 5000 + "\n")
    out = mikt("study", grid, "--out", tmp_path / "out", code=1).output
    assert "not valid TOML: nested too deeply" in out
