"""Stagger-angle correction of the wear width (the paper's section 4.2, eq. 11-12).

The scanning plane of the cameras is perpendicular to the track; a contact wire crosses it at
the angle ``θ`` it makes with the track in plan, so the worn face measured in the plane is
``w = w0 / cos θ`` and the face across the wire is::

    w0 = w cos θ                                                    (eq. 12)

The paper estimates ``θ`` from the design staggers of two masts (eq. 11: ``sin θ =
(|S1| + |S2|) / L``). Here ``θ`` comes from the *measured* stagger along the track, so that it
holds in curves (where the stagger is an arc), at overlaps and turnouts (where a wire leaves the
track's direction quickly) and wherever the line differs from its design::

    tan θ = |d stagger / d position|

The gradient is a local least-squares line fitted to the stagger samples of one wire within a
window of ``window_m`` metres of track (``DEFAULT_WINDOW_M``). A stagger zigzag has a kink at
every registration point, where the slope changes sign; a window centred on a kink would
average the two sides toward zero. So three windows of the same length are fitted at every
point — centred, ending at it and starting at it — and the centred one gives the slope unless
a one-sided one fits clearly better (``ONE_SIDED_PREFERENCE``): near a kink the window that
does not straddle it wins (the "essentially non-oscillatory" choice of stencil). Noise in the
slope from the fitted window: for ``n`` samples of stagger noise ``σ`` over ``W`` metres,
``σ_slope ≈ σ sqrt(12 / n) / W`` (0.3 mm over 2 m at 13 mm spacing: 0.05 mm/m, against the
12-20 mm/m of a typical zigzag).

The stagger must be in the track frame (after vehicle compensation): the car body's lateral
sway moves the roof frame by ~10 mm over a few metres, a gradient of the same order as the
wire's own. A streaming caller gives each call ``window_m`` of samples on either side of the
ones it keeps.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

__all__ = [
    "DEFAULT_WINDOW_M",
    "MIN_WINDOW_SAMPLES",
    "corrected_wear_width_mm",
    "stagger_angle_by_wire_rad",
    "stagger_angle_rad",
]

FloatArray = NDArray[np.float64]

DEFAULT_WINDOW_M = 2.0
"""Length of track over which the stagger gradient is fitted [m]. Long enough to average the
stagger's measurement noise (the slope's noise falls as ``W^-1.5``), short enough that the
gradient of a wire at a turnout or an overlap, which changes over 10-30 m, is followed, and at
most a few percent of a 40-65 m span, so that a kink affects only the points next to it."""

MIN_WINDOW_SAMPLES = 5
"""Fewest samples a window needs for its line to be used."""

ONE_SIDED_PREFERENCE = 0.5
"""A one-sided window replaces the centred one when its residual variance is below this
fraction of the centred one's: clearly better (a kink in the centred window), not by chance.
On a smooth curve (an offset arc in a curve) all three fit alike and the centred window,
unbiased there, is kept."""

_BINS_PER_WINDOW = 20


def _window_sums(values: FloatArray, first: int, last: int, power: int = 0) -> FloatArray:
    """``out[i] = Σ_k values[k] · (k - i)**power`` over ``k = i + first .. i + last``.

    Zero outside the array; the weights are the small offsets ``k - i``, so no large numbers
    cancel however long the run.
    """
    offsets = np.arange(first, last + 1, dtype=np.float64)
    # correlate1d centres a window of ``size`` taps on ``size // 2``, shifted by ``origin``
    origin = first + offsets.shape[0] // 2
    return np.asarray(
        ndimage.correlate1d(
            values, offsets**power, axis=0, mode="constant", cval=0.0, origin=-origin
        ),
        dtype=np.float64,
    )


def _window_moments(
    bins: dict[str, FloatArray], step_m: float, first: int, last: int
) -> tuple[FloatArray, ...]:
    """Sums over bins ``i + first .. i + last`` of the samples' moments, with ``x`` the
    position relative to bin ``i``'s centre [m]: ``n, Σx, Σx², Σs, Σxs, Σs²``."""
    n_b, p1, p2 = bins["n"], bins["p1"], bins["p2"]
    s1, ps, s2 = bins["s1"], bins["ps"], bins["s2"]
    count = _window_sums(n_b, first, last)
    sum_x = step_m * _window_sums(n_b, first, last, 1) + _window_sums(p1, first, last)
    sum_xx = (
        step_m * step_m * _window_sums(n_b, first, last, 2)
        + 2.0 * step_m * _window_sums(p1, first, last, 1)
        + _window_sums(p2, first, last)
    )
    sum_s = _window_sums(s1, first, last)
    sum_xs = step_m * _window_sums(s1, first, last, 1) + _window_sums(ps, first, last)
    sum_ss = _window_sums(s2, first, last)
    return count, sum_x, sum_xx, sum_s, sum_xs, sum_ss


def stagger_angle_rad(
    position_m: ArrayLike, stagger_mm: ArrayLike, window_m: float = DEFAULT_WINDOW_M
) -> FloatArray:
    """Angle ``θ`` between one wire and the track in plan, from its measured stagger.

    ``tan θ = |d stagger / d position|`` from a local least-squares line over ``window_m`` of
    track (module docstring: centred, trailing or leading window, whichever fits best).

    Parameters
    ----------
    position_m : array_like, shape (m,)
        Position of each sample along the track [m] (encoder distance), any order; repeated
        positions are allowed.
    stagger_mm : array_like, shape (m,)
        The wire's stagger at each sample, track frame [mm]. NaN samples are ignored (and get
        NaN).
    window_m : float, default DEFAULT_WINDOW_M
        Length of track of each fitted line [m], positive.

    Returns
    -------
    ndarray, shape (m,)
        ``θ`` [rad] in ``[0, π/2)``, fitted per twentieth of a window and interpolated
        linearly between; NaN where no window around the sample holds ``MIN_WINDOW_SAMPLES``
        samples spread over a quarter of the window at least.
    """
    position = np.asarray(position_m, dtype=np.float64)
    stagger = np.asarray(stagger_mm, dtype=np.float64)
    if position.shape != stagger.shape or position.ndim != 1:
        raise ValueError(
            f"position_m {position.shape} and stagger_mm {stagger.shape} must be one (m,) shape"
        )
    if not (np.isfinite(window_m) and window_m > 0.0):
        raise ValueError(f"window_m = {window_m} must be a positive length")
    theta = np.full(position.shape, np.nan)
    valid = np.isfinite(position) & np.isfinite(stagger)
    if np.count_nonzero(valid) < MIN_WINDOW_SAMPLES:
        return theta
    p = position[valid]
    s = stagger[valid]
    s = s - np.median(s)  # small numbers in the sums
    half_bins = _BINS_PER_WINDOW // 2
    step = window_m / (2 * half_bins)
    origin = float(p.min())
    index = np.floor((p - origin) / step).astype(np.intp)
    offset = p - (origin + (index + 0.5) * step)
    bins_count = int(index.max()) + 1

    def accumulate(weights: FloatArray) -> FloatArray:
        return np.bincount(index, weights=weights, minlength=bins_count).astype(np.float64)

    bins = {
        "n": accumulate(np.ones_like(p)),
        "p1": accumulate(offset),
        "p2": accumulate(offset * offset),
        "s1": accumulate(s),
        "ps": accumulate(offset * s),
        "s2": accumulate(s * s),
    }
    fits = []
    for first, last in ((-half_bins, half_bins), (-2 * half_bins, 0), (0, 2 * half_bins)):
        n, sx, sxx, ss, sxs, sss = _window_moments(bins, step, first, last)
        with np.errstate(divide="ignore", invalid="ignore"):
            spread_xx = sxx - sx * sx / n
            spread_xs = sxs - sx * ss / n
            spread_ss = sss - ss * ss / n
            slope = spread_xs / spread_xx
            variance = np.maximum(spread_ss - slope * spread_xs, 0.0) / (n - 2.0)
        # enough samples, spread along the window (a quarter of it at least: positions
        # uniform over W/4 have a standard deviation of W / sqrt(192))
        usable = (n >= MIN_WINDOW_SAMPLES) & (spread_xx > n * window_m**2 / 192.0)
        usable &= np.isfinite(slope) & np.isfinite(variance)
        fits.append((slope, np.where(usable, variance, np.inf)))
    (centred, v_centred), (trailing, v_trailing), (leading, v_leading) = fits
    side = np.where(v_trailing <= v_leading, trailing, leading)
    v_side = np.minimum(v_trailing, v_leading)
    # the centred window unless a one-sided one fits clearly better
    use_side = np.isfinite(v_side) & ~(v_side >= ONE_SIDED_PREFERENCE * v_centred)
    best_slope = np.where(use_side, side, np.where(np.isfinite(v_centred), centred, np.nan))
    # θ at each bin's centre, linear between neighbouring centres (a gradient that changes
    # along the track, as in a curve, is followed between bins; across a kink the two sides'
    # angles are blended over one bin only)
    theta_bins = np.arctan(np.abs(best_slope) / 1000.0)
    centre = origin + (np.arange(bins_count) + 0.5) * step
    fraction = (p - centre[index]) / step  # -0.5 .. 0.5
    neighbour = np.clip(index + np.where(fraction >= 0.0, 1, -1), 0, bins_count - 1)
    blend = np.where(np.isfinite(theta_bins[neighbour]), np.abs(fraction), 0.0)
    theta[valid] = (1.0 - blend) * theta_bins[index] + blend * np.nan_to_num(theta_bins[neighbour])
    return theta


def stagger_angle_by_wire_rad(
    wire: ArrayLike,
    position_m: ArrayLike,
    stagger_mm: ArrayLike,
    window_m: float = DEFAULT_WINDOW_M,
) -> FloatArray:
    """:func:`stagger_angle_rad` of every wire of a table of observations.

    Parameters
    ----------
    wire : array_like of int, shape (m,)
        Wire number of each row.
    position_m, stagger_mm : array_like, shape (m,)
        As in :func:`stagger_angle_rad`.
    window_m : float, default DEFAULT_WINDOW_M
        Length of track of each fitted line [m].

    Returns
    -------
    ndarray, shape (m,)
        ``θ`` [rad] of each row, from the rows of its own wire only.
    """
    wires = np.asarray(wire)
    position = np.asarray(position_m, dtype=np.float64)
    stagger = np.asarray(stagger_mm, dtype=np.float64)
    if not (wires.shape == position.shape == stagger.shape) or wires.ndim != 1:
        raise ValueError("wire, position_m and stagger_mm must share one (m,) shape")
    theta = np.full(position.shape, np.nan)
    for number in np.unique(wires):  # one loop step per wire, not per sample
        rows = np.flatnonzero(wires == number)
        theta[rows] = stagger_angle_rad(position[rows], stagger[rows], window_m)
    return theta


def corrected_wear_width_mm(w_mm: ArrayLike, theta_rad: ArrayLike) -> FloatArray:
    """Wear width across the wire from the width in the scanning plane (eq. 12).

    Parameters
    ----------
    w_mm : array_like
        Worn face's width measured in the scanning plane [mm].
    theta_rad : array_like, broadcastable with ``w_mm``
        Angle between the wire and the track in plan [rad] (:func:`stagger_angle_rad`).

    Returns
    -------
    ndarray, the broadcast shape
        ``w0 = w cos θ`` [mm]; NaN where either input is NaN.
    """
    w = np.asarray(w_mm, dtype=np.float64)
    theta = np.asarray(theta_rad, dtype=np.float64)
    return np.asarray(w * np.cos(theta), dtype=np.float64)
