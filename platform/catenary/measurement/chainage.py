"""Chainage of an inspection run: registration points in the stagger, matched to the masts.

A run's scans carry the wheel encoder's distance ``position_m`` since the first scan. The
encoder has a scale error of a few tenths of a percent (wheel wear, slip) and the header's
start chainage is only as good as the marker it was read from, so ``start + sign · position``
drifts by tens of metres over tens of kilometres, more than half a 40-65 m span. The line
itself marks the masts: at each one a steady arm registers the contact wire, and the wire's
stagger (its lateral position, a zigzag on straight track, chords of the curved track in
curves) has a kink there. :class:`TurningPointFinder` finds those kinks in the measured
stagger, :func:`align_to_register` matches them to the mast register's chainages and fits

    chainage = offset + sign · scale · position

**Finding registration points.** Per wire, the samples are binned along the track in
``BIN_M`` bins of moments (count, powers of the position up to the fourth, stagger and its
products: a least-squares line or quadratic over any run of bins comes from sums of them,
and the memory per wire is a fixed window of bins, never the run). At every bin edge two
lines are fitted over ``DETECTION_WINDOW_M`` on either side; their slope difference ``Δ``
peaks at a kink with the kink's slope change. On a curve's arc ``Δ`` has a steady part (the
arc's curvature times the window), so what is tested is the *excess* of ``Δ`` over a
baseline: the smaller in magnitude of ``Δ`` ``BASELINE_OFFSET_M`` before and after (clear of
the kink's own windows; a missing one counts as 0, and a kink 6 m away is never the baseline
of an edge: no echoes). A bin edge is a registration point where the excess

- is at least ``MIN_SLOPE_CHANGE_MM_PER_M`` (8 mm/m: a real zigzag slopes 8-20 mm/m on each
  side, so its kinks change slope by 16-40 mm/m, and by more in curves, where every
  registration pulls the wire outward; the excess of a smooth arc is nil, and body sway left
  over after vehicle compensation is a few mm over metres, well below),
- is ``SIGNIFICANCE`` (10) times its standard error from the lines' residuals (a 4 m window
  of 1 mm noise at 15 mm spacing gives 0.05 mm/m, so only a kink-sized change passes, however
  noisy the processor is within reason),
- is the largest within ``BASELINE_OFFSET_M + DETECTION_WINDOW_M`` (10 m) either side (one
  point per kink; registrations are 30 m apart at least), and
- has both windows holding ``MIN_WINDOW_SAMPLES`` samples spread over half the window at
  least (the ends of a wire's view and gaps give no kink).

The point is then refined where the quadratics (lines, or arcs in curves) fitted over
``FIT_WINDOW_M`` on either side, ``FIT_GAP_M`` away from it (the fittings at the registration
do not enter the fits), cross; twice, the second time about the first crossing. A point the
quadratics do not confirm (samples over less than half of either window, a slope change at
the crossing below half ``MIN_SLOPE_CHANGE_MM_PER_M``, no crossing within 2 m) is dropped.
About 1 cm RMS at 1 mm of noise, on straights and arcs alike (lines fitted to arcs would be
biased by decimetres where the curvature changes, at a curve's first registration). Points
of different wires (an overlap's two wires registered at one mast) within ``MERGE_M`` are one
registration, at their mean. A wire's edges are decided once the samples ``_MARGIN`` bins
beyond them are in, so the result does not depend on how the rows are split into pushes.

**Alignment.** (:func:`align_to_register`) The offset near the start is voted for: every
mast within ``max_start_error_m`` (plus the scale error's drift) of the header's prediction
of one of the first turning points proposes a shift, and the shift that puts most of the
first turning points within the tolerance of a mast wins. From there the turning points are
taken in order: each is predicted by the model fitted so far (offset only, scale 1, until
the matched points span ``MIN_SCALE_EXTENT_M``; then offset and scale), matched to the
nearest mast within ``tolerance_m`` plus the model's possible drift since the matched points
(never more than a third of the register's median span), and the model is refitted. The
final model is the least-squares fit of offset and scale on the matched pairs after rejecting
outliers (beyond ``REJECT_FLOOR_M`` and 4 robust standard deviations), the scale with a prior
(``SCALE_PRIOR``: over a short run a few points move it only as far as they can tell), with
every turning point matched again to it, one turning point per mast. Missing registrations
(anchor masts, missed kinks) leave masts unmatched; spurious kinks match no mast; neither
moves the fit.

A constant scale is what the encoder's error is (wheel diameter); a drift that changes along
a run (slip on a gradient, a wheel turned mid-way) shows as residuals that grow with the
run, in ``residual_rms_m`` and ``max_residual_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

from catenary.arrays import BoolArray, FloatArray, IndexArray

__all__ = [
    "BASELINE_OFFSET_M",
    "BIN_M",
    "DETECTION_WINDOW_M",
    "FIT_GAP_M",
    "FIT_WINDOW_M",
    "MATCH_TOLERANCE_M",
    "MAX_SCALE_ERROR",
    "MAX_START_ERROR_M",
    "MERGE_M",
    "MIN_MATCHED",
    "MIN_MATCHED_FRACTION",
    "MIN_SLOPE_CHANGE_MM_PER_M",
    "MIN_WINDOW_SAMPLES",
    "SIGNIFICANCE",
    "ChainageAlignment",
    "TurningPointFinder",
    "align_to_register",
    "direction_sign",
    "span_index",
]

BIN_M = 0.25
"""Length of track of one bin of moments [m]: where fit windows may begin and end (the
refined position is not limited to it)."""

DETECTION_WINDOW_M = 4.0
"""Length of each of the two lines whose slope difference detects a kink [m]: the slope's
noise is ``σ sqrt(12 / n) / W`` (0.05 mm/m at 1 mm, 15 mm spacing), and the window is short
against the 30-65 m between registrations."""

BASELINE_OFFSET_M = 6.0
"""Distance of the two slope differences the smaller of which is the curve's baseline [m]:
their windows (out to 10 m) stay clear of the kink's own (4 m either side)."""

FIT_WINDOW_M = 8.0
"""Length of the quadratics crossed to refine a registration point [m]: 1 cm RMS at 1 mm of
noise, 3 cm at 3 mm; 8.5 m either side of a registration stays within its spans (30 m at
least)."""

FIT_GAP_M = 0.5
"""Gap between the refined point and its two fitted quadratics [m]: the steady arm and the
clamps at the registration may disturb the wire's detection over a few centimetres."""

MIN_SLOPE_CHANGE_MM_PER_M = 8.0
"""Smallest slope change of a registration point (module docstring) [mm/m]."""

SIGNIFICANCE = 10.0
"""Smallest slope change of a registration point in standard errors of its estimate."""

MIN_WINDOW_SAMPLES = 20
"""Fewest samples of a fitted line (a 4 m window holds 90 at 160 km/h and 1000 scans/s)."""

MERGE_M = 2.0
"""Registration points of different wires this close are one registration [m]."""

IDLE_RELEASE_M = 200.0
"""A wire with no rows while others advanced this far is decided and its bins released [m];
rows that continue it later start it afresh (as after a gap)."""

MATCH_TOLERANCE_M = 2.0
"""Default distance within which a turning point's predicted chainage matches a mast [m]:
the turning point's precision (decimetres), the register's survey (decimetres) and the scale
error's drift over a span (0.6 % of 65 m: 0.4 m), well below half the shortest span."""

MAX_START_ERROR_M = 12.0
"""Default largest error of the header's start chainage searched for [m]."""

MAX_SCALE_ERROR = 0.01
"""Default largest relative scale error of the encoder accepted (the field's: ±0.6 %)."""

MIN_SCALE_EXTENT_M = 200.0
"""Matched turning points must span this much of the run before the matching follows a
scale [m]; the final fit always fits one (with ``SCALE_PRIOR``)."""

SCALE_PRIOR = 0.003
"""The encoder's scale error expected [-] (a few tenths of a percent: wheel wear, slip)."""

POINT_SIGMA_M = 0.1
"""Uncertainty of a matched pair's chainage [m]: the register's survey of a mast (decimetres)
and the turning point's own (centimetres)."""

REJECT_FLOOR_M = 0.5
"""Matched pairs are outliers beyond this residual [m] and 4 robust standard deviations."""

MIN_MATCHED = 3
"""Fewest matched turning points of an alignment."""

MIN_MATCHED_FRACTION = 0.5
"""Smallest fraction of the turning points found that must match a mast."""

INIT_LENGTH_M = 500.0
"""The offset is voted for by the turning points within this of the first one [m] (at least
``_INIT_POINTS`` of them)."""

_INIT_POINTS = 6

_W = round(DETECTION_WINDOW_M / BIN_M)
_B = round(BASELINE_OFFSET_M / BIN_M)
_NMS = _B + _W
_FIT = round(FIT_WINDOW_M / BIN_M)
_GAP = round(FIT_GAP_M / BIN_M)
_SHIFT = 8  # bins a refined point may move from its detected edge
_MARGIN = max(_NMS + _B + _W, _SHIFT + _GAP + _FIT + 1)
"""Bins either side of an edge its decision depends on."""
_CAPACITY = 6 * _MARGIN
"""Bins a wire keeps."""
_DECIDE_EVERY = _CAPACITY // 4
_MOMENTS = 9  # n, Σu, Σu², Σu³, Σu⁴, Σs, Σus, Σu²s, Σs² (u: position from the bin's centre)


def direction_sign(direction: str) -> int:
    """``+1`` for ``"increasing"``, ``-1`` for ``"decreasing"`` chainage; ValueError else."""
    if direction == "increasing":
        return 1
    if direction == "decreasing":
        return -1
    raise ValueError(f"direction must be 'increasing' or 'decreasing', got {direction!r}")


# -- registration points ------------------------------------------------------------------


@dataclass(frozen=True)
class _Lines:
    """Least-squares lines over windows of bins, one per window, each ``(e,)``."""

    usable: BoolArray
    slope: FloatArray  # mm/m
    value: FloatArray  # mm, at the evaluation point
    var_slope: FloatArray


def _prefix_sums(moments: FloatArray) -> FloatArray:
    """Prefix sums ``(6, C + 1)`` of ``n, Σx, Σx², Σs, Σxs, Σs²`` of bins ``(9, C)``, with
    ``x`` the position from the buffer's first edge [m]."""
    n, u1, u2, _, _, s1, us, _, s2 = moments
    centre = (np.arange(moments.shape[1]) + 0.5) * BIN_M
    per_bin = np.stack(
        [
            n,
            n * centre + u1,
            n * centre * centre + 2.0 * centre * u1 + u2,
            s1,
            centre * s1 + us,
            s2,
        ]
    )
    out = np.zeros((6, moments.shape[1] + 1))
    np.cumsum(per_bin, axis=1, out=out[:, 1:])
    return out


def _fit_lines(
    prefix: FloatArray, first: IndexArray, stop: IndexArray, at_m: FloatArray, fill: float
) -> _Lines:
    """Lines over bins ``[first, stop)`` (clipped to the buffer), evaluated at ``at_m``.

    ``first``, ``stop``, ``at_m`` have one shape ``(e,)``; positions from the buffer's first
    edge [m]. Usable where the window holds ``MIN_WINDOW_SAMPLES`` samples spread as widely
    as a uniform spread over the fraction ``fill`` of its nominal length at least.
    """
    size = prefix.shape[1] - 1
    length_m = (stop - first) * BIN_M
    a = np.clip(first, 0, size)
    b = np.clip(stop, 0, size)
    n, sx, sxx, ss, sxs, sss = prefix[:, b] - prefix[:, a]
    with np.errstate(divide="ignore", invalid="ignore"):
        mean_x = sx / n
        mean_s = ss / n
        spread_xx = sxx - sx * mean_x
        spread_xs = sxs - sx * mean_s
        spread_ss = sss - ss * mean_s
        slope = spread_xs / spread_xx
        variance = np.maximum(spread_ss - slope * spread_xs, 0.0) / (n - 2.0)
        var_slope = variance / spread_xx
        value = mean_s + slope * (at_m - mean_x)
    usable = (n >= MIN_WINDOW_SAMPLES) & (spread_xx > n * (fill * length_m) ** 2 / 12.0)
    usable &= np.isfinite(slope) & np.isfinite(var_slope)
    return _Lines(usable, slope, value, var_slope)


def _kink_edges(prefix: FloatArray, lo: int, hi: int) -> IndexArray:
    """Edges in ``[lo, hi)`` of the buffer that are registration points (module docstring).

    Decisions use bins within ``_MARGIN`` of the edge only.
    """
    edges = np.arange(prefix.shape[1])
    at = np.asarray(edges * BIN_M, dtype=np.float64)
    left = _fit_lines(prefix, edges - _W, edges, at, 0.5)
    right = _fit_lines(prefix, edges, edges + _W, at, 0.5)
    usable = left.usable & right.usable
    delta = np.where(usable, right.slope - left.slope, np.nan)
    var_delta = left.var_slope + right.var_slope
    pad = np.full(_B, np.nan)
    before = np.concatenate([pad, delta[:-_B]])
    after = np.concatenate([delta[_B:], pad])
    # the smaller of the two (a missing one counts as 0): a kink 6 m away is no baseline
    before = np.nan_to_num(before)
    after = np.nan_to_num(after)
    baseline = np.where(np.abs(before) <= np.abs(after), before, after)
    strength = np.where(usable, np.abs(delta - baseline), 0.0)
    peak = strength >= ndimage.maximum_filter1d(strength, 2 * _NMS + 1, mode="constant")
    with np.errstate(invalid="ignore"):
        kink = usable & peak & (strength >= MIN_SLOPE_CHANGE_MM_PER_M)
        kink &= strength >= SIGNIFICANCE * np.sqrt(var_delta)
    found = np.flatnonzero(kink[lo:hi]) + lo
    if found.shape[0] > 1:  # equal maxima within one neighbourhood: the first
        found = found[np.concatenate([[True], np.diff(found) > _NMS])]
    return found.astype(np.intp)


def _quadratic(moments: FloatArray, first: int, stop: int, at_m: float) -> FloatArray | None:
    """Least-squares ``s = c0 + c1 t + c2 t²`` [mm, mm/m, mm/m²] over bins ``[first, stop)``,
    ``t`` [m] from ``at_m`` (from the buffer's first edge); None unless the samples number
    ``MIN_WINDOW_SAMPLES`` and spread over half the window."""
    k = np.arange(max(first, 0), min(stop, moments.shape[1]))
    n, u1, u2, u3, u4, s1, us, uus, _ = moments[:, k]
    d = (k + 0.5) * BIN_M - at_m
    count = float(n.sum())
    t1 = float(np.sum(n * d + u1))
    t2 = float(np.sum(n * d**2 + 2.0 * d * u1 + u2))
    t3 = float(np.sum(n * d**3 + 3.0 * d**2 * u1 + 3.0 * d * u2 + u3))
    t4 = float(np.sum(n * d**4 + 4.0 * d**3 * u1 + 6.0 * d**2 * u2 + 4.0 * d * u3 + u4))
    length_m = (stop - first) * BIN_M
    if count < MIN_WINDOW_SAMPLES or t2 - t1 * t1 / count <= count * (0.5 * length_m) ** 2 / 12:
        return None
    normal = np.array([[count, t1, t2], [t1, t2, t3], [t2, t3, t4]])
    rhs = np.array(
        [float(s1.sum()), float(np.sum(d * s1 + us)), float(np.sum(d**2 * s1 + 2.0 * d * us + uus))]
    )
    try:
        return np.asarray(np.linalg.solve(normal, rhs), dtype=np.float64)
    except np.linalg.LinAlgError:
        return None


def _crossing(left: FloatArray, right: FloatArray) -> float:
    """The root nearest 0 of ``left(t) - right(t)`` (quadratics' coefficients), or NaN."""
    a, b, c = left - right
    disc = max(b * b - 4.0 * a * c, 0.0)
    q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
    return a / q if q != 0.0 else math.nan


def _refine(moments: FloatArray, edges: IndexArray) -> FloatArray:
    """Where the quadratics fitted on either side of each edge cross, from the buffer's first
    edge [m]; NaN where they give no crossing near the edge (no kink there)."""
    result = np.full(edges.shape[0], np.nan)
    for i, edge in enumerate(edges.tolist()):  # one step per turning point
        centre = edge
        for _ in range(2):
            at = centre * BIN_M
            left = _quadratic(moments, centre - _GAP - _FIT, centre - _GAP, at)
            right = _quadratic(moments, centre + _GAP, centre + _GAP + _FIT, at)
            if left is None or right is None:
                break
            if abs(right[1] - left[1]) < 0.5 * MIN_SLOPE_CHANGE_MM_PER_M:
                break
            cross = at + _crossing(left, right)
            if not abs(cross - edge * BIN_M) <= _SHIFT * BIN_M:
                break
            result[i] = cross
            centre = round(cross / BIN_M)
    return result


class _Wire:
    """One wire's window of bins and how far its edges are decided (global bin indices)."""

    def __init__(self) -> None:
        self.moments: FloatArray | None = None
        self.origin = 0  # global index of the buffer's first bin
        self.done = 0  # edges below are decided
        self.last = -1  # bin of the last sample
        self.last_position_m = -math.inf
        self.started = False


class TurningPointFinder:
    """Streaming detection of registration points (kinks) in contact wires' stagger.

    Push rows of ``(wire, position, stagger)`` as the processor releases them, then call
    :meth:`finish`. The method and its thresholds: module docstring. Memory per wire is a
    fixed window of ``BIN_M`` bins (about 100 m); the output, one float per registration,
    is all that grows with the run.
    """

    def __init__(self) -> None:
        self._wires: dict[int, _Wire] = {}
        self._kinks: list[float] = []
        self._furthest = -(2**62)
        self._result: FloatArray | None = None

    def push(self, wire: ArrayLike, position_m: ArrayLike, stagger_mm: ArrayLike) -> None:
        """Add rows of any wires.

        Parameters
        ----------
        wire : array_like of int, shape (m,)
            Wire number of each row.
        position_m : array_like, shape (m,)
            Encoder position of each row [m]; per wire, not below that wire's earlier rows.
        stagger_mm : array_like, shape (m,)
            Stagger in the track frame [mm]; rows with NaN are ignored.
        """
        if self._result is not None:
            raise RuntimeError("TurningPointFinder.push after finish")
        wires = np.asarray(wire)
        position = np.asarray(position_m, dtype=np.float64)
        stagger = np.asarray(stagger_mm, dtype=np.float64)
        if not (wires.shape == position.shape == stagger.shape) or wires.ndim != 1:
            raise ValueError("wire, position_m and stagger_mm must share one (m,) shape")
        keep = np.isfinite(position) & np.isfinite(stagger)
        wires, position, stagger = wires[keep], position[keep], stagger[keep]
        if position.shape[0] == 0:
            return
        if not np.issubdtype(wires.dtype, np.integer):
            raise ValueError(f"wire numbers must be integers, got dtype {wires.dtype}")
        for number in np.unique(wires):  # one step per wire
            rows = np.flatnonzero(wires == number)
            order = np.argsort(position[rows], kind="stable")
            state = self._wires.setdefault(int(number), _Wire())
            p = position[rows][order]
            if p[0] < state.last_position_m:
                raise ValueError(
                    f"wire {int(number)}: position {p[0]} m after rows up to "
                    f"{state.last_position_m} m (positions must not decrease)"
                )
            self._add(state, p, stagger[rows][order])
            self._furthest = max(self._furthest, state.last)
        idle = self._furthest - round(IDLE_RELEASE_M / BIN_M)
        for state in self._wires.values():
            if state.moments is not None and state.last < idle:
                self._close(state)

    def finish(self) -> FloatArray:
        """Decide every wire's remaining edges and return the registration points.

        Returns
        -------
        ndarray, shape (k,)
            Encoder positions of the registration points [m], ascending; points of different
            wires within ``MERGE_M`` merged into their mean.
        """
        if self._result is None:
            for state in self._wires.values():
                self._close(state)
            points = np.sort(np.array(self._kinks, dtype=np.float64))
            if points.shape[0]:
                start = np.concatenate([[True], np.diff(points) > MERGE_M])
                first = np.flatnonzero(start)
                sums = np.add.reduceat(points, first)
                counts = np.diff(np.append(first, points.shape[0]))
                points = sums / counts
            self._result = np.asarray(points, dtype=np.float64)
        return self._result.copy()

    # -- one wire --------------------------------------------------------------------------

    def _add(self, state: _Wire, position: FloatArray, stagger: FloatArray) -> None:
        index = np.floor(position / BIN_M).astype(np.int64)
        i = 0
        total = index.shape[0]
        while i < total:
            g = int(index[i])
            if state.moments is not None and g > state.last + 2 * _MARGIN + 1:
                self._close(state)  # a gap: nothing between decides anything
            if state.moments is None:
                state.done = g - _MARGIN if not state.started else max(state.done, g - _MARGIN)
                # rows continuing a released wire may fall in its last bins again
                state.origin = min(state.done - _MARGIN, g)
                state.moments = np.zeros((_MOMENTS, _CAPACITY))
                state.started = True
            if g >= state.origin + _CAPACITY:
                self._decide(state, g - _MARGIN)  # bins before g are complete
                continue
            stop = i + int(np.searchsorted(index[i:], state.origin + _CAPACITY, side="left"))
            local = index[i:stop] - state.origin
            p = position[i:stop]
            s = stagger[i:stop]
            u = p - (index[i:stop] + 0.5) * BIN_M
            u2 = u * u
            for row, weights in enumerate((None, u, u2, u2 * u, u2 * u2, s, u * s, u2 * s, s * s)):
                state.moments[row] += np.bincount(local, weights=weights, minlength=_CAPACITY)
            state.last = int(index[stop - 1])
            state.last_position_m = float(p[-1])
            i = stop
        if state.last - _MARGIN - state.done >= _DECIDE_EVERY:
            self._decide(state, state.last - _MARGIN)

    def _decide(self, state: _Wire, limit: int) -> None:
        """Decide edges ``[done, limit)`` (bins below ``limit + _MARGIN`` complete), as far as
        the window holds, and drop the bins no longer needed."""
        assert state.moments is not None
        limit = min(limit, state.origin + _CAPACITY - _MARGIN)
        if limit <= state.done:
            return
        prefix = _prefix_sums(state.moments)
        edges = _kink_edges(prefix, state.done - state.origin, limit - state.origin)
        if edges.shape[0]:
            refined = _refine(state.moments, edges)
            refined = refined[np.isfinite(refined)]
            self._kinks.extend((refined + state.origin * BIN_M).tolist())
        shift = limit - _MARGIN - state.origin
        moments = state.moments
        if shift >= _CAPACITY:
            moments[:] = 0.0
        elif shift > 0:
            moments[:, :-shift] = moments[:, shift:]
            moments[:, -shift:] = 0.0
        state.origin += shift
        state.done = limit

    def _close(self, state: _Wire) -> None:
        """Decide every edge a wire's samples reach and release its bins."""
        if state.moments is None:
            return
        while state.done < state.last + _MARGIN + 1:
            self._decide(state, state.last + _MARGIN + 1)
        state.moments = None


# -- alignment -----------------------------------------------------------------------------


@dataclass(frozen=True)
class ChainageAlignment:
    """A run's encoder positions aligned to the register: ``offset + sign · scale · p``.

    ``matched`` turning points of the ``turning_points`` found matched a mast, with the
    residuals (mast minus fitted chainage) ``residual_rms_m`` and ``max_residual_m`` (NaN when
    none). ``aligned`` is False (and ``reason`` says why) when the header's start and scale 1
    had to be kept.
    """

    offset_m: float
    scale: float
    direction_sign: int
    matched: int
    turning_points: int
    residual_rms_m: float
    max_residual_m: float
    aligned: bool
    reason: str = ""

    @classmethod
    def unaligned(
        cls,
        start_chainage_m: float,
        direction: str,
        reason: str,
        *,
        turning_points: int = 0,
        matched: int = 0,
    ) -> ChainageAlignment:
        """The header's model ``start + sign · position`` (ValueError for a bad direction)."""
        return cls(
            offset_m=float(start_chainage_m),
            scale=1.0,
            direction_sign=direction_sign(direction),
            matched=matched,
            turning_points=turning_points,
            residual_rms_m=math.nan,
            max_residual_m=math.nan,
            aligned=False,
            reason=reason,
        )

    def chainage_m(self, position_m: ArrayLike) -> FloatArray:
        """Chainage [m] of encoder positions [m], any shape."""
        p = np.asarray(position_m, dtype=np.float64)
        return np.asarray(self.offset_m + self.direction_sign * self.scale * p, dtype=np.float64)


def _nearest(sorted_values: FloatArray, x: FloatArray) -> IndexArray:
    """Index of the nearest of ``sorted_values`` (non-empty) to each ``x``."""
    upper = np.clip(np.searchsorted(sorted_values, x), 1, max(sorted_values.shape[0] - 1, 1))
    lower = upper - 1
    if sorted_values.shape[0] == 1:
        return np.zeros(np.shape(x), dtype=np.intp)
    pick = np.abs(sorted_values[upper] - x) < np.abs(x - sorted_values[lower])
    return np.where(pick, upper, lower).astype(np.intp)


def _fit(
    q: FloatArray, chainage: FloatArray, max_scale_error: float, with_scale: bool
) -> tuple[float, float]:
    """``(offset, scale)`` of ``chainage = offset + scale · q`` by least squares, the scale
    limited to ``1 ± max_scale_error`` (1 without ``with_scale``).

    The scale has a prior: 1 within ``SCALE_PRIOR`` for points known to ``POINT_SIGMA_M``,
    so that a few points over a short run pull it only as far as they can tell.
    """
    scale = 1.0
    if with_scale and q.shape[0] >= 2:
        dq = q - q.mean()
        information = float(dq @ dq) / POINT_SIGMA_M**2
        prior = 1.0 / SCALE_PRIOR**2
        data = float(dq @ (chainage - chainage.mean())) / POINT_SIGMA_M**2
        scale = (data + prior) / (information + prior)
        scale = min(max(scale, 1.0 - max_scale_error), 1.0 + max_scale_error)
    return float(np.mean(chainage - scale * q)), scale


def _initial_shift(
    turning: FloatArray,
    masts: FloatArray,
    start: float,
    sign: int,
    tolerance_m: float,
    max_start_error_m: float,
    max_scale_error: float,
) -> tuple[float, int, int]:
    """The header error voted for by the first turning points: ``(shift, votes, voters)``."""
    count = max(int(np.searchsorted(turning, turning[0] + INIT_LENGTH_M, side="right")), 1)
    p = turning[: max(count, min(turning.shape[0], _INIT_POINTS))]
    travelled = p - p[0]
    predicted = start + sign * p
    reach = max_start_error_m + max_scale_error * p
    lo = np.searchsorted(masts, predicted - reach, side="left")
    hi = np.searchsorted(masts, predicted + reach, side="right")
    shifts = np.concatenate(
        [masts[a:b] - c for a, b, c in zip(lo, hi, predicted, strict=True)] + [np.zeros(0)]
    )
    if shifts.shape[0] == 0:
        return 0.0, 0, int(p.shape[0])
    shifted = predicted[None, :] + shifts[:, None]
    residual = masts[_nearest(masts, shifted)] - shifted
    tolerance = tolerance_m + max_scale_error * travelled
    hit = np.abs(residual) <= tolerance[None, :]
    votes = hit.sum(axis=1)
    cost = np.where(hit, np.abs(residual) / tolerance[None, :], 1.0).sum(axis=1)
    best = int(np.lexsort((cost, -votes))[0])
    return float(shifts[best]), int(votes[best]), int(p.shape[0])


def _robust_fit(
    q: FloatArray, chainage: FloatArray, max_scale_error: float
) -> tuple[float, float, BoolArray]:
    """Least squares with outliers (beyond ``REJECT_FLOOR_M`` and 4 robust σ) rejected."""
    keep = np.ones(q.shape[0], dtype=bool)
    offset, scale = 0.0, 1.0
    for _ in range(10):
        offset, scale = _fit(q[keep], chainage[keep], max_scale_error, with_scale=True)
        residual = chainage - (offset + scale * q)
        centre = np.median(residual[keep])
        sigma = 1.4826 * float(np.median(np.abs(residual[keep] - centre)))
        new = np.abs(residual) <= max(REJECT_FLOOR_M, 4.0 * sigma)
        if np.count_nonzero(new) < 2 or np.array_equal(new, keep):
            break
        keep = new
    return offset, scale, keep


def _one_per_mast(mast: IndexArray, residual: FloatArray) -> BoolArray:
    """Of turning points matched to the same mast, the one closest to it."""
    order = np.lexsort((np.abs(residual), mast))
    first = np.concatenate([[True], np.diff(mast[order]) != 0])
    keep = np.zeros(mast.shape[0], dtype=bool)
    keep[order[first]] = True
    return keep


def align_to_register(
    turning_position_m: ArrayLike,
    mast_chainage_m: ArrayLike,
    start_chainage_m: float,
    direction: str,
    *,
    tolerance_m: float = MATCH_TOLERANCE_M,
    max_start_error_m: float = MAX_START_ERROR_M,
    max_scale_error: float = MAX_SCALE_ERROR,
) -> ChainageAlignment:
    """Match a run's turning points to the register's masts and fit the encoder's error.

    Parameters
    ----------
    turning_position_m : array_like, shape (k,)
        Encoder positions of the registration points [m] (:class:`TurningPointFinder`).
    mast_chainage_m : array_like, shape (n,)
        Chainages of the line's and track's masts [m], any order.
    start_chainage_m : float
        The header's chainage of the first scan [m].
    direction : str
        ``"increasing"`` or ``"decreasing"`` chainage (ValueError otherwise).
    tolerance_m : float, default MATCH_TOLERANCE_M
        Distance within which a predicted turning point matches a mast [m].
    max_start_error_m : float, default MAX_START_ERROR_M
        Largest error of ``start_chainage_m`` searched for [m].
    max_scale_error : float, default MAX_SCALE_ERROR
        Largest relative scale error of the encoder accepted.

    Returns
    -------
    ChainageAlignment
        Aligned, or :meth:`ChainageAlignment.unaligned` with the reason (too few turning
        points, too few matched: fewer than ``MIN_MATCHED`` or ``MIN_MATCHED_FRACTION``).
    """
    sign = direction_sign(direction)
    turning = np.asarray(turning_position_m, dtype=np.float64).ravel()
    turning = np.sort(turning[np.isfinite(turning)])
    masts = np.asarray(mast_chainage_m, dtype=np.float64).ravel()
    masts = np.unique(masts[np.isfinite(masts)])
    found = int(turning.shape[0])
    start = float(start_chainage_m)

    def unaligned(reason: str, matched: int = 0) -> ChainageAlignment:
        return ChainageAlignment.unaligned(
            start, direction, reason, turning_points=found, matched=matched
        )

    if masts.shape[0] < MIN_MATCHED:
        return unaligned(f"the register has {masts.shape[0]} masts, at least {MIN_MATCHED} needed")
    if found < MIN_MATCHED:
        return unaligned(f"{found} turning points found, at least {MIN_MATCHED} needed")
    shift, votes, voters = _initial_shift(
        turning, masts, start, sign, tolerance_m, max_start_error_m, max_scale_error
    )
    if votes < MIN_MATCHED:
        return unaligned(
            f"no start offset within ±{max_start_error_m:g} m puts {MIN_MATCHED} of the first "
            f"{voters} of {found} turning points at masts (best: {votes})"
        )
    cap = max(tolerance_m, float(np.median(np.diff(masts))) / 3.0)

    # progressive matching, one turning point at a time
    q_all = sign * turning
    offset, scale = start + shift, 1.0
    tp: list[int] = []
    mast: list[int] = []
    for i in range(found):
        predicted = offset + scale * q_all[i]
        m = int(_nearest(masts, np.array([predicted]))[0])
        residual = masts[m] - predicted
        if tp:
            matched_p = turning[tp]
            extent = float(matched_p[-1] - matched_p[0])
            drift = max_scale_error
            if extent >= MIN_SCALE_EXTENT_M:
                drift = min(max_scale_error, tolerance_m / extent)
            tolerance = tolerance_m + drift * abs(float(turning[i] - matched_p.mean()))
        else:
            tolerance = tolerance_m + max_scale_error * float(turning[i] - turning[0])
        if abs(residual) > min(tolerance, cap):
            continue
        if mast and mast[-1] == m:  # the same mast again: keep the closer turning point
            previous = masts[m] - (offset + scale * q_all[tp[-1]])
            if abs(previous) <= abs(residual):
                continue
            tp.pop()
            mast.pop()
        tp.append(i)
        mast.append(m)
        q = q_all[tp]
        with_scale = float(turning[tp[-1]] - turning[tp[0]]) >= MIN_SCALE_EXTENT_M
        offset, scale = _fit(q, masts[mast], max_scale_error, with_scale)
    if len(tp) < MIN_MATCHED:
        return unaligned(f"{len(tp)} of {found} turning points matched a mast", len(tp))

    # the final model: robust least squares, every turning point matched again to it
    offset, scale, _ = _robust_fit(q_all[tp], masts[mast], max_scale_error)
    index = np.zeros(0, dtype=np.intp)
    to_mast = np.zeros(0, dtype=np.intp)
    for _ in range(2):
        predicted_all = offset + scale * q_all
        nearest = _nearest(masts, predicted_all)
        residual_all = masts[nearest] - predicted_all
        index = np.flatnonzero(np.abs(residual_all) <= min(tolerance_m, cap))
        index = index[_one_per_mast(nearest[index], residual_all[index])]
        to_mast = nearest[index]
        if index.shape[0] < MIN_MATCHED:
            break
        offset, scale, keep = _robust_fit(q_all[index], masts[to_mast], max_scale_error)
        index, to_mast = index[keep], to_mast[keep]
    if index.shape[0] < MIN_MATCHED:
        return unaligned(
            f"{index.shape[0]} of {found} turning points matched a mast", int(index.shape[0])
        )
    matched = int(index.shape[0])
    need = max(MIN_MATCHED, math.ceil(MIN_MATCHED_FRACTION * found))
    if matched < need:
        return unaligned(
            f"{matched} of {found} turning points matched a mast (at least {need} needed)",
            matched,
        )
    if abs(scale - 1.0) >= max_scale_error:
        return unaligned(
            f"fitted encoder scale {scale:.5f} is beyond 1 ± {max_scale_error:g}", matched
        )
    residual = masts[to_mast] - (offset + scale * q_all[index])
    return ChainageAlignment(
        offset_m=float(offset),
        scale=float(scale),
        direction_sign=sign,
        matched=matched,
        turning_points=found,
        residual_rms_m=float(np.sqrt(np.mean(residual**2))),
        max_residual_m=float(np.max(np.abs(residual))),
        aligned=True,
    )


# -- spans ---------------------------------------------------------------------------------


def span_index(chainage_m: ArrayLike, boundaries_m: ArrayLike) -> IndexArray:
    """The span of each chainage: ``i`` with ``boundaries[i] <= c < boundaries[i + 1]``.

    Parameters
    ----------
    chainage_m : array_like, any shape
        Chainages [m].
    boundaries_m : array_like, shape (b,)
        Span boundaries (mast chainages) [m], ascending (non-decreasing; a repeated value is
        an empty span). ValueError otherwise.

    Returns
    -------
    ndarray of intp, the shape of ``chainage_m``
        Span index in ``0 .. b - 2``; ``-1`` outside all spans (before the first boundary, at
        or after the last one, NaN, or fewer than two boundaries).
    """
    c = np.asarray(chainage_m, dtype=np.float64)
    b = np.asarray(boundaries_m, dtype=np.float64)
    if b.ndim != 1:
        raise ValueError(f"boundaries_m must be one-dimensional, got shape {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(np.diff(b) < 0.0):
        raise ValueError("boundaries_m must be finite and ascending")
    index = np.searchsorted(b, c, side="right") - 1
    inside = np.isfinite(c) & (index >= 0) & (index < b.shape[0] - 1)
    return np.where(inside, index, -1).astype(np.intp)
