"""A transfer run's teacher-free student becomes a teacher (`mikt teacher add`), and teaches in turn."""

import json

import pytest

from helpers import mikt


@pytest.mark.slow
def test_a_student_is_added_as_a_teacher_and_teaches_the_next_body(registry, teacher):
    first = json.loads(mikt("transfer", "--from", "tiny", "--to", "centipede-four", "--steps", 2048,
                            "--eval-episodes", 1, "--json").stdout)["run"]
    out = mikt("teacher", "add", first, "--name", "four-from-hopper")
    assert out.stdout.strip() == "four-from-hopper@v1"
    assert f"added {first}'s student (mikt from tiny@v1, on centipede-four)" in out.output
    card = json.loads(mikt("teacher", "show", "four-from-hopper", "--json").stdout)
    assert (card["env"], card["obs_dim"], card["source_run"]) == ("centipede-four", 97, first)
    assert card["trained_with"] == ["tiny@v1"] and card["method"] == "mikt"
    # the chain goes on: the student teaches a six-legged body
    second = json.loads(mikt("transfer", "--from", "four-from-hopper", "--to", "centipede-six", "--steps", 2048,
                             "--eval-episodes", 1, "--json").stdout)
    assert second["eval_without_teacher"]["episodes"] == 1
    assert json.loads(mikt("eval", "four-from-hopper", "--episodes", 1, "--json").stdout)["episodes"] == 1


def test_only_a_completed_transfer_has_a_student_to_add(registry, ctrl_c_at_second_update, teacher):
    teacher_run = json.loads(mikt("runs", "--json").stdout)[0]["run_id"]
    assert "is a teacher run: its teacher is published already (tiny@v1)" in mikt(
        "teacher", "add", teacher_run, "--name", "x", code=1).output
    mikt("transfer", "--from", "tiny", "--to", "hopper", "--steps", 6144, code=1)  # interrupted at 2,048
    assert "is interrupted: only a completed transfer has a student to add" in mikt(
        "teacher", "add", "run2", "--name", "x", code=1).output
    assert "unknown run 'run9'" in mikt("teacher", "add", "run9", "--name", "x", code=1).output
    assert not (registry / "teachers" / "x").exists()
