"""`mikt study --report-only` on a folder that holds no study is an error, not an empty report (issue 37, minor)."""

from typer.testing import CliRunner

from miktcli.cli.app import app

runner = CliRunner()


def write_grid(tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('name = "g"\nsteps = 2048\nseeds = [0]\n[[pairs]]\nfrom = ["x"]\nto = "hopper"\n'
                    '[[methods]]\nname = "vpg"\nmethod = "vpg"\n')
    return grid


def test_report_only_on_a_missing_or_empty_folder_is_one_line(registry, tmp_path):
    grid = write_grid(tmp_path)
    for out in (tmp_path / "missing", tmp_path / "empty"):
        if out.name == "empty":
            out.mkdir()
        r = runner.invoke(app, ["study", str(grid), "--out", str(out), "--report-only"])
        assert r.exit_code == 1, r.output
        assert f"Error: {out} holds no study yet (no state.json): nothing to report" in r.output
        assert not (out / "results.md").exists()
    assert not (tmp_path / "missing").exists()


def test_report_only_on_a_prepared_study_reports_it(registry, tmp_path):
    from miktcli.studies.grid import load_grid
    from miktcli.studies.study import Study

    grid = write_grid(tmp_path)
    Study(load_grid(grid), tmp_path / "out", registry).prepare("test")  # prepared, nothing finished yet
    r = runner.invoke(app, ["study", str(grid), "--out", str(tmp_path / "out"), "--report-only"])
    assert r.exit_code == 0 and (tmp_path / "out" / "results.md").exists(), r.output
