"""`mikt study --address` with no Ray cluster behind it ends in one line, before any cell is prepared
(issue 37 K); it hung, printing Ray's log lines, after creating every cell's run."""

import socket

import pytest
from typer.testing import CliRunner

from miktcli.cli.app import app

pytest.importorskip("ray")
runner = CliRunner()


def write_grid(tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "g"\nsteps = 2048\nseeds = [0, 1]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    return grid


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_address_where_nothing_listens_is_one_line_before_any_cell_exists(registry, tmp_path):
    address = f"127.0.0.1:{free_port()}"
    r = runner.invoke(app, ["study", str(write_grid(tmp_path)), "--out", str(tmp_path / "out"), "--address", address])
    assert r.exit_code == 1, r.output
    assert f"Error: no Ray cluster answers at {address}" in r.output
    assert "ray start --head" in r.output
    assert not (registry / "runs").exists() and not (tmp_path / "out" / "state.json").exists()


def test_an_address_that_never_answers_times_out(registry, tmp_path, monkeypatch):
    import miktcli.studies.ray_executor as ray_executor

    monkeypatch.setattr(ray_executor, "RAY_CONNECT_TIMEOUT_S", 0.5)
    # TEST-NET-1 (RFC 5737): routed nowhere, so a connection waits until it times out (or fails at once
    # where the machine has no route at all); either way one line, no run
    r = runner.invoke(app, ["study", str(write_grid(tmp_path)), "--out", str(tmp_path / "out"),
                            "--address", "192.0.2.1:6379"])
    assert r.exit_code == 1 and "Error: no Ray cluster answers at 192.0.2.1:6379" in r.output, r.output
    assert not (registry / "runs").exists()


def test_auto_without_a_running_cluster_is_one_line(registry, tmp_path, monkeypatch):
    import ray._private.services as services

    def nothing_found(address):  # as on a machine where `ray start` never ran (other tests may run Ray here)
        raise ConnectionError("Could not find any running Ray instance. Please specify the one to connect to.")

    monkeypatch.setattr(services, "canonicalize_bootstrap_address_or_die", nothing_found)
    r = runner.invoke(app, ["study", str(write_grid(tmp_path)), "--out", str(tmp_path / "out"), "--address", "auto"])
    assert r.exit_code == 1, r.output
    assert "Error: no Ray cluster answers at auto: Could not find any running Ray instance" in r.output
    assert not (registry / "runs").exists()


def test_a_malformed_address_is_one_line(registry, tmp_path):
    r = runner.invoke(app, ["study", str(write_grid(tmp_path)), "--out", str(tmp_path / "out"),
                            "--address", "not an address"])
    assert r.exit_code == 1 and "Error: --address 'not an address'" in r.output, r.output
    assert not (registry / "runs").exists()
