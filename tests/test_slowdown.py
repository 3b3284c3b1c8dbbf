"""Runs whose update slows as they train are flagged (the measure: update time over rollout time)."""

import pytest

from miktcli.workflows.slowdown import WINDOW, SlowdownWatch, update_ratio


def test_a_steady_run_is_not_flagged_and_a_tripled_update_is_once_per_phase():
    watch = SlowdownWatch()
    assert all(watch.add("ramp", i, 0.5 + 0.1 * (i % 3)) is None for i in range(100))
    flagged = [watch.add("ramp", 100 + i, 1.6) for i in range(3 * WINDOW)]
    records = [r for r in flagged if r is not None]
    assert len(records) == 1 and records[0]["phase"] == "ramp" and records[0]["factor"] >= 2.0
    # a new phase starts its own baseline: a slower update there is not a slowdown by itself
    assert all(watch.add("teacher-free", 200 + i, 1.6) is None for i in range(3 * WINDOW))


def test_a_resumed_watch_knows_what_it_flagged_and_rows_without_timings_are_skipped():
    history = [("ramp", i, 0.5) for i in range(WINDOW)] + [("ramp", WINDOW + i, 1.5) for i in range(WINDOW)]
    assert SlowdownWatch(history).add("ramp", 99, 1.5) is None  # flagged while the history was read
    assert update_ratio({"time_rollout": 2.0, "time_update": 1.0}) == 0.5
    assert update_ratio({}) != update_ratio({})  # NaN
    watch = SlowdownWatch()
    assert all(watch.add("x", i, float("nan")) is None for i in range(3 * WINDOW))


@pytest.mark.parametrize("factor", [1.5, 2.5])
def test_the_threshold_is_twice_the_phase_s_lowest_rolling_median(factor):
    watch = SlowdownWatch([("p", i, 1.0) for i in range(WINDOW)])
    records = [watch.add("p", WINDOW + i, factor) for i in range(WINDOW)]
    assert any(records) == (factor >= 2.0)


@pytest.mark.slow
def test_a_run_that_slows_says_so_in_its_card(registry, monkeypatch):
    import json
    import time

    from typer.testing import CliRunner

    from miktcli.cli.app import app
    from miktcli.engine.ppo import PPOTrainer
    from miktcli.workflows import slowdown

    monkeypatch.setattr(slowdown, "WINDOW", 1)
    original = PPOTrainer.update

    def slower_from_the_third(self, batch):
        # six times its own update time from the third iteration: a jump that a busy machine scales with the
        # rest (a fixed 1.5 s sleep was flagged an iteration late on a machine running two trainings beside)
        start = time.perf_counter()
        out = original(self, batch)
        if self.iteration >= 2:
            time.sleep(5 * (time.perf_counter() - start))
        return out

    monkeypatch.setattr(PPOTrainer, "update", slower_from_the_third)
    result = CliRunner().invoke(app, ["teacher", "train", "hopper", "--steps", "8192", "--name", "t"])
    assert result.exit_code == 0, result.output
    card = json.loads((registry / "runs" / "run1" / "run.json").read_text())
    (record,) = card["result"]["slowdowns"]
    assert record["phase"] == "train" and record["step"] == 6144 and record["factor"] >= 2.0
