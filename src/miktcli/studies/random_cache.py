"""A study's random-policy returns (the zero of its normalised scores) and its initial-policy returns (reported
beside them), each cached in its folder.

`random-returns.json` has the format of the project's committed random-policy.json: `policy`, `code_version`,
`command` and `targets` (target → episodes, seed, return_mean, return_std, length_mean, returns). A target
missing from it is measured by the committed protocol (miktcli.engine.random_policy: 100 episodes from seed 0,
uniform over the action box) and written back atomically, each entry it adds with the code version and the
study that measured it; entries already there are never measured again. `initial-policy-returns.json` is the
same for the initial policy (N(0, 1) per action dimension, unclipped; miktcli.engine.random_policy).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

from miktcli.engine.random_policy import EPISODES, INITIAL_POLICY, POLICY, SEED, initial_policy_returns, random_returns
from miktcli.errors import MiktError
from miktcli.registry.cards import code_version
from miktcli.registry.files import write_text_atomic

CACHE_FILE = "random-returns.json"
INITIAL_CACHE_FILE = "initial-policy-returns.json"
# each baseline policy: its cache file, its description and the name of its measurement in this module
BASELINES = {"uniform": (CACHE_FILE, POLICY, "random_returns"),
             "initial": (INITIAL_CACHE_FILE, INITIAL_POLICY, "initial_policy_returns")}
MAX_CACHE_BYTES = 16 * 1024 * 1024  # five targets of 100 episodes are 30 kB; more is not a cache of ours

Measure = Callable[[str, int, int], dict]  # (target, episodes, seed) → an entry of `targets`


def read_cache(path: Path, policy: str = POLICY) -> dict:
    """The cache file's document, or an empty one where there is none; a damaged file is a MiktError (it is
    not ours to overwrite)."""
    if not path.is_file():
        return {"policy": policy, "code_version": code_version(), "command": "", "targets": {}}
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_CACHE_BYTES + 1)
        if len(raw) > MAX_CACHE_BYTES:
            raise MiktError(f"{path} is larger than {MAX_CACHE_BYTES:,} bytes")
        data = json.loads(raw.decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise MiktError(f"{path} cannot be read: {type(err).__name__}: {err}") from None
    targets = data.get("targets") if isinstance(data, dict) else None
    if not isinstance(targets, dict) or not all(isinstance(e, dict) for e in targets.values()):
        raise MiktError(f"{path} is not a random-returns file (expected an object with `targets`)")
    for target, entry in targets.items():
        value = entry.get("return_mean")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise MiktError(f"{path}: {target} has no finite return_mean")
    return data


def study_random_returns(folder: Path, targets: list[str], study: str, measure: Measure | None = None,
                         baseline: str = "uniform") -> dict[str, float]:
    """Each target's mean return under the baseline policy (`uniform`, the random policy, or `initial`): from
    the folder's cache, measuring (and caching) the missing ones. Raises MiktError where the cache is damaged or
    a target cannot be measured."""
    cache_file, policy, function = BASELINES[baseline]
    if measure is None:  # looked up here, so a test can stand in for the measurement
        measure = random_returns if baseline == "uniform" else initial_policy_returns
    path = folder / cache_file
    data = read_cache(path, policy)
    missing = [t for t in targets if t not in data["targets"]]
    for target in missing:  # written after each: a failure (or Ctrl-C) later keeps what was measured
        entry = measure(target, EPISODES, SEED)
        entry["code_version"] = code_version()
        entry["measured_by"] = f"the report of study `{study}` (miktcli.engine.random_policy.{function})"
        data["targets"][target] = entry
        if not data.get("command"):
            data["command"] = (f"measured by the reports of study `{study}`: "
                               f"miktcli.engine.random_policy.{function}(target, episodes={EPISODES}, seed={SEED}) "
                               "for each target it lacked")
        folder.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps(data, indent=1) + "\n")
    return {t: float(data["targets"][t]["return_mean"]) for t in targets}
