"""What a run was started with survives --resume: the final evaluation's episode count is
recorded in the card, and a resumed run evaluates with it rather than with the flag's default."""

import json

from helpers import mikt
from miktcli.registry.runs import open_run


def test_eval_episodes_are_recorded_and_kept_on_resume(registry, ctrl_c_at_second_update):
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 4096, "--eval-episodes", 3, code=1)
    assert open_run(registry, "run1").card.config.eval_episodes == 3
    ctrl_c_at_second_update()
    result = json.loads(mikt("transfer", "--resume", "run1", "--json").stdout)
    assert result["eval_without_teacher"]["episodes"] == 3


def test_eval_episodes_given_with_resume_still_decide(registry, ctrl_c_at_second_update):
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 4096, "--eval-episodes", 3, code=1)
    ctrl_c_at_second_update()
    result = json.loads(mikt("transfer", "--resume", "run1", "--eval-episodes", 2, "--json").stdout)
    assert result["eval_without_teacher"]["episodes"] == 2


def test_a_card_from_before_the_field_resumes_with_the_command_s_count(registry, ctrl_c_at_second_update):
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 4096, "--eval-episodes", 3, code=1)
    path = registry / "runs" / "run1" / "run.json"
    card = json.loads(path.read_text())
    del card["config"]["eval_episodes"]
    path.write_text(json.dumps(card))
    ctrl_c_at_second_update()
    result = json.loads(mikt("transfer", "--resume", "run1", "--json").stdout)
    assert result["eval_without_teacher"]["episodes"] == 10


def test_a_study_cell_records_the_grid_s_eval_episodes(registry):
    from miktcli.studies.grid import Grid
    from miktcli.studies.study import Study

    grid = Grid.model_validate({"name": "g", "steps": 2048, "seeds": [0], "eval_episodes": 2,
                                "methods": [{"name": "vpg", "method": "vpg"}],
                                "pairs": [{"from": ["x"], "to": "centipede-four"}]})
    [(_, run)] = Study(grid, registry.parent / "out", registry).prepare("test")
    assert run.card.config.eval_episodes == 2


def test_a_resume_may_change_the_update_mode_and_the_card_says_from_which_step(registry, ctrl_c_at_second_update,
                                                                              monkeypatch):
    from miktcli.engine import ppo

    monkeypatch.setattr(ppo, "compiled", lambda loss: loss)  # what is recorded is tested here, not torch.compile
    mikt("teacher", "train", "hopper", "--steps", 6144, "--no-compile", code=1)  # interrupted at 2,048
    ctrl_c_at_second_update()
    mikt("teacher", "train", "--resume", "run1", "--compile")
    ppo = json.loads(mikt("inspect", "run1", "--json").stdout)["card"]["config"]["ppo"]
    assert ppo["compile_loss"] is True
    assert ppo["compile_reason"] == "off: asked (--no-compile); from step 2,048: on, asked on resume (--compile)"


def test_auto_compile_probes_the_compiler_and_a_broken_one_turns_it_off(monkeypatch):
    from miktcli.engine import compile_choice

    monkeypatch.setenv("CXX", "/bin/false")
    compile_choice.compiler_works.cache_clear()
    compiled, reason = compile_choice.decide_compile(None, 2_000_000)
    assert not compiled and reason == "auto: off, the C++ compiler /bin/false does not compile a test program"
    compile_choice.compiler_works.cache_clear()
