"""Repeatability: two runs over the same section of line, compared point by point.

The paper's repeatability experiment (section 4.1, figure 16) measures the same wire twice and
counts the points whose residual thickness differs by less than 0.1 mm between the two tests
(more than 90 % in the paper), with a histogram of the differences. Here the two runs are
``samples`` exports (FORMATS.md) of the same line and track, possibly in opposite directions:

1. **Wires.** Wire numbers are per run, so each wire of run A is paired with the wire of run B
   that runs along it: over their common chainage the median ``|stagger_B - stagger_A|`` is
   below ``MATCH_STAGGER_MM``. Pairs are taken in order of that median, each wire once; a wire
   without a partner (one run saw it, the other did not) is left out. Staggers are in the
   *line* frame (positive to the right looking toward increasing chainage), so that runs in
   opposite directions agree: the caller flips the track-frame stagger of a decreasing run.
2. **Shift.** Aligned chainages of two runs still disagree by some decimetres (encoder
   errors). One shift ``s`` for the whole comparison (B is read at A's chainage ``+ s``)
   minimises the mean squared stagger difference of the paired wires: the zigzag's slope of
   10-20 mm/m turns a shift error ``δ`` into a stagger difference ``slope·δ``, so the mean
   square is a parabola ``mean(slope²)·δ² + noise²`` around the true shift. It is searched on
   a coarse grid over ``±max_shift_m``, then on a fine grid around the best coarse shift
   (without the points the coarse fit calls outliers), and the vertex of the parabola through
   the fine minimum and its neighbours gives it to a fraction of a millimetre.
3. **Differences.** At every sample of A within the common chainage of a pair, B's residual
   thickness is interpolated linearly at A's chainage ``+ s`` (never across a gap longer than
   ``MAX_GAP_M`` between B's samples, NaN samples being gaps) and the difference ``B - A``
   kept where both are finite.

For independent noise ``σ_A``, ``σ_B`` in the two runs, the difference at a point has a
standard deviation ``sqrt(σ_A² + 2/3 σ_B²)`` (B interpolated between two samples at a uniform
fraction ``f`` averages its noise to ``σ_B² (f² + (1 - f)²)``, ``2/3 σ_B²`` on average), and a
share ``erf(0.1 / (σ sqrt 2))`` of the points is within 0.1 mm: 91 % for ``σ = 0.06 mm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray, IndexArray, IntArray
from catenary.errors import UserError

__all__ = [
    "MATCH_STAGGER_MM",
    "MAX_GAP_M",
    "MIN_COMMON_M",
    "Comparison",
    "RunProfile",
    "compare_profiles",
]

MATCH_STAGGER_MM = 50.0
"""Largest median stagger difference [mm] of two wires that run along each other. Wires of an
overlap are 200 mm apart or more; a shift of 1 m along a 20 mm/m zigzag moves 20 mm."""

MIN_COMMON_M = 1.0
"""Shortest common chainage [m] over which two wires are compared."""

MAX_GAP_M = 0.1
"""Longest gap [m] between two samples of B that a value of B is interpolated across."""

COARSE_STEP_M = 0.05
"""Step of the coarse shift grid [m]; the fine grid steps ``FINE_STEP_M`` over ±one coarse
step around the best coarse shift."""

FINE_STEP_M = 0.0025

_MATCH_POINTS = 2000  # samples of A per pair for the wire match
_COARSE_POINTS = 20000  # samples of A for the coarse shift search
_FINE_POINTS = 200000  # and for the fine one
_MIN_POINTS = 20  # fewest samples a wire match or a shift fit needs
_OUTLIER_SIGMAS = 5.0  # stagger differences beyond this many robust σ leave the fine fit
_OUTLIER_FLOOR_MM = 5.0  # ... but never below this


@dataclass(frozen=True)
class RunProfile:
    """The contact wire samples of one run (the ``samples`` export's columns), ``(m,)`` each.

    Parameters
    ----------
    chainage_m : array_like of float, shape (m,)
        Aligned chainage of each sample [m], any order (a decreasing run's samples may stay in
        the order of the run). NaN rows are ignored.
    wire : array_like of int, shape (m,)
        Wire number within the run (not comparable between runs).
    stagger_mm : array_like of float, shape (m,)
        Stagger in the *line* frame [mm]: positive to the right looking toward increasing
        chainage (a decreasing run's track-frame stagger with its sign flipped). NaN: none.
    residual_thickness_mm : array_like of float, shape (m,)
        Residual thickness [mm]; NaN: no value.
    """

    chainage_m: FloatArray
    wire: IntArray
    stagger_mm: FloatArray
    residual_thickness_mm: FloatArray

    def __post_init__(self) -> None:
        columns = {
            "chainage_m": np.asarray(self.chainage_m, dtype=np.float64),
            "wire": np.asarray(self.wire, dtype=np.int64),
            "stagger_mm": np.asarray(self.stagger_mm, dtype=np.float64),
            "residual_thickness_mm": np.asarray(self.residual_thickness_mm, dtype=np.float64),
        }
        shapes = {name: array.shape for name, array in columns.items()}
        if len(set(shapes.values())) != 1 or columns["wire"].ndim != 1:
            raise ValueError(f"run profile columns must share one (m,) shape, got {shapes}")
        for name, array in columns.items():
            object.__setattr__(self, name, array)

    @classmethod
    def from_columns(
        cls,
        chainage_m: ArrayLike,
        wire: ArrayLike,
        stagger_mm: ArrayLike,
        residual_thickness_mm: ArrayLike,
    ) -> RunProfile:
        """A profile from any array-likes (converted and checked as in the class)."""
        return cls(
            np.asarray(chainage_m, dtype=np.float64),
            np.asarray(wire, dtype=np.int64),
            np.asarray(stagger_mm, dtype=np.float64),
            np.asarray(residual_thickness_mm, dtype=np.float64),
        )


@dataclass(frozen=True)
class Comparison:
    """Residual thickness of run B minus run A at ``n`` points of A (module docstring).

    Attributes
    ----------
    wire_pairs : tuple of (int, int)
        ``(wire of A, wire of B)`` of every paired wire, best match first.
    shift_m : float
        B's chainage minus A's at the same place on the line [m] (B is read at A's chainage
        ``+ shift_m``).
    stagger_rms_mm : float
        RMS stagger difference of the paired wires at ``shift_m`` [mm], outliers left out: how
        well the runs' wires lie on each other (a few mm when both are right).
    chainage_m : ndarray, shape (n,)
        A's chainage of each compared point [m]; grouped by pair in ``wire_pairs`` order,
        increasing within a pair.
    wire : ndarray of int, shape (n,)
        A's wire number of each point.
    residual_thickness_mm : ndarray, shape (n,)
        A's residual thickness at each point [mm] (B's is this plus ``difference_mm``).
    difference_mm : ndarray, shape (n,)
        B's residual thickness minus A's [mm], finite.
    tolerance_mm, bin_mm : float
        Defaults of :meth:`share_within` and :meth:`histogram` (the paper: 0.1 mm).
    """

    wire_pairs: tuple[tuple[int, int], ...]
    shift_m: float
    stagger_rms_mm: float
    chainage_m: FloatArray
    wire: IntArray
    residual_thickness_mm: FloatArray
    difference_mm: FloatArray
    tolerance_mm: float = 0.1
    bin_mm: float = 0.02
    _abs: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_abs", np.abs(np.asarray(self.difference_mm, np.float64)))

    @property
    def points(self) -> int:
        """Number of compared points ``n``."""
        return int(self._abs.shape[0])

    def share_within(self, tolerance_mm: float | None = None) -> float:
        """Share of the points with ``|B - A| < tolerance_mm`` (default ``self.tolerance_mm``);
        NaN without points."""
        tol = self.tolerance_mm if tolerance_mm is None else tolerance_mm
        return float(np.mean(self._abs < tol)) if self.points else math.nan

    @property
    def mean_mm(self) -> float:
        """Mean difference ``B - A`` [mm]: a bias between the runs."""
        return float(np.mean(self.difference_mm)) if self.points else math.nan

    @property
    def rms_mm(self) -> float:
        """RMS of ``B - A`` [mm]."""
        return float(np.sqrt(np.mean(self._abs**2))) if self.points else math.nan

    @property
    def p95_mm(self) -> float:
        """95th percentile of ``|B - A|`` [mm]."""
        return float(np.percentile(self._abs, 95.0)) if self.points else math.nan

    @property
    def max_abs_mm(self) -> float:
        """Largest ``|B - A|`` [mm]."""
        return float(np.max(self._abs)) if self.points else math.nan

    def histogram(
        self, bin_mm: float | None = None, half_width_mm: float | None = None
    ) -> tuple[FloatArray, IntArray]:
        """Histogram of ``B - A`` in bins of ``bin_mm`` (default ``self.bin_mm``) [mm].

        Parameters
        ----------
        bin_mm : float, optional
            Bin width [mm], positive. Edges are multiples of it, so that ``±tolerance_mm``
            (a multiple of the bin) falls on edges.
        half_width_mm : float, optional
            Bins over ``±half_width_mm`` only (rounded up to a multiple of ``bin_mm``); points
            beyond are not counted. Default: bins cover every point.

        Returns
        -------
        edges : ndarray, shape (k + 1,)
            Bin edges [mm], increasing.
        counts : ndarray of int, shape (k,)
            Points per bin (the last bin includes its right edge).
        """
        width = self.bin_mm if bin_mm is None else bin_mm
        if not (math.isfinite(width) and width > 0.0):
            raise ValueError(f"bin_mm = {width} must be a positive width")
        d = np.asarray(self.difference_mm, dtype=np.float64)
        if half_width_mm is not None:
            k = max(1, math.ceil(half_width_mm / width - 1e-9))
            low, high = -k, k
        elif self.points:
            low = math.floor(float(d.min()) / width + 1e-9)
            high = max(math.ceil(float(d.max()) / width - 1e-9), low + 1)
        else:
            low, high = -1, 1
        edges = np.arange(low, high + 1, dtype=np.float64) * width
        counts, _ = np.histogram(d, bins=edges)
        return edges, counts.astype(np.int64)

    def summary_lines(self, bar_width: int = 40) -> list[str]:
        """A short text report (points, share within the tolerance, RMS, p95, max, shift and
        the histogram as rows), one string per line, for a CLI to print."""
        tol, width = self.tolerance_mm, self.bin_mm
        pairs = ", ".join(f"A{a}-B{b}" for a, b in self.wire_pairs)
        lines = [
            f"points compared      {self.points} ({len(self.wire_pairs)} wire pairs: {pairs})",
            f"chainage shift       {self.shift_m:+.3f} m (B minus A); "
            f"stagger RMS {self.stagger_rms_mm:.2f} mm",
            f"within ±{tol:.2f} mm      {100.0 * self.share_within():.1f} %",
            f"difference B - A     mean {self.mean_mm:+.3f} mm, RMS {self.rms_mm:.3f} mm, "
            f"p95 {self.p95_mm:.3f} mm, max {self.max_abs_mm:.3f} mm",
        ]
        if not self.points:
            return lines
        # the central part in bins of bin_mm (at most 20 a side), the rest in two overflow rows
        half = min(max(2.0 * tol, self.p95_mm), 20.0 * width)
        edges, counts = self.histogram(width, half)
        d = np.asarray(self.difference_mm, dtype=np.float64)
        below = int(np.count_nonzero(d < edges[0]))
        above = int(np.count_nonzero(d > edges[-1]))
        peak = max(int(counts.max()), below, above, 1)
        decimals = max(2, math.ceil(-math.log10(width) - 1e-9))

        def row(label: str, count: int) -> str:
            bar = "#" * round(bar_width * count / peak)
            share = 100.0 * count / self.points
            return f"  {label:>17} {count:>9} {share:5.1f} % {bar}".rstrip()

        lines.append(f"histogram of B - A [mm], bins of {width:g} mm")
        lines.append(row(f"< {edges[0]:+.{decimals}f}", below))
        for lo, hi, count in zip(edges[:-1], edges[1:], counts, strict=True):
            lines.append(row(f"{lo:+.{decimals}f} .. {hi:+.{decimals}f}", int(count)))
        lines.append(row(f"> {edges[-1]:+.{decimals}f}", above))
        return lines


# -- one wire of one run ---------------------------------------------------------------------


@dataclass(frozen=True)
class _Wire:
    """One wire's samples sorted by chainage: stagger and thickness where finite."""

    start_m: float
    end_m: float
    stagger_at_m: FloatArray
    stagger_mm: FloatArray
    thickness_at_m: FloatArray
    thickness_mm: FloatArray


def _wires(run: RunProfile) -> dict[int, _Wire]:
    c, s, t = run.chainage_m, run.stagger_mm, run.residual_thickness_mm
    usable = np.isfinite(c) & (np.isfinite(s) | np.isfinite(t))
    out: dict[int, _Wire] = {}
    for number in np.unique(run.wire[usable]):  # one loop step per wire, not per sample
        rows = np.flatnonzero(usable & (run.wire == number))
        rows = rows[np.argsort(c[rows], kind="stable")]
        has_s = rows[np.isfinite(s[rows])]
        has_t = rows[np.isfinite(t[rows])]
        out[int(number)] = _Wire(
            start_m=float(c[rows[0]]),
            end_m=float(c[rows[-1]]),
            stagger_at_m=c[has_s],
            stagger_mm=s[has_s],
            thickness_at_m=c[has_t],
            thickness_mm=t[has_t],
        )
    return out


def _interpolate(xp: FloatArray, fp: FloatArray, x: FloatArray, max_gap_m: float) -> FloatArray:
    """``fp`` (at sorted ``xp``, shape (k,)) linearly at ``x`` (shape (n,)); NaN outside
    ``[xp[0], xp[-1]]`` and where the two samples around ``x`` are more than ``max_gap_m``
    apart."""
    if xp.shape[0] < 2:
        return np.full(x.shape, np.nan)
    j = np.clip(np.searchsorted(xp, x, side="right"), 1, xp.shape[0] - 1)
    left, right = xp[j - 1], xp[j]
    gap = right - left
    with np.errstate(divide="ignore", invalid="ignore"):
        fraction = np.where(gap > 0.0, (x - left) / gap, 0.0)
    value = fp[j - 1] + fraction * (fp[j] - fp[j - 1])
    inside = (x >= xp[0]) & (x <= xp[-1]) & (gap <= max_gap_m)
    return np.where(inside, value, np.nan)


def _common(a: _Wire, b: _Wire, shift_m: float) -> tuple[float, float]:
    """Common chainage of two wires, in A's chainage, with B read at ``+ shift_m``."""
    return max(a.start_m, b.start_m - shift_m), min(a.end_m, b.end_m - shift_m)


def _thin(count: int, most: int) -> IndexArray:
    """At most ``most`` indices spread evenly over ``range(count)``."""
    if count <= most:
        return np.arange(count, dtype=np.intp)
    return np.unique(np.linspace(0, count - 1, most).round().astype(np.intp))


# -- the comparison --------------------------------------------------------------------------


def _match_wires(
    wires_a: dict[int, _Wire], wires_b: dict[int, _Wire]
) -> tuple[tuple[tuple[int, int], ...], bool]:
    """Pairs ``(wire of A, wire of B)`` by median stagger difference, and whether any two
    wires had a common section at all."""
    candidates: list[tuple[float, float, int, int]] = []
    any_common = False
    for na, a in wires_a.items():
        for nb, b in wires_b.items():
            low, high = _common(a, b, 0.0)
            if high - low < MIN_COMMON_M:
                continue
            any_common = True
            inside = np.flatnonzero((a.stagger_at_m >= low) & (a.stagger_at_m <= high))
            inside = inside[_thin(inside.shape[0], _MATCH_POINTS)]
            b_mm = _interpolate(b.stagger_at_m, b.stagger_mm, a.stagger_at_m[inside], 1.0)
            d = np.abs(b_mm - a.stagger_mm[inside])
            d = d[np.isfinite(d)]
            if d.shape[0] >= _MIN_POINTS:
                candidates.append((float(np.median(d)), low - high, na, nb))
    pairs: list[tuple[int, int]] = []
    used_a: set[int] = set()
    used_b: set[int] = set()
    for median_mm, _, na, nb in sorted(candidates):  # best first, longer first on a tie
        if median_mm < MATCH_STAGGER_MM and na not in used_a and nb not in used_b:
            pairs.append((na, nb))
            used_a.add(na)
            used_b.add(nb)
    return tuple(pairs), any_common


def _stagger_points(
    pairs: tuple[tuple[int, int], ...], wires_a: dict[int, _Wire], wires_b: dict[int, _Wire]
) -> list[tuple[FloatArray, FloatArray, _Wire]]:
    """Per pair: A's stagger samples (chainage, stagger) and B's wire."""
    return [(wires_a[na].stagger_at_m, wires_a[na].stagger_mm, wires_b[nb]) for na, nb in pairs]


def _stagger_difference(
    points: list[tuple[FloatArray, FloatArray, _Wire]], shift_m: float
) -> FloatArray:
    """``stagger_B(c + shift) - stagger_A(c)`` at every point (NaN where B has none)."""
    parts = [
        _interpolate(b.stagger_at_m, b.stagger_mm, c + shift_m, MAX_GAP_M) - s for c, s, b in points
    ]
    return np.concatenate(parts) if parts else np.zeros(0)


def _subset(
    points: list[tuple[FloatArray, FloatArray, _Wire]], most: int
) -> list[tuple[FloatArray, FloatArray, _Wire]]:
    total = sum(c.shape[0] for c, _, _ in points)
    stride = max(1, math.ceil(total / most))
    return [(c[::stride], s[::stride], b) for c, s, b in points]


def _vertex(x: FloatArray, y: FloatArray, best: int) -> float:
    """Abscissa of the minimum of the parabola through the grid minimum and its neighbours
    (the grid point itself at an end of the grid or without curvature)."""
    if 0 < best < x.shape[0] - 1:
        y0, y1, y2 = y[best - 1], y[best], y[best + 1]
        curvature = y0 - 2.0 * y1 + y2
        if curvature > 0.0:
            step = x[best + 1] - x[best]
            offset = 0.5 * (y0 - y2) / curvature  # within ±0.5 step of the minimum
            return float(x[best] + offset * step)
    return float(x[best])


def _refine_shift(
    points: list[tuple[FloatArray, FloatArray, _Wire]], max_shift_m: float
) -> tuple[float, float]:
    """The shift minimising the mean squared stagger difference, and the RMS there [mm]."""
    if max_shift_m == 0.0:
        d = _stagger_difference(points, 0.0)
        d = d[np.isfinite(d)]
        return 0.0, float(np.sqrt(np.mean(d * d))) if d.shape[0] else math.nan
    # coarse: every COARSE_STEP_M over ±max_shift_m, on a subset of the points
    count = max(1, math.ceil(max_shift_m / COARSE_STEP_M))
    coarse = np.linspace(-max_shift_m, max_shift_m, 2 * count + 1)
    subset = _subset(points, _COARSE_POINTS)
    cost = np.full(coarse.shape, np.inf)
    for i, shift in enumerate(coarse):  # one step per candidate shift
        d = _stagger_difference(subset, float(shift))
        d = d[np.isfinite(d)]
        if d.shape[0] >= _MIN_POINTS:
            cost[i] = float(np.mean(d * d))
    if not np.isfinite(cost).any():
        return 0.0, math.nan
    centre = float(coarse[int(np.argmin(cost))])
    # fine: FINE_STEP_M over ± one coarse step, on a fixed set of points (B has values at both
    # ends of the fine grid, so at every shift between: the grid is narrower than MAX_GAP_M)
    # without the coarse fit's outliers
    step = coarse[1] - coarse[0]
    fine_count = max(1, math.ceil(step / FINE_STEP_M))
    fine = centre + np.linspace(-step, step, 2 * fine_count + 1)
    fine = fine[np.abs(fine) <= max_shift_m + 1e-12]
    subset = _subset(points, _FINE_POINTS)
    low = _stagger_difference(subset, float(fine[0]))
    high = _stagger_difference(subset, float(fine[-1]))
    at_centre = _stagger_difference(subset, centre)
    keep = np.isfinite(low) & np.isfinite(high) & np.isfinite(at_centre)
    if np.count_nonzero(keep) < _MIN_POINTS:
        return centre, float(np.sqrt(cost.min()))
    residual = at_centre[keep]
    spread = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    limit = max(_OUTLIER_SIGMAS * spread, _OUTLIER_FLOOR_MM)
    keep[keep] = np.abs(residual - np.median(residual)) <= limit
    fine_cost = np.empty(fine.shape)
    for i, shift in enumerate(fine):
        d = _stagger_difference(subset, float(shift))[keep]
        fine_cost[i] = float(np.mean(d * d))
    best = int(np.argmin(fine_cost))
    shift_m = float(np.clip(_vertex(fine, fine_cost, best), -max_shift_m, max_shift_m))
    d = _stagger_difference(subset, shift_m)[keep]
    return shift_m, float(np.sqrt(np.mean(d * d)))


def compare_profiles(
    a: RunProfile,
    b: RunProfile,
    *,
    max_shift_m: float = 1.0,
    tolerance_mm: float = 0.1,
    bin_mm: float = 0.02,
) -> Comparison:
    """Residual thickness of run B minus run A over their common section (module docstring).

    Parameters
    ----------
    a, b : RunProfile
        The two runs' samples, ``(m_a,)`` and ``(m_b,)``; chainages aligned, staggers in the
        line frame.
    max_shift_m : float, default 1.0
        Largest residual chainage offset between the runs searched for [m]; 0: none.
    tolerance_mm : float, default 0.1
        Tolerance of :meth:`Comparison.share_within` (the paper: 0.1 mm).
    bin_mm : float, default 0.02
        Bin width of :meth:`Comparison.histogram` [mm].

    Returns
    -------
    Comparison
        ``n`` points of A on the paired wires where both runs have a residual thickness.

    Raises
    ------
    UserError
        The runs have no section of line in common, no wire of A runs along a wire of B, or
        the paired wires have no residual thickness in common.
    """
    if not (math.isfinite(max_shift_m) and max_shift_m >= 0.0):
        raise ValueError(f"max_shift_m = {max_shift_m} must be a non-negative length")
    if not (math.isfinite(tolerance_mm) and tolerance_mm > 0.0):
        raise ValueError(f"tolerance_mm = {tolerance_mm} must be positive")
    if not (math.isfinite(bin_mm) and bin_mm > 0.0):
        raise ValueError(f"bin_mm = {bin_mm} must be positive")
    wires_a, wires_b = _wires(a), _wires(b)
    pairs, any_common = _match_wires(wires_a, wires_b)
    if not any_common:

        def extent(wires: dict[int, _Wire]) -> str:
            if not wires:
                return "no samples"
            low = min(w.start_m for w in wires.values())
            high = max(w.end_m for w in wires.values())
            return f"{low:.1f}-{high:.1f} m"

        raise UserError(
            f"the runs have no section of line in common "
            f"(chainage {extent(wires_a)} and {extent(wires_b)})"
        )
    if not pairs:
        raise UserError(
            "no contact wire of one run runs along a wire of the other "
            f"(median stagger difference {MATCH_STAGGER_MM:g} mm or more everywhere)"
        )
    shift_m, stagger_rms_mm = _refine_shift(_stagger_points(pairs, wires_a, wires_b), max_shift_m)
    chainage, wire, thickness, difference = [], [], [], []
    for na, nb in pairs:
        wa, wb = wires_a[na], wires_b[nb]
        low, high = _common(wa, wb, shift_m)
        inside = (wa.thickness_at_m >= low) & (wa.thickness_at_m <= high)
        c = wa.thickness_at_m[inside]
        t = wa.thickness_mm[inside]
        d = _interpolate(wb.thickness_at_m, wb.thickness_mm, c + shift_m, MAX_GAP_M) - t
        finite = np.isfinite(d)
        chainage.append(c[finite])
        wire.append(np.full(np.count_nonzero(finite), na, dtype=np.int64))
        thickness.append(t[finite])
        difference.append(d[finite])
    comparison = Comparison(
        wire_pairs=pairs,
        shift_m=shift_m,
        stagger_rms_mm=stagger_rms_mm,
        chainage_m=np.concatenate(chainage),
        wire=np.concatenate(wire),
        residual_thickness_mm=np.concatenate(thickness),
        difference_mm=np.concatenate(difference),
        tolerance_mm=tolerance_mm,
        bin_mm=bin_mm,
    )
    if comparison.points == 0:
        raise UserError("the paired wires of the runs have no residual thickness in common")
    return comparison
