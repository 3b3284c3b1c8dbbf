"""The packaged teachers: a read-only layer below the local registry."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from helpers import mikt
from miktcli.registry import packaged

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def shipped(tmp_path, monkeypatch):
    """A packaged layer holding hopper v1 and v2 (only the latest counts) and centipede-four v2."""
    root = tmp_path / "package" / "_teachers"
    for name, version in (("hopper", 1), ("hopper", 2), ("centipede-four", 2)):
        (root / name).mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / "registry" / "teachers" / name / f"v{version}.safetensors", root / name)
    monkeypatch.setattr(packaged, "packaged_root", lambda: root)
    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "1")
    return root


def test_lookups_fall_back_to_the_packaged_teachers(shipped, registry):
    rows = json.loads(mikt("teacher", "list", "--json").stdout)
    assert [(r["ref"], r["source"]) for r in rows] == [("centipede-four@v2", "packaged"), ("hopper@v2", "packaged")]
    shown = json.loads(mikt("teacher", "show", "hopper", "--json").stdout)
    assert shown["source"] == "packaged" and shown["path"] == str(shipped / "hopper" / "v2.safetensors")
    assert "packaged" in mikt("teacher", "list").stdout
    # v1 lies in the packaged folder but only the latest version of each name is the layer
    assert "has no version v1; versions: v2" in mikt("teacher", "show", "hopper@v1", code=1).output


def test_a_local_teacher_of_the_same_name_and_version_wins(shipped, registry):
    (registry / "teachers" / "hopper").mkdir(parents=True)
    shutil.copy(shipped / "hopper" / "v2.safetensors", registry / "teachers" / "hopper")
    rows = {r["ref"]: r for r in json.loads(mikt("teacher", "list", "--json").stdout)}
    assert rows["hopper@v2"]["source"] == "local (over packaged)"
    assert rows["hopper@v2"]["path"] == str(registry / "teachers" / "hopper" / "v2.safetensors")
    assert json.loads(mikt("teacher", "show", "hopper@v2", "--json").stdout)["source"] == "local"


def test_integrity_checks_apply_to_packaged_files(shipped, registry):
    data = bytearray((shipped / "hopper" / "v2.safetensors").read_bytes())
    data[-10] ^= 0xFF  # a flipped bit in the last tensor
    (shipped / "hopper" / "v2.safetensors").write_bytes(bytes(data))
    assert "do not match the card's sha256" in mikt("teacher", "show", "hopper", code=1).output


def test_a_new_version_is_numbered_above_both_layers_and_written_locally(shipped, registry):
    before = sorted(p.name for p in shipped.rglob("*"))
    r = mikt("teacher", "train", "hopper", "--steps", 2048)
    assert r.stdout.strip() == "hopper@v3"
    assert (registry / "teachers" / "hopper" / "v3.safetensors").is_file()
    assert sorted(p.name for p in shipped.rglob("*")) == before  # nothing written into the package
    rows = json.loads(mikt("teacher", "list", "--json").stdout)
    assert [(r["ref"], r["source"]) for r in rows if r["ref"].startswith("hopper")] == [
        ("hopper@v2", "packaged"), ("hopper@v3", "local")]
    assert json.loads(mikt("teacher", "show", "hopper", "--json").stdout)["version"] == 3  # latest: the newest


def test_the_switch_hides_the_layer(shipped, registry, monkeypatch):
    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "0")
    assert "no teachers in" in mikt("teacher", "list").output


def test_an_import_never_silently_replaces_a_shipped_teacher(registry, monkeypatch):
    from helpers import FIXTURE, mikt

    monkeypatch.setenv("MIKT_PACKAGED_TEACHERS", "1")
    out = mikt("teacher", "import", FIXTURE, "--env", "hopper", code=1).output
    assert "teacher 'hopper' exists already (hopper@v2, shipped with mikt)" in out
    assert "--name hopper-sb3" in out
    assert json.loads(mikt("teacher", "show", "hopper", "--json").stdout)["source"] == "packaged"
    r = mikt("teacher", "import", FIXTURE, "--env", "hopper", "--name", "hopper")  # on purpose: the next version
    assert r.stdout.strip() == "hopper@v3"
    assert "in place of hopper@v2 (trained by mikt" in r.output and "unreadable" not in r.output
