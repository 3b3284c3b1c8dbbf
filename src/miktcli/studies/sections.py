"""The report's sections, registered by name.

results.md is its intro (the study, left-out runs, failed cells, teachers), then a list of sections, then the
table of every cell's run. The standard sections (`STANDARD`) come in every report; a grid asks for more with
`[[report]]` tables, each naming a section and giving its options:

    [[report]]
    section = "reference"
    file = "../reference/cat-uai2022.toml"   # relative to the grid file
    method = "mikt"
    label = "CAT"

A section is a `Section`: its name, a line saying what it shows, its options model (checked when the study is
opened, so a bad option is an error before any cell trains) and `render(SectionInput) -> Rendered`: the
Markdown lines, and optionally plain data that summary.json holds under `json_key`. A section may draw figures
into the study folder as it renders. A new section is a function and one `register(Section(...))`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from miktcli.errors import MiktError, describe_validation_error
from miktcli.studies.aggregates import AcrossPairs, across_pairs, baseline_targets, unavailable
from miktcli.studies.grid import Grid, ReportRequest
from miktcli.studies.handover import pair_handover_json
from miktcli.studies.random_cache import CACHE_FILE, INITIAL_CACHE_FILE, study_random_returns
from miktcli.studies.reference import load_reference
from miktcli.studies.render_figures import write_profiles
from miktcli.studies.render_json import across_pairs_json
from miktcli.studies.render_markdown import across_pairs_lines, handover_lines, pair_lines, slowdown_lines
from miktcli.studies.render_reference import reference_lines
from miktcli.studies.summary import StudySummary


@dataclass(frozen=True)
class SectionInput:
    summary: StudySummary
    out_dir: Path  # the study folder: figures go here
    options: BaseModel | None = None  # the section's options, validated


@dataclass(frozen=True)
class Rendered:
    markdown: list[str]
    data: dict[str, Any] | None = None  # summary.json's entry under the section's json_key


class NoOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")


@dataclass(frozen=True)
class Section:
    name: str
    about: str
    render: Callable[[SectionInput], Rendered]
    options: type[BaseModel] = NoOptions
    json_key: str | None = None


SECTIONS: dict[str, Section] = {}
STANDARD = ("across-pairs", "pairs", "hand-over", "slowdowns")  # every report, in this order


def register(section: Section) -> Section:
    if section.name in SECTIONS:
        raise ValueError(f"a report section named '{section.name}' is already registered")
    SECTIONS[section.name] = section
    return section


@dataclass(frozen=True)
class Requested:
    section: Section
    options: BaseModel = field(default_factory=NoOptions)


def requested(grid: Grid) -> list[Requested]:
    """The standard sections, then those the grid asks for with their options checked: a one-line error
    naming the registered sections or the bad option."""
    out = [Requested(SECTIONS[name]) for name in STANDARD]
    for i, request in enumerate(grid.report):
        out.append(Requested(_section(request, i), _options(grid, request, i)))
    return out


def _section(request: ReportRequest, i: int) -> Section:
    if request.section not in SECTIONS:
        raise MiktError(f"grid report[{i}]: unknown section '{request.section}'",
                        hint=f"sections: {', '.join(sorted(SECTIONS))}")
    if request.section in STANDARD:
        raise MiktError(f"grid report[{i}]: section '{request.section}' is in every report already")
    return SECTIONS[request.section]


def _options(grid: Grid, request: ReportRequest, i: int) -> BaseModel:
    section = SECTIONS[request.section]
    try:
        options = section.options.model_validate(request.options)
    except ValidationError as err:
        fields = ", ".join(section.options.model_fields) or "none"
        raise MiktError(f"grid report[{i}] ({request.section}): {describe_validation_error(err)}",
                        hint=f"its options: {fields}") from None
    check = getattr(options, "check", None)
    if check is not None:  # what needs the grid (a method it has) or the disk (a file beside it)
        options = check(grid, f"grid report[{i}] ({request.section})")
    return options


def render_sections(summary: StudySummary, out_dir: Path) -> list[tuple[Requested, Rendered]]:
    return [(r, r.section.render(SectionInput(summary, out_dir, r.options))) for r in requested(summary.grid)]


# the standard sections ---------------------------------------------------------------------------------------------

def study_across_pairs(summary: StudySummary, out_dir: Path) -> AcrossPairs:
    """The across-pairs numbers, the random-policy returns from the study folder's cache (measuring the
    targets it lacks), or the reason there are none."""
    if not summary.grid.random_returns:
        return unavailable(summary, "the grid says `random_returns = false`")
    targets = baseline_targets(summary)
    if not targets:  # nothing to measure: across_pairs says why there are no numbers
        return across_pairs(summary, {}, CACHE_FILE)
    try:
        random = study_random_returns(out_dir, targets, summary.grid.name)
    except MiktError as err:  # a damaged cache, or a target that cannot be made: said in the section
        return unavailable(summary, f"no random-policy returns: {err}", CACHE_FILE)
    try:  # shown beside R_random, not a scale: without it the numbers stand, and the section says why it is gone
        initial, missing = study_random_returns(out_dir, targets, summary.grid.name, baseline="initial"), None
    except MiktError as err:
        initial, missing = None, f"the initial policy's returns: {err}"
    numbers = across_pairs(summary, random, f"{CACHE_FILE} and {INITIAL_CACHE_FILE} in this folder",
                           initial=initial)
    return dataclasses.replace(numbers, notes=[*numbers.notes, missing]) if missing else numbers


def _across_pairs(given: SectionInput) -> Rendered:
    numbers = study_across_pairs(given.summary, given.out_dir)
    write_profiles(numbers, given.out_dir, given.summary.grid.name)
    return Rendered(across_pairs_lines(numbers), across_pairs_json(numbers))


register(Section("across-pairs", "every method normalised between the random policy and the baseline, IQM and "
                 "mean with bootstrap intervals, probability of improvement, performance profiles",
                 _across_pairs, json_key="across_pairs"))
register(Section("pairs", "per pair: the table at the marks, comparisons over seeds, curves and weights",
                 lambda given: Rendered([line for pair in given.summary.pairs
                                         for line in pair_lines(pair, given.summary.grid.baseline)])))
register(Section("hand-over", "each run with teachers at its drop: the mixed policy and the student alone; per "
                 "pair, beside the baseline from scratch over the same windows",
                 lambda given: Rendered(handover_lines(given.summary), {
                     "by_pair": [pair_handover_json(h) for h in given.summary.handover_pairs]}
                     if given.summary.handover_pairs else None),
                 json_key="handover"))
register(Section("slowdowns", "runs whose update time grew as they trained",
                 lambda given: Rendered(slowdown_lines(given.summary))))


# sections a grid asks for ------------------------------------------------------------------------------------------

class ReferenceOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")

    file: str = Field(description="the reference result (TOML, studies.reference), relative to the grid file")
    method: str = Field(description="the grid's method set beside it")
    label: str = Field("the reference", min_length=1, max_length=40, description="its name in the report")
    fall: tuple[int, int] | None = Field(None, description="two steps: does the seed-mean curve fall between?")
    targets: dict[str, str] = Field(default_factory=dict, description="our target → the reference's, where the "
                                    "reference's runs stand for ours under another name (CAT's centipede-eight "
                                    "saw what centipede-eight-zero-contacts shows)")

    def check(self, grid: Grid, where: str) -> ReferenceOptions:
        if self.method not in {m.name for m in grid.methods}:
            raise MiktError(f"{where}: the grid has no method '{self.method}'",
                            hint=f"its methods: {', '.join(m.name for m in grid.methods)}")
        load_reference(grid.folder / self.file)  # a missing or malformed file is an error now, not after training
        return self


def _reference(given: SectionInput) -> Rendered:
    o, grid = given.options, given.summary.grid
    if not isinstance(o, ReferenceOptions):
        raise TypeError(f"the reference section was given {type(o).__name__}, not its options")
    reference = load_reference(grid.folder / o.file).on_targets(o.targets)
    return Rendered(reference_lines(grid, given.summary, reference, o.method, o.label, o.fall))


register(Section("reference", "a method beside another implementation's published figures (e.g. CAT's logs), "
                 "measured with their estimator", _reference, ReferenceOptions))


def section_data(rendered: list[tuple[Requested, Rendered]]) -> dict[str, Any]:
    return {r.section.json_key: out.data for r, out in rendered if r.section.json_key and out.data is not None}

