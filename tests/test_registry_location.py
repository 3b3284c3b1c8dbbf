"""A message that something is not in the registry names the folder it read and how that folder was chosen
($MIKT_REGISTRY, the default ./registry, or --registry), with a hint: `cd sub && mikt eval` says where it looked."""

import pytest

from helpers import mikt


@pytest.fixture()
def sub(tmp_path, monkeypatch):
    """A project folder with its registry (one finished vpg run), and the user one folder below it."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MIKT_REGISTRY", raising=False)
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 2048, "--eval-episodes", 1)
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    return tmp_path / "sub"


def test_eval_from_a_subfolder_names_the_folder_it_read(sub):
    r = mikt("eval", code=1)
    assert (f"Error: no runs yet in registry {sub / 'registry'} (the default ./registry, as MIKT_REGISTRY is "
            "unset; no such folder)") in r.output
    assert "Hint: run mikt from the folder that holds your registry, set MIKT_REGISTRY, or pass --registry" \
        in r.output
    assert "student on hopper" in mikt("eval", "--registry", "../registry", "--episodes", 1).stdout


def test_the_message_says_how_the_registry_was_chosen(sub, monkeypatch):
    project = sub.parent / "registry"
    monkeypatch.setenv("MIKT_REGISTRY", str(sub / "elsewhere"))
    assert f"{sub / 'elsewhere'} (from $MIKT_REGISTRY; no such folder)" in mikt("inspect", "last", code=1).output
    # --registry wins over the variable, and the message says so; a folder that exists is not called missing
    r = mikt("inspect", "run7", "--registry", project, code=1)
    assert f"unknown run 'run7' in registry {project} (given by --registry); known: run1" in r.output
    assert "Hint: run mikt from the folder" in r.output


def test_unknown_teachers_and_empty_listings_name_the_folder(sub):
    where = f"{sub / 'registry'} (the default ./registry, as MIKT_REGISTRY is unset; no such folder)"
    r = mikt("eval", "ghost", code=1)
    assert f"unknown teacher 'ghost' in registry {where}; known: (none)" in r.output
    assert "or read another registry (set MIKT_REGISTRY or pass --registry)" in r.output
    assert f"no runs yet in registry {where}" in mikt("runs").output
    assert f"no teachers in registry {where}" in mikt("teacher", "list").output

