"""Plots along the chainage: min/max envelopes per pixel column, drawn by matplotlib as SVG.

A run holds a sample every few centimetres over kilometres; a plot has about a thousand pixel
columns. :class:`~catenary.measurement.envelope.EnvelopeGrid` (the core's) keeps, batch by
batch, each wire's minimum and maximum of each quantity per column, and the plots draw them as
a line through every column's minimum and maximum: the picture is that of every sample drawn
at the plot's resolution, and no local minimum (a hot spot) is ever averaged away. Memory is
the number of columns, whatever the run's length.

Figures use matplotlib's object API (``Figure``, no pyplot and no global state), written as
SVG with text kept as text, ids salted per figure so that several can share one page.
"""

from __future__ import annotations

import io
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

import numpy as np
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from catenary.arrays import FloatArray, IntArray
from catenary.measurement.envelope import EnvelopeGrid

__all__ = [
    "LEVEL_COLOURS",
    "PLOT_COLUMNS",
    "Boundary",
    "LimitLine",
    "Marker",
    "Panel",
    "Series",
    "TrendSeries",
    "histogram_figure",
    "profile_figure",
    "svg",
    "trend_figure",
    "wire_colour",
]

PLOT_COLUMNS = 1100
"""Pixel columns of a plot's axes at the figure's width (12.4 in at 100 dpi, less margins)."""

WIRE_COLOURS = ("#1f6fb4", "#f07f0e", "#2a9d3a", "#8c4fb8", "#17a2b8", "#a05a2c")
LEVEL_COLOURS = {"plan": "#b08900", "urgent": "#d9600f", "critical": "#c0231a"}
MAST_COLOUR = "#8a94a3"


@dataclass(frozen=True)
class Boundary:
    """A span boundary on the chainage: a mast's code (or None) at ``chainage_m``."""

    chainage_m: float
    label: str | None


@dataclass(frozen=True)
class LimitLine:
    """A horizontal limit on panel ``panel``; ``dotted`` for an average-based limit."""

    value: float
    level: str
    label: str
    dotted: bool = False
    panel: int = 0


@dataclass(frozen=True)
class Marker:
    """A point to mark on the first panel (a span's minimum), in the colour ``colour``."""

    chainage_m: float
    value: float
    colour: str


@dataclass(frozen=True)
class Series:
    """One line of a panel: quantity ``quantity`` of grid wire ``wire``, ``width`` points wide;
    ``label`` names it in the legend (once per label)."""

    wire: int
    quantity: str
    colour: str
    label: str
    width: float = 0.9


@dataclass(frozen=True)
class Panel:
    """One panel of a profile figure: its axis label and its lines."""

    label: str
    series: tuple[Series, ...]


def wire_colour(wire: int) -> str:
    """The colour of contact wire ``wire`` in every plot (blue, orange, ...: the paper's)."""
    return WIRE_COLOURS[wire % len(WIRE_COLOURS)]


def _masts(axes: Sequence[Axes], boundaries: Sequence[Boundary], low: float, high: float) -> None:
    inside = [b for b in boundaries if low <= b.chainage_m <= high]
    for ax in axes:
        for b in inside:
            ax.axvline(b.chainage_m, color=MAST_COLOUR, lw=0.7, ls=(0, (4, 3)), zorder=0)
    labelled = [b for b in inside if b.label]
    if not labelled:
        return
    top = axes[0].secondary_xaxis("top")
    top.set_xticks([b.chainage_m for b in labelled], [b.label or "" for b in labelled])
    top.tick_params(labelsize=8, length=3, rotation=90 if len(labelled) > 24 else 0)
    top.set_xlabel("mast", fontsize=9, color="#3b4450")


def _limit_lines(ax: Axes, limits: Sequence[LimitLine]) -> None:
    for line in limits:
        colour = LEVEL_COLOURS.get(line.level, "#5b6675")
        ax.axhline(line.value, color=colour, lw=1.1, ls=":" if line.dotted else "--")
        ax.annotate(
            line.label,
            (1.0, line.value),
            xycoords=("axes fraction", "data"),
            xytext=(-4, 3),
            textcoords="offset points",
            ha="right",
            fontsize=8,
            color=colour,
        )
    if limits:
        values = [line.value for line in limits]
        span = max(values) - min(values)
        bottom, ceiling = ax.get_ylim()
        pad = 0.05 * max(ceiling - bottom, span)
        ax.set_ylim(min(bottom, min(values) - pad), max(ceiling, max(values) + pad))


def _markers(ax: Axes, markers: Sequence[Marker], unit: str) -> Line2D | None:
    for m in markers:
        ax.plot(m.chainage_m, m.value, "s", ms=5.5, mfc="none", mew=1.2, color=m.colour)
    if not markers:
        return None
    lowest = min(markers, key=lambda m: m.value)
    ax.annotate(
        f"min {lowest.value:.2f} {unit} at {lowest.chainage_m:.1f} m",
        (lowest.chainage_m, lowest.value),
        xytext=(8, 2),
        textcoords="offset points",
        fontsize=8.5,
        color="#1d2430",
        bbox={"boxstyle": "square,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85},
    )
    return Line2D([], [], ls="none", marker="s", mfc="none", color="#1d2430", label="span minimum")


def profile_figure(
    grid: EnvelopeGrid,
    first: int,
    last: int,
    panels: Sequence[Panel],
    *,
    boundaries: Sequence[Boundary] = (),
    limits: Sequence[LimitLine] = (),
    markers: Sequence[Marker] = (),
    marker_unit: str = "mm",
) -> Figure:
    """Stacked panels along the chainage of bins ``first:last`` of ``grid``, top to bottom,
    span boundaries (and mast codes above) across them; ``markers`` go on the first panel."""
    low = grid.start_m + first * grid.bin_m
    high = grid.start_m + last * grid.bin_m
    fig = Figure(figsize=(12.4, 2.5 * len(panels) + 1.2), dpi=100, layout="constrained")
    axes: list[Axes] = list(fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0])
    legend: dict[str, Line2D] = {}
    for number, (ax, panel) in enumerate(zip(axes, panels, strict=True)):
        for s in panel.series:
            if not grid.has_data(s.wire, s.quantity, first, last):
                continue
            x, y = grid.series(s.wire, s.quantity, first, last)
            ax.plot(x, y, color=s.colour, lw=s.width)
            legend.setdefault(s.label, Line2D([], [], color=s.colour, lw=1.6, label=s.label))
        ax.set_ylabel(panel.label, fontsize=9.5)
        ax.grid(axis="y", color="#e3e7ec", lw=0.6)
        ax.tick_params(labelsize=8.5)
        _limit_lines(ax, [line for line in limits if line.panel == number])
    handle = _markers(axes[0], [m for m in markers if low <= m.chainage_m <= high], marker_unit)
    handles = [*legend.values(), *([handle] if handle is not None else [])]
    _masts(axes, boundaries, low, high)
    axes[-1].set_xlim(low, high)
    axes[-1].set_xlabel("chainage [m]", fontsize=9.5)
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=len(handles), fontsize=9)
    return fig


def histogram_figure(
    edges: FloatArray, counts: IntArray, total: int, tolerance_mm: float, title: str
) -> Figure:
    """Bars of ``counts`` (share of ``total`` points) per bin of ``edges`` [mm], with the
    ``±tolerance_mm`` band marked."""
    fig = Figure(figsize=(8.0, 3.6), dpi=100, layout="constrained")
    ax = fig.subplots()
    share = 100.0 * counts / max(total, 1)
    ax.bar(edges[:-1], share, width=np.diff(edges), align="edge", color="#1f6fb4", ec="#ffffff")
    for x in (-tolerance_mm, tolerance_mm):
        ax.axvline(x, color=LEVEL_COLOURS["urgent"], lw=1.1, ls="--")
    ax.set_xlabel("difference B − A in residual thickness [mm]", fontsize=9.5)
    ax.set_ylabel("share of points [%]", fontsize=9.5)
    ax.set_title(title, fontsize=10)
    ax.grid(axis="y", color="#e3e7ec", lw=0.6)
    ax.tick_params(labelsize=8.5)
    return fig


@dataclass(frozen=True)
class TrendSeries:
    """One history on a trend figure: each run's minimum residual thickness [mm] at its start
    (``since_repair`` false: before the wire's last repair, drawn hollow and not fitted), and
    the fitted line with its confidence band at ``fit_times`` (empty: no line)."""

    label: str
    colour: str
    times: Sequence[datetime]
    values_mm: FloatArray
    since_repair: Sequence[bool]
    fit_times: Sequence[datetime]
    fit_mm: FloatArray
    band_low_mm: FloatArray
    band_high_mm: FloatArray


def trend_figure(series: Sequence[TrendSeries], limits: Sequence[LimitLine], title: str) -> Figure:
    """Minimum residual thickness over time: each history's runs, its fitted line and band,
    and the limits as horizontal lines."""
    fig = Figure(figsize=(10.0, 4.8), dpi=100, layout="constrained")
    ax = fig.subplots()
    for s in series:
        kept = np.asarray(s.since_repair, dtype=bool)
        times = np.asarray(s.times, dtype=object)
        ax.plot(times[kept], s.values_mm[kept], "o", ms=5, color=s.colour, label=s.label)
        if not kept.all():
            ax.plot(times[~kept], s.values_mm[~kept], "o", ms=5, mfc="none", color=s.colour)
        if len(s.fit_times):
            fit_times = np.asarray(s.fit_times, dtype=object)
            ax.plot(fit_times, s.fit_mm, color=s.colour, lw=1.2)
            ax.fill_between(
                fit_times, s.band_low_mm, s.band_high_mm, color=s.colour, alpha=0.15, lw=0
            )
    ax.set_ylabel("minimum residual thickness [mm]", fontsize=9.5)
    ax.set_xlabel("run start (UTC)", fontsize=9.5)
    ax.set_title(title, fontsize=10)
    ax.grid(axis="y", color="#e3e7ec", lw=0.6)
    ax.tick_params(labelsize=8.5)
    _limit_lines(ax, limits)
    if series:
        ax.legend(fontsize=8, loc="lower left")
    return fig


_XML_PROLOGUE = re.compile(r"^.*?(?=<svg)", re.DOTALL)
_METADATA = re.compile(r"<metadata>.*?</metadata>\s*", re.DOTALL)


def svg(fig: Figure, salt: str) -> str:
    """The figure as an inline ``<svg>`` element: text as text, ids salted with ``salt`` (one
    per figure of a page), no XML prologue and no metadata."""
    buffer = io.StringIO()
    with rc_context({"svg.fonttype": "none", "svg.hashsalt": salt}):
        fig.savefig(buffer, format="svg", metadata={"Date": None})
    text = _XML_PROLOGUE.sub("", buffer.getvalue(), count=1)
    return _METADATA.sub("", text, count=1)
