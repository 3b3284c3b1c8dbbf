"""Curves as text (for the terminal) and as PNG files (matplotlib, headless)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from miktcli.outfiles import atomic_output

MARKERS = "●○◆◇▲△■□"


def text_plot(series: dict[str, list[tuple[float, float]]], width: int = 64, height: int = 12,
              y_range: tuple[float, float] | None = None) -> str:
    """A small scatter chart of several (x, y) series; one marker per series, legend underneath."""
    points = [(x, y) for pts in series.values() for x, y in pts if math.isfinite(y)]
    if not points:
        return "(no data)"
    x0, x1 = min(p[0] for p in points), max(p[0] for p in points)
    y0, y1 = y_range or (min(p[1] for p in points), max(p[1] for p in points))
    if y1 == y0:
        y0, y1 = y0 - 0.5, y1 + 0.5
    grid = [[" "] * width for _ in range(height)]
    for marker, pts in zip(MARKERS, series.values(), strict=False):
        for x, y in pts:
            if not math.isfinite(y):
                continue
            col = 0 if x1 == x0 else round((x - x0) / (x1 - x0) * (width - 1))
            row = height - 1 - round((min(max(y, y0), y1) - y0) / (y1 - y0) * (height - 1))
            grid[row][col] = marker
    label_w = max(len(f"{y1:.3g}"), len(f"{y0:.3g}"))
    lines = []
    for i, row in enumerate(grid):
        label = f"{y1:.3g}" if i == 0 else f"{y0:.3g}" if i == height - 1 else ""
        lines.append(f"{label:>{label_w}} │{''.join(row)}")
    lines.append(" " * label_w + " └" + "─" * width)
    lines.append(" " * label_w + f"  {x0:,.0f}" + f"{x1:,.0f} steps".rjust(width - len(f"{x0:,.0f}")))
    legend = "  ".join(f"{m} {name}" for m, name in zip(MARKERS, series, strict=False))
    if len(series) > len(MARKERS):  # one marker per series: say which ones the chart could not draw
        legend += f"  (not drawn: {', '.join(list(series)[len(MARKERS):])})"
    lines.append(" " * label_w + "  " + legend)
    return "\n".join(lines)


Series = dict[str, list[tuple[float, float]]]
Bands = dict[str, list[tuple[float, float, float]]]


def series_colors(panels: list[Series], palette: list[str], order: Sequence[str] = ()) -> dict[str, str]:
    """One colour per series name across every panel: the names in `order` first, then the others as they first
    appear. A study passes its methods, so vpg has one colour in every figure of the report, including a pair
    that has no mikt curve yet (or a summary panel that never will)."""
    colors: dict[str, str] = {}
    for series in [dict.fromkeys(order), *panels]:
        for name in series:
            colors.setdefault(name, palette[len(colors) % len(palette)])
    return colors


LINESTYLES = ("-", "--", ":", "-.")


def series_linestyles(colors: dict[str, str], palette_size: int) -> dict[str, str]:
    """A line style per name of `series_colors`: solid for the palette's first round of colours, then dashed,
    dotted… so that a figure with more curves than colours (a two-teacher run logs 12 weights) never draws two
    curves alike."""
    return {name: LINESTYLES[(i // palette_size) % len(LINESTYLES)] for i, name in enumerate(colors)}


def _draw(ax, series: Series, title: str, ylabel: str, bands: Bands | None, colors: dict[str, str],
          labels: Mapping[str, str] | None = None, xlabel: str = "environment steps",
          styles: Mapping[str, str] | None = None) -> None:
    for name, pts in series.items():
        xs, ys = zip(*pts, strict=True) if pts else ((), ())
        # the legend may say more than the name (a curve of fewer seeds than the others); the colour stays the name's
        ax.plot(xs, ys, label=(labels or {}).get(name, name), linewidth=1.6, color=colors[name],
                linestyle=(styles or {}).get(name, "-"))
        if bands and name in bands and bands[name]:
            bx, lo, hi = zip(*bands[name], strict=True)
            ax.fill_between(bx, lo, hi, alpha=0.2, color=colors[name])
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def png_plot(series: Series, path: Path, title: str, ylabel: str, bands: Bands | None = None,
             order: Sequence[str] = (), labels: Mapping[str, str] | None = None) -> Path:
    """Line plot of series (and optional mean ± std bands as (x, lo, hi)) written atomically to a PNG;
    `labels` gives a series a legend text other than its name."""
    return png_panels([(series, title, bands)], path, ylabel, order=order, labels=[labels])


def png_panels(panels: list[tuple[Series, str, Bands | None]], path: Path, ylabel: str, columns: int = 3,
               order: Sequence[str] = (), labels: Sequence[Mapping[str, str] | None] = (),
               xlabel: str = "environment steps") -> Path:
    """One panel per (series, title, bands), `columns` to a row, in one PNG (a study's summary figure); series
    colours by name, `order` first (see series_colors); `labels`, one mapping per panel, their legend texts."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(columns, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(7 * cols if cols == 1 else 5 * cols, 4.2 * rows), dpi=110,
                             squeeze=False)
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = series_colors([series for series, _, _ in panels], palette, order)
    styles = series_linestyles(colors, len(palette))
    panel_labels = [*labels, *[None] * (len(panels) - len(labels))]
    for ax, (series, title, bands), names in zip(axes.flat, panels, panel_labels, strict=False):
        _draw(ax, series, title, ylabel, bands, colors, names, xlabel, styles)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    fig.tight_layout()
    try:
        with atomic_output(path, ".png") as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return Path(path)


def png_performance_profiles(profiles: Mapping[str, tuple[Sequence[float], Sequence[float], Sequence[float],
                                                          Sequence[float]]],
                             path: Path, title: str, xlabel: str = "normalised score τ",
                             order: Sequence[str] = ()) -> Path:
    """Performance profiles (Agarwal et al. 2021): per method (thresholds, fraction above, band low, band high),
    one curve each with its bootstrap band, in one PNG; colours by name, `order` first (default: as given)."""
    series = {name: list(zip(taus, point, strict=True)) for name, (taus, point, _, _) in profiles.items()}
    bands = {name: list(zip(taus, low, high, strict=True)) for name, (taus, _, low, high) in profiles.items()}
    return png_panels([(series, title, bands)], path, "fraction of runs with score > τ", order=order or list(profiles),
                      xlabel=xlabel)
