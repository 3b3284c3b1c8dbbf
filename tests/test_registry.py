import json

import pytest
import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from miktcli.engine.policies import GaussianActorCritic
from miktcli.envs import load_spec
from miktcli.errors import MiktError
from miktcli.registry.cards import TeacherCard, now
from miktcli.registry.files import CARD_KEY
from miktcli.registry.teachers import list_names, load_teacher, publish_teacher, resolve, versions


def make_card(**kw):
    base = dict(name="tiny", version=1, env="hopper", env_spec=load_spec("hopper").model_dump(), obs_dim=11, act_dim=3,
                pi_hidden=[8, 8], vf_hidden=[8, 8], steps=0, seed=0, final_return=None, best_return=None,
                hyperparameters={}, packages={}, code_version="test", created=now(), tensors_sha256="")
    base.update(kw)
    return TeacherCard(**base)


@pytest.fixture()
def published(registry):
    policy = GaussianActorCritic(11, 3, [8, 8], [8, 8])
    policy.obs_normalizer.update(torch.randn(50, 11).double().numpy())
    card = publish_teacher(registry, make_card(), policy)
    return registry, policy, card


def test_round_trip_versions_and_latest(published):
    registry, policy, card = published
    assert card.ref == "tiny@v1"
    loaded = load_teacher(registry, "tiny")
    for k, v in policy.state_dict().items():
        assert torch.equal(loaded.policy.state_dict()[k], v)
    assert loaded.policy.obs_normalizer.frozen
    assert not any(p.requires_grad for p in loaded.policy.parameters())
    card2 = publish_teacher(registry, make_card(), GaussianActorCritic(11, 3, [8, 8], [8, 8]))
    assert card2.version == 2 and versions(registry, "tiny") == [1, 2]
    assert resolve(registry, "tiny").name == "v2.safetensors"
    assert resolve(registry, "tiny@latest").name == "v2.safetensors"
    assert load_teacher(registry, "tiny@v1").card.tensors_sha256 == card.tensors_sha256
    assert list_names(registry) == ["tiny"]


def test_unknown_teacher_and_version(published):
    registry, _, _ = published
    with pytest.raises(MiktError, match="unknown teacher 'nope'.*known: tiny"):
        load_teacher(registry, "nope")
    with pytest.raises(MiktError, match="no version v7; versions: v1"):
        load_teacher(registry, "tiny@v7")


def rewrite(path, tensors=None, card=None, raw_card=None):
    data = path.read_bytes()
    old_tensors = st_load(data)
    from safetensors import safe_open

    with safe_open(str(path), "pt") as f:
        meta = f.metadata()
    tensors = old_tensors if tensors is None else tensors
    if card is not None:
        meta = {CARD_KEY: card.model_dump_json()}
    if raw_card is not None:
        meta = {CARD_KEY: raw_card}
    path.write_bytes(st_save(tensors, metadata=meta))


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda p, c: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]), "not a readable safetensors"),
        (lambda p, c: p.write_bytes(b"PK\x03\x04 definitely a zip, not safetensors"), "not a readable safetensors"),
        (lambda p, c: rewrite(p, card=c.model_copy(update={"obs_dim": 12})), "card disagrees with tensor"),
        (lambda p, c: rewrite(p, card=c.model_copy(update={"pi_hidden": [8]})), "card"),
        (lambda p, c: rewrite(p, raw_card=json.dumps({**json.loads(c.model_dump_json()), "schema_version": 99})),
         "schema version 99 is newer"),
        (lambda p, c: rewrite(p, raw_card="{not json"), "not valid JSON"),
        (lambda p, c: rewrite(p, tensors={k: (v + 1 if k == "log_std" else v)
                                          for k, v in st_load(p.read_bytes()).items()}), "sha256"),
    ],
    ids=["truncated", "not-safetensors", "dims-vs-shapes", "layers-vs-shapes", "newer-schema", "bad-json",
         "tampered"],
)
def test_bad_teacher_files_are_refused(published, damage, message):
    registry, _, card = published
    path = resolve(registry, "tiny")
    damage(path, card)
    with pytest.raises(MiktError, match=message):
        load_teacher(registry, "tiny")


def test_versions_are_immutable_and_writes_atomic(published, monkeypatch):
    registry, _, _ = published
    path = resolve(registry, "tiny@v1")
    before = path.read_bytes()
    import miktcli.registry.files as atomic

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "link", crash)
    with pytest.raises(OSError):
        publish_teacher(registry, make_card(), GaussianActorCritic(11, 3, [8, 8], [8, 8]))
    assert versions(registry, "tiny") == [1]  # nothing half-written, no v2
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp file left
    assert path.read_bytes() == before


def test_listing_reads_headers_only(published, monkeypatch):
    registry, _, _ = published
    import miktcli.registry.files as checkpoint
    from miktcli.cli.teacher import _teacher_rows

    monkeypatch.setattr(checkpoint, "load", lambda *a, **k: pytest.fail("list must not load tensors"))
    rows = _teacher_rows(registry)
    assert rows[0]["ref"] == "tiny@v1" and rows[0]["card"]["obs_dim"] == 11


def test_a_signal_during_an_atomic_write_waits_for_the_write(tmp_path, pythons_ctrl_c):
    import os
    import signal

    from miktcli.registry.files import write_bytes_atomic

    target = tmp_path / "f.bin"
    original = os.fsync

    def fsync_then_ctrl_c(fd):
        original(fd)
        signal.raise_signal(signal.SIGINT)  # arrives mid-write, before the rename, in this thread

    import miktcli.registry.files as atomic

    atomic.os.fsync = fsync_then_ctrl_c
    try:
        with pytest.raises(KeyboardInterrupt):
            write_bytes_atomic(target, b"complete")
    finally:
        atomic.os.fsync = original
    assert target.read_bytes() == b"complete"  # the write finished first, then Ctrl-C was delivered


def test_run_cards_written_by_0_1_still_open(registry):
    """run.json of mikt 0.1 (a committed study run): MIKT options under `mikt`, dead keys, no clip field."""
    import shutil
    from pathlib import Path

    from miktcli.registry.runs import open_run

    old = Path(__file__).resolve().parents[1] / "benchmarks/results/four-to-eight/runs/run5/run.json"
    (registry / "runs" / "run5").mkdir(parents=True)
    shutil.copy(old, registry / "runs" / "run5" / "run.json")
    run = open_run(registry, "run5")
    assert run.card.method == "mikt" and run.card.config.options["coupling_schedule"] == "three-phase"
    assert run.card.config.ppo.clip_actions_for_env is True  # 0.1 clipped actions for the env
    assert "encoder_widths" not in run.card.config.model_dump()
    data = json.loads(old.read_text())
    data["schema_version"] = 7
    (registry / "runs" / "run5" / "run.json").write_text(json.dumps(data))
    with pytest.raises(MiktError, match="schema version 7 is newer"):
        open_run(registry, "run5")


def test_a_saved_card_carries_this_codes_schema_version(registry, monkeypatch):
    """A version-1 card that gains version-2 fields is written as version 2, so an older mikt refuses it
    with a message rather than a validation error about a field it does not know."""
    import shutil
    from pathlib import Path

    import miktcli.registry.runs as runs_module
    from miktcli.registry.cards import RUN_SCHEMA_VERSION

    old = Path(__file__).resolve().parents[1] / "benchmarks/results/four-to-eight/runs/run5/run.json"
    (registry / "runs" / "run5").mkdir(parents=True)
    shutil.copy(old, registry / "runs" / "run5" / "run.json")
    run = runs_module.open_run(registry, "run5")
    assert run.card.schema_version == 1 < RUN_SCHEMA_VERSION
    run.save_card(status="created")  # a status that version 1 did not have
    assert json.loads((registry / "runs" / "run5" / "run.json").read_text())["schema_version"] == RUN_SCHEMA_VERSION

    monkeypatch.setattr(runs_module, "RUN_SCHEMA_VERSION", RUN_SCHEMA_VERSION - 1)  # an older mikt's reader
    with pytest.raises(MiktError, match=f"schema version {RUN_SCHEMA_VERSION} is newer than this mikt understands"):
        runs_module.open_run(registry, "run5")


def test_a_published_teacher_carries_this_codes_schema_version(registry):
    from miktcli.registry.cards import TEACHER_SCHEMA_VERSION

    card = publish_teacher(registry, make_card(schema_version=1), GaussianActorCritic(11, 3, [8, 8], [8, 8]))
    assert card.schema_version == TEACHER_SCHEMA_VERSION
    assert load_teacher(registry, "tiny").card.schema_version == TEACHER_SCHEMA_VERSION


def test_a_run_whose_card_cannot_be_written_leaves_no_folder(registry, monkeypatch):
    import errno

    from miktcli.engine.ppo import PPOConfig
    from miktcli.registry import runs as runs_module
    from miktcli.registry.cards import RunConfig
    from miktcli.registry.runs import Run

    def disk_full(self, **updates):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Run, "save_card", disk_full)
    with pytest.raises(MiktError, match="No space left on device"):
        runs_module.create_run(registry, kind="teacher", env="hopper", method="vpg", seed=0, total_steps=2048,
                               config=RunConfig(ppo=PPOConfig(), pi_hidden=[8], vf_hidden=[8]), command="x",
                               code_version="x", packages={})
    assert not list((registry / "runs").iterdir())
