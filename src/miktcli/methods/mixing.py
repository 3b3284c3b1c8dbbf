"""Every source's mixing weight over training, read back from a MIKT run's metrics.

MIKT logs, per branch (pi: policy, vf: value) and hidden layer j, the student's weight as `p_{branch}_{j}` and,
with two or more teachers, each teacher's weight as `w_{branch}_{j}_t{k}` (k in the card's teacher order) or,
with `mixing = "shared"`, the one teacher share as `w_{branch}_{j}_shared`. A single teacher's weight is not
logged: it is 1 − p. This module turns those rows into one series per (layer, source).
"""

from __future__ import annotations

import re

BRANCHES = {"pi": "policy", "vf": "value"}
_STUDENT = re.compile(r"p_(pi|vf)_(\d+)")
_TEACHER = re.compile(r"w_(pi|vf)_(\d+)_(t\d+|shared)")

Series = dict[str, list[tuple[float, float]]]


# --- the metric names: built and read only here -------------------------------------------------------
def student_key(branch: str, layer: int) -> str:
    """The student's weight in one branch ("pi" or "vf") and hidden layer: `p_pi_0`."""
    return f"p_{branch}_{layer}"


def teacher_key(branch: str, layer: int, source: str) -> str:
    """One teacher's (source `t0`, `t1`, …) or the shared teachers' (`shared`) weight: `w_pi_0_t1`."""
    return f"w_{branch}_{layer}_{source}"


def teacher_sources(teachers: int, shared: bool) -> list[str]:
    """The source names a run with this many teachers logs: `shared`, or `t0`, `t1`, …"""
    return ["shared"] if shared else [f"t{k}" for k in range(teachers)]


def is_mixing_key(key: str) -> bool:
    """A student's or a teacher's mixing weight (the rest of a metrics row is PPO's and MIKT's other terms)."""
    return _STUDENT.fullmatch(key) is not None or _TEACHER.fullmatch(key) is not None


def is_teacher_key(key: str) -> bool:
    return _TEACHER.fullmatch(key) is not None


def student_layers(weights: dict[str, float], branch: str) -> list[float]:
    """The student's weights of one branch, layer by layer, from a dict of metric names."""
    found = {int(m.group(2)): v for k, v in weights.items() if (m := _STUDENT.fullmatch(k)) and m.group(1) == branch}
    return [found[j] for j in sorted(found)]


def source_labels(teachers: list[str]) -> dict[str, str]:
    """A label per logged source name (t0, t1, …, shared) for the given teacher names, in card order."""
    labels = {f"t{k}": name for k, name in enumerate(teachers)}
    labels["shared"] = f"{' + '.join(teachers)} (shared)"
    return labels


def mixing_series(metrics: list[dict], teachers: list[str]) -> dict[str, Series]:
    """{"policy": {"layer 0 student": [(steps, w), …], "layer 0 centipede-four": […], …}, "value": {…}}:
    the student's and every teacher's weight per layer. Empty when the rows hold no mixing weights."""
    labels = source_labels(teachers)
    keys = list(dict.fromkeys(k for row in metrics for k in row))
    logged_teachers = {(m.group(1), m.group(2)) for m in map(_TEACHER.fullmatch, keys) if m}
    out: dict[str, Series] = {}
    for key in keys:
        if m := _STUDENT.fullmatch(key):
            branch, j = m.groups()
            series = out.setdefault(BRANCHES[branch], {})
            points = [(r["steps"], r[key]) for r in metrics if r.get(key) is not None]
            series[f"layer {j} student"] = points
            if len(teachers) == 1 and (branch, j) not in logged_teachers:
                series[f"layer {j} {teachers[0]}"] = [(x, 1.0 - p) for x, p in points]
        elif m := _TEACHER.fullmatch(key):
            branch, j, source = m.groups()
            out.setdefault(BRANCHES[branch], {})[f"layer {j} {labels.get(source, source)}"] = [
                (r["steps"], r[key]) for r in metrics if r.get(key) is not None]
    return {b: dict(sorted(s.items(), key=lambda kv: _order(kv[0], labels))) for b, s in out.items()}


def _order(label: str, labels: dict[str, str]) -> tuple[int, int]:
    """Layer by layer, the student first, then the teachers in card order."""
    layer, _, source = label.removeprefix("layer ").partition(" ")
    names = list(labels.values())
    return int(layer), -1 if source == "student" else names.index(source) if source in names else len(names)
