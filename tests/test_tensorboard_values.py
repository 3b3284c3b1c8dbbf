"""The TensorBoard view never fails the run: values float32 cannot hold (finite beyond its range,
±inf, NaN, ints past float64) are left out of the event file, and metrics.jsonl records them as they were."""

import json
import math

from helpers import mikt
from miktcli.registry.runs import open_run
from miktcli.registry.tensorboard import read_scalars

ODD = {"return_mean": -8.7e300, "loss_value": math.inf, "approx_kl": math.nan, "entropy": 10**400, "clip_frac": 0.25}


def test_a_run_whose_metrics_overflow_float32_trains_to_its_end(registry, monkeypatch):
    from miktcli.engine.ppo import PPOTrainer

    original = PPOTrainer.run

    def odd_metrics(self):
        for metrics in original(self):
            yield {**metrics, **ODD}

    monkeypatch.setattr(PPOTrainer, "run", odd_metrics)
    mikt("transfer", "--to", "hopper", "--method", "vpg", "--steps", 4096, "--eval-episodes", 1)
    run = open_run(registry, "run1")
    assert run.card.status == "completed"
    rows = [json.loads(line) for line in run.metrics_path.read_text().splitlines()]
    assert len(rows) == 2 and rows[0]["return_mean"] == -8.7e300  # the record keeps the value exactly
    scalars = read_scalars(run.events_path)
    assert [v for _, tag, v in scalars if tag == "ppo/clip_frac"] == [0.25, 0.25]
    tags = {tag for _, tag, _ in scalars}
    for tag in ("episode/return_mean", "loss/value", "ppo/approx_kl", "ppo/entropy"):
        assert tag not in tags  # TensorBoard cannot show them; the view leaves them out
