"""Files written by mikt 0.1, read as today's: every difference between the two formats, in one place.

Each function takes the raw data (a dict read from JSON or TOML) and returns it in today's form; data written
today passes through unchanged. Run cards, teacher cards, study grids and state.json files of 0.1 are read
with these; a checkpoint of 0.1 has no environment state, so its envs start fresh episodes on resume.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

PPO_KEYS_0_1 = ("autoreset", "init")  # descriptive strings 0.1 recorded among the PPO settings; they set nothing
RUN_CONFIG_KEYS_0_1 = ("encoder_widths", "target_obs_dim", "target_act_dim")  # nothing reads them
OPTIONS_KEY_0_1 = "mikt"  # where 0.1 kept a method's options: in run cards, and in grids whatever the method


def ppo_record(record: dict[str, Any]) -> dict[str, Any]:
    """PPO settings of a card or checkpoint. 0.1 clipped actions for the env and recorded no
    `clip_actions_for_env`, so a missing field means True: resuming or evaluating its runs keeps the reward
    they were trained on. Cards before `flush_denormal` ran their updates with subnormal floats kept."""
    return {"clip_actions_for_env": True, "flush_denormal": False,
            **{k: v for k, v in record.items() if k not in PPO_KEYS_0_1}}


def teacher_card(data: Any) -> Any:
    """A teacher card of 0.1 has no `clip_actions_for_env`: its policies were trained with clipped actions."""
    if isinstance(data, dict) and "clip_actions_for_env" not in data:
        return {**data, "clip_actions_for_env": True}
    return data


def run_config(data: Any) -> Any:
    """A run card's config of 0.1: MIKT's options under `mikt`, and keys that nothing reads (a teacher's
    state dim lives in its card and tensors, checked when it is loaded)."""
    if not isinstance(data, dict):
        return data
    data = {k: v for k, v in data.items() if k not in RUN_CONFIG_KEYS_0_1}
    if OPTIONS_KEY_0_1 in data:
        data["options"] = data.pop(OPTIONS_KEY_0_1)
    return data


def grid_method(data: Any) -> Any:
    """A grid's method of 0.1 gives its options under `mikt`, whatever the method."""
    if not (isinstance(data, dict) and OPTIONS_KEY_0_1 in data):
        return data
    if "options" in data:
        raise ValueError(f"give the method's options once: under `options` or the older `{OPTIONS_KEY_0_1}`, "
                         "not both")
    data = dict(data)
    data["options"] = data.pop(OPTIONS_KEY_0_1)
    return data


def cell_key(teachers: list[str], to: str, method_name: str, seed: int) -> str:
    """A cell's key in a state.json of 0.1, where every cell named its pair's teachers (today a method without
    teachers has one run per target, shared by the pairs)."""
    return f"{'+'.join(teachers)}>{to}|{method_name}|{seed}"


def adopt_cells(cells: dict[str, str], keys: Iterable[tuple[str, str]]) -> dict[str, str]:
    """state.json's cells with each 0.1 key of `keys` (today's key, 0.1's key) under today's key; where two
    0.1 cells now share a run, the first one's run is kept."""
    cells = dict(cells)
    for key, old in keys:
        if key != old and old in cells:
            run_id = cells.pop(old)
            cells.setdefault(key, run_id)
    return cells
