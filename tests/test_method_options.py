"""A method's options are declared once, in its options model: the CLI flags, their help, the grid key and the
run card all come from it, and a new method needs its own file plus one registry line (toy_method.py)."""

import json

import pytest

import toy_method
from helpers import mikt, runner
from miktcli.cli.app import app
from miktcli.errors import MethodOptionError, TeacherCountError, TeacherMismatchError
from miktcli.methods import METHODS

TINY = ("--steps", 2048, "--eval-episodes", 1)


@pytest.fixture()
def toy(monkeypatch):
    monkeypatch.setitem(METHODS, "toy", toy_method.METHOD)  # the one registry line


def test_a_new_method_with_one_option_needs_only_its_file_and_a_registry_line(toy, registry, tmp_path):
    help_text = runner.invoke(app, ["transfer", "--help"]).output
    assert "toy (PPO from scratch, chosen initial noise" in help_text
    assert "--init-log-std [FLOAT]: log-std of the action noise at the start. ≤ 1.0. Default: 0.0." in help_text

    result = json.loads(mikt("transfer", "--to", "hopper", "--method", "toy", "--init-log-std", "-0.5", *TINY,
                             "--json").stdout)
    card = json.loads((registry / "runs" / result["run"] / "run.json").read_text())
    assert card["method"] == "toy" and card["config"]["options"] == {"init_log_std": -0.5}
    assert card["config"]["ppo"]["kl_coef"] == 0.0  # the method's own default

    r = mikt("transfer", "--to", "hopper", "--method", "toy", "--init-log-std=2", *TINY, code=1)
    assert "bad toy option: field 'init_log_std'" in r.output
    assert "Hint: see --init-log-std" in r.output  # from the error's type and field, not its wording
    assert "'--mi'" in mikt("transfer", "--to", "hopper", "--method", "toy", "--no-mi", *TINY, code=2).output
    assert "'--init-log-std'" in mikt("transfer", "--from", "t", "--to", "hopper", "--init-log-std", "1", *TINY,
                                      code=2).output  # not an option of mikt

    grid = tmp_path / "g.toml"
    grid.write_text('name = "x"\nsteps = 2048\nseeds = [0]\nbaseline = "toy"\neval_episodes = 1\n'
                    '[[pairs]]\nfrom = ["t"]\nto = "hopper"\n'
                    '[[methods]]\nname = "toy"\nmethod = "toy"\noptions = { init_log_std = -0.5 }\n')
    mikt("study", grid, "--out", tmp_path / "out")
    state = json.loads((tmp_path / "out" / "state.json").read_text())
    study_run = json.loads((registry / "runs" / state["-" + ">hopper|toy|0"] / "run.json").read_text())
    assert study_run["config"]["options"] == {"init_log_std": -0.5}


def test_grid_options_take_the_neutral_key_the_old_one_and_are_checked_when_read(tmp_path):
    from miktcli.studies.grid import load_grid

    head = 'name = "x"\nsteps = 2048\nseeds = [0]\nbaseline = "m"\n[[pairs]]\nfrom = ["t"]\nto = "hopper"\n'
    path = tmp_path / "g.toml"
    for key in ("options", "mikt"):  # `mikt = {...}`: grids of mikt 0.1
        path.write_text(head + f'[[methods]]\nname = "m"\nmethod = "mikt"\n{key} = {{ mi = false }}\n')
        assert load_grid(path).methods[0].options == {"mi": False}
    for body, message in [('options = { mi = false }\nmikt = { mi = false }', "not both"),
                          ("options = { mi_coef = -1 }", "bad mikt option: field 'mi_coef'"),
                          ("options = { lateral = 'diagonal' }", "bad mikt option: field 'lateral'")]:
        path.write_text(head + f'[[methods]]\nname = "m"\nmethod = "mikt"\n{body}\n')
        with pytest.raises(Exception, match=message):
            load_grid(path)


def test_every_field_of_every_options_model_is_a_flag_that_reaches_the_model():
    """A field added to an options model (MiktConfig's next one) is a flag without touching the CLI."""
    import typer

    from miktcli.cli.method_options import flag_of, parse_method_options

    own = {opt for p in typer.main.get_command(app).commands["transfer"].params for opt in p.opts}
    for name, method in METHODS.items():
        if method.options is None:
            continue
        for field, info in method.options.model_fields.items():
            assert flag_of(field) not in own, f"{name}.{field} would be taken by a flag of mikt transfer itself"

            if info.annotation is bool:  # the flag that sets the default
                arg = flag_of(field) if info.default else "--no-" + flag_of(field)[2:]
            else:
                arg = f"{flag_of(field)}={info.default}"

            class Ctx:
                args = [arg]

            given = parse_method_options(Ctx(), name, method.options)
            assert method.options.model_validate(given) == method.options()


def test_the_cli_hint_comes_from_the_error_type():
    from miktcli.cli.transfer import flag_hint

    assert flag_hint(TeacherCountError("any words", given=1, minimum=0, maximum=0)) == "drop --from"
    assert flag_hint(TeacherCountError("other words", given=0, minimum=1, maximum=None)).startswith("add --from")
    assert flag_hint(TeacherMismatchError("x", stated="hidden")).startswith("--hidden")
    assert flag_hint(TeacherMismatchError("x", stated="encoder_widths")).startswith("--encoder-width")
    assert flag_hint(TeacherMismatchError("x", stated=None)) is None
    assert flag_hint(MethodOptionError("x", method="mikt", option="mi_coef")) == \
        "see --mi-coef under `mikt transfer --help`"
