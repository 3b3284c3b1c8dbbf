import os
import shutil

import pytest
import torch

os.environ.setdefault("COLUMNS", "160")
# Tests see only the registries they make: the teachers packaged with mikt (a read-only layer below every
# registry) would otherwise number a test's first "hopper" as v3. tests/test_packaged_teachers.py turns it on.
os.environ["MIKT_PACKAGED_TEACHERS"] = "0"
torch.set_num_threads(1)


@pytest.fixture()
def registry(tmp_path, monkeypatch):
    reg = tmp_path / "registry"
    monkeypatch.setenv("MIKT_REGISTRY", str(reg))
    return reg


@pytest.fixture()
def ctrl_c_at_second_update(monkeypatch):
    """Training raises KeyboardInterrupt (as Ctrl-C would) in its second update; call the returned function
    to let training run normally again."""
    from helpers import ctrl_c_at_second_call
    from miktcli.engine.ppo import PPOTrainer

    return ctrl_c_at_second_call(monkeypatch, PPOTrainer, "update")


@pytest.fixture()
def pythons_ctrl_c():
    """Python's own Ctrl-C handler on SIGINT for the test, whatever earlier tests' libraries (Ray, torch's
    compiler) left there; the previous handler comes back after."""
    import signal

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture()
def specs(tmp_path, monkeypatch):
    """An empty spec folder of the test's own ($MIKT_ENVSPECS): where `mikt envs add` writes."""
    folder = tmp_path / "specs"
    folder.mkdir()
    monkeypatch.setenv("MIKT_ENVSPECS", str(folder))
    return folder


@pytest.fixture(scope="session")
def tiny_teacher_registry(tmp_path_factory):
    """What `mikt teacher train hopper --steps 2048 --name tiny` leaves in an empty registry, trained once per
    test process: for many tests, training a teacher to transfer from was most of their time."""
    from helpers import mikt

    registry = tmp_path_factory.mktemp("tiny-teacher") / "registry"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MIKT_REGISTRY", str(registry))
        mikt("teacher", "train", "hopper", "--steps", 2048, "--name", "tiny")
    return registry


@pytest.fixture()
def teacher(registry, tiny_teacher_registry):
    """The test's registry as `mikt teacher train hopper --steps 2048 --name tiny` leaves it (a copy of one
    trained once): the teacher tiny@v1, trained by run1. Its file."""
    shutil.copytree(tiny_teacher_registry, registry, dirs_exist_ok=True)
    return registry / "teachers" / "tiny" / "v1.safetensors"


@pytest.fixture()
def two_vpg_runs(registry):
    """Two finished vpg runs on hopper (run1, run2): checkpoints and students on disk."""
    from helpers import TINY, mikt

    for seed in (0, 1):
        mikt("transfer", "--to", "hopper", "--method", "vpg", *TINY, "--seed", seed, "--eval-episodes", 1)
    return registry / "runs"
