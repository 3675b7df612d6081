"""Stagger-angle correction of the wear width (the paper's section 4.2, eq. 11-12), and the
along-track screen of the widths.

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

**Screen.** A wire's wear changes along the track over decimetres and more; a fitting behind
the wire (a dropper's or registration clamp) disturbs the images of the worn face's edges for
a few scans: the wire's side between its face and the clamp is a dark strip narrower than the
optical blur, which no view can tell from a narrower face (the face reads up to 0.1 mm
narrower in every camera, 0.14 mm of residual thickness near the wear limit).
:func:`screened_wear_width_mm` leaves such excursions out, as a Hampel filter along the track:
a width departing from the median of its wire's widths within ``SCREEN_HALF_WINDOW_M`` by more
than ``SCREEN_MADS`` times their noise. The row keeps its position; only its width goes.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike
from scipy import ndimage

from catenary.arrays import FloatArray, IndexArray

__all__ = [
    "DEFAULT_WINDOW_M",
    "MIN_WINDOW_SAMPLES",
    "SCREEN_HALF_WINDOW_M",
    "SCREEN_NOISE_HALF_WINDOW_M",
    "corrected_wear_width_mm",
    "screened_wear_width_by_wire_mm",
    "screened_wear_width_mm",
    "stagger_angle_by_wire_rad",
    "stagger_angle_rad",
]

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

SCREEN_HALF_WINDOW_M = 0.1
"""Half the length of track over which a wear width is compared with its neighbours [m]
(:func:`screened_wear_width_mm`). A wire's wear changes over decimetres to metres (hot spots
at registrations span one to a few metres); a fitting that disturbs the worn face's edges in
the images (a dropper's or registration clamp behind the wire, 15-50 mm along the track) lasts
a few scans. The window is four times that at least, so that its median is the wire's."""

SCREEN_NOISE_HALF_WINDOW_M = 0.5
"""Half the length of track over which the widths' noise is estimated [m]: long enough that a
fitting's few scans do not raise it, short enough to follow the lighting along the run. The
screen looks this far on either side of a width."""

SCREEN_MADS = 4.0
"""A width further than this many noise deviations from its window's median is an excursion
(the Hampel identifier's usual 3, with room)."""

SCREEN_FLOOR_MM = 0.04
"""Least departure from the window's median screened out [mm]: where the widths are quieter
than this over a window, four deviations would be below what matters to the thickness."""

_SCREEN_MAX_SIDE = 128
"""Most samples on either side of a width that a window holds: a train at a standstill
repeats one place. Below 0.8 mm between scans (2.8 km/h at 1000 scans/s) the median's window
is shorter than ``SCREEN_HALF_WINDOW_M``, and a fitting that spans more than half of it is no
longer screened."""

_SCREEN_CHUNK_VALUES = 1 << 20
"""Window values sorted at once (8 MiB), whatever the number of widths."""

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
    return _per_wire(
        wire, position_m, ("stagger_mm", stagger_mm), lambda p, v: stagger_angle_rad(p, v, window_m)
    )


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


def screened_wear_width_mm(position_m: ArrayLike, width_mm: ArrayLike) -> FloatArray:
    """One wire's wear widths with short excursions along the track left out (NaN).

    A Hampel filter: a width further from the median of the widths within
    ``SCREEN_HALF_WINDOW_M`` of it (itself included) than ``SCREEN_MADS`` times their noise,
    and than ``SCREEN_FLOOR_MM``, is not the wire's wear but a fitting's disturbance of the
    face's edges: at a dropper clamp the wire's dark side between its face and the clamp
    behind it is narrower than the optical blur, and the face reads up to 0.1 mm narrower, in
    every camera. Its row keeps its position; only the width is dropped. The noise is the
    robust deviation of the differences between neighbouring widths within
    ``SCREEN_NOISE_HALF_WINDOW_M`` (the wire's own gradient is not noise; an excursion's
    two steps are two differences of many). An excursion shorter than half the window is
    screened; a change that lasts longer (new wear, a splice, a hot spot) is kept, but for the
    odd sample at its edge. A width of 0.0 (no face seen) among worn ones, or a face among
    0.0s, is an excursion too. A window with fewer than ``MIN_WINDOW_SAMPLES`` widths
    screens nothing (over 50 mm between scans: 180 km/h at 1000 scans/s).

    Parameters
    ----------
    position_m : array_like, shape (m,)
        Position of each sample along the track [m], any order.
    width_mm : array_like, shape (m,)
        The wire's wear width at each sample [mm]; NaN samples are ignored (and stay NaN).

    Returns
    -------
    ndarray, shape (m,)
        The widths [mm], NaN where screened out.
    """
    position = np.asarray(position_m, dtype=np.float64)
    width = np.asarray(width_mm, dtype=np.float64)
    if position.shape != width.shape or position.ndim != 1:
        raise ValueError(
            f"position_m {position.shape} and width_mm {width.shape} must be one (m,) shape"
        )
    out = width.copy()
    valid = np.flatnonzero(np.isfinite(position) & np.isfinite(width))
    if valid.shape[0] < MIN_WINDOW_SAMPLES:
        return out
    order = valid[np.argsort(position[valid], kind="stable")]
    p, w = position[order], width[order]
    median, count = _rolling_median(p, w, p, SCREEN_HALF_WINDOW_M)
    steps, _ = _rolling_median(
        0.5 * (p[1:] + p[:-1]), np.abs(np.diff(w)), p, SCREEN_NOISE_HALF_WINDOW_M
    )
    noise = 1.4826 / math.sqrt(2.0) * steps
    excursion = np.abs(w - median) > np.maximum(SCREEN_MADS * noise, SCREEN_FLOOR_MM)
    excursion &= count >= MIN_WINDOW_SAMPLES
    out[order[excursion]] = np.nan
    return out


def _rolling_median(
    position: FloatArray, values: FloatArray, at: FloatArray, half_window_m: float
) -> tuple[FloatArray, IndexArray]:
    """Median ``(k,)`` of the ``values`` (``(m,)``, ``m >= 1``, sorted by ``position``)
    within ``half_window_m`` of each of the sorted positions ``at`` ``(k,)``, and how many
    there are. A window holds at most ``_SCREEN_MAX_SIDE`` values on either side of index
    ``i`` for ``at[i]``; windows are sorted ``_SCREEN_CHUNK_VALUES`` values at a time."""
    i = np.arange(at.shape[0])
    first = np.maximum(np.searchsorted(position, at - half_window_m), i - _SCREEN_MAX_SIDE)
    stop = np.minimum(
        np.searchsorted(position, at + half_window_m, side="right"), i + _SCREEN_MAX_SIDE + 1
    )
    count = np.maximum(stop - first, 0)
    widest = max(int(count.max()), 1)
    padded = np.concatenate([values, np.full(widest, np.inf)])
    median = np.full(at.shape[0], np.nan)
    rows = max(1, _SCREEN_CHUNK_VALUES // widest)
    for lo in range(0, at.shape[0], rows):  # a loop per chunk of rows: bounded memory
        part = slice(lo, lo + rows)
        n = count[part]
        span = max(int(n.max()), 1)  # a standstill widens its own chunk only
        window = sliding_window_view(padded, span)[first[part]]  # (rows, span), a copy
        window[np.arange(span) >= n[:, np.newaxis]] = np.inf
        window.sort(axis=1)  # the padding last; ten times faster than nanmedian
        j = np.arange(window.shape[0])
        middle = 0.5 * (window[j, np.maximum(n - 1, 0) // 2] + window[j, n // 2])
        median[part] = np.where(n > 0, middle, np.nan)
    return median, count


def screened_wear_width_by_wire_mm(
    wire: ArrayLike, position_m: ArrayLike, width_mm: ArrayLike
) -> FloatArray:
    """:func:`screened_wear_width_mm` of every wire of a table of observations.

    Parameters
    ----------
    wire : array_like of int, shape (m,)
        Wire number of each row.
    position_m, width_mm : array_like, shape (m,)
        As in :func:`screened_wear_width_mm`.

    Returns
    -------
    ndarray, shape (m,)
        Each row's width [mm], screened against the rows of its own wire only.
    """
    return _per_wire(wire, position_m, ("width_mm", width_mm), screened_wear_width_mm)


def _per_wire(
    wire: ArrayLike,
    position_m: ArrayLike,
    values: tuple[str, ArrayLike],
    along_track: Callable[[FloatArray, FloatArray], FloatArray],
) -> FloatArray:
    """``along_track(position, values)`` of the rows of each wire number, in place of its rows
    (``values``: their name, for the error, and the values)."""
    name, given = values
    wires = np.asarray(wire)
    position = np.asarray(position_m, dtype=np.float64)
    value = np.asarray(given, dtype=np.float64)
    if not (wires.shape == position.shape == value.shape) or wires.ndim != 1:
        raise ValueError(f"wire, position_m and {name} must share one (m,) shape")
    out = np.full(position.shape, np.nan)
    for number in np.unique(wires):  # one loop step per wire, not per sample
        rows = np.flatnonzero(wires == number)
        out[rows] = along_track(position[rows], value[rows])
    return out
