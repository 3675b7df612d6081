"""Profile features of one camera's lines: wire candidates, their boundaries and wear faces.

Step 1 of the line-scan stereovision processor (the paper, section 3.2, steps 1-3, figures
5-7). Per camera line:

1. **Noise.** A robust per-line noise estimate: the MAD of the first difference on a sample
   of pixel pairs (``noise_samples``), read as a grouped median so that quantised low-noise
   data (8-bit lines at night) give a smooth estimate, floored at ``noise_floor_lsb``.
2. **Background and candidates** (step 1 of the paper). The line is summed in bins of
   ``bin_px`` pixels, grouped in cells of four bins. The background beside a cell is the
   mean filter of the line over ``background_px`` on either side of it, beyond a guard of
   one wire width, so that an object (at most a wire wide) never drags its own background. A
   bin is a candidate when it stands out from the background on both sides, in the same
   polarity, by ``detect_k`` noise deviations and by ``detect_rel`` of the sky's level:
   bright wires on a dark sky (night, or by day with the band-pass filter), dark silhouettes
   on a bright sky (white daylight). Both sides: the sky's gradients are not objects. The
   bright test uses the mean of the cells' brightest bins, the dark test of their darkest,
   so that another object in the windows makes detection harder, never easier (the sky
   between two wires is not an object). Next to a step between neighbouring bins
   (``edge_rel`` of their level: the first difference at bin scale) half of ``detect_rel``
   suffices: an unworn wire by day behind the filter is a silhouette of low mean contrast,
   while the sky's texture changes far less over one bin. Runs of such bins are candidates
   (a bright run and a dark one that together span no more than the widest wire are one: a
   face and its dark sides, or an unworn wire's dark side and its lit bottom with the sky's
   level between them); runs wider than a wire can be are dropped (registration arms,
   droppers seen along their length, glare). Two dark runs are one candidate too when the
   undetected run between them is narrower than the widest wire, together they span no more
   than the widest wire, and it is darker or brighter than the sky beside them: a dark
   silhouette whose worn face, lit from below, is almost as bright as the sky (white
   daylight), or an unworn wire's lit bottom between its dark sides (behind the filter), not
   two wires with the sky between them (``_dark_joins``). A dark run takes the undetected
   bins beside it up to a step back to the sky, within the widest wire, when they are darker
   than the sky beyond that step: near the wear limit a camera that sees the wire obliquely
   sees the face reach the silhouette on one side, the wire's side on the other is all that
   is dark, and against the darker background window of a sloping sky the face is not
   detected (``_dark_faces``). A candidate then reaches to where the sky begins beside it:
   the nearest bin within a wire's width that differs from the flat sky just beyond it, that
   sky agreeing with the sky beyond its other end (``_extents``: a faint side of a wire,
   undetected, is not left out of step 3).
3. **Wire boundaries** (step 2). On a pixel window per candidate, after a light
   ``[1, 2, 1] / 4`` smoothing, against the sky measured just beside it (clear of its
   neighbours): the run's extreme deviation gives the polarity and the contrast (it must
   pass ``detect_k`` and ``detect_rel`` at pixel level too); each boundary is where the
   deviation crosses half of its level just inside the outermost significant pixel
   (``boundary_k`` noise deviations, ``boundary_rel`` of the peak, and three times the sky's
   texture: the largest deviation of the sky pixels from the ramp between the two sides,
   capped at ``detect_rel`` of the peak, beyond which it is a neighbour's edge): over a
   blurred step's rise (4 px), and for a dark silhouette, which occludes the sky, over three
   ``sharp_px`` (its plateau under a blur of several pixels: a 16k line's). Candidates
   wider than a wire can be, or narrower and without a face (``wire_width_px``,
   ``width_tolerance``: the expected width at the measuring range), are dropped. A boundary
   is the wire's outline (it occludes the sky there) when, just inside it (pixels 1 to
   ``sharp_px // 2``), the line has fallen to half the wire's darkest deviation from the sky,
   as a blurred step does; the end of a lit part is brighter than the sky inside, and an
   unworn wire's shading darkens over a good part of the wire. A wire without a face whose
   outline shows on one side only (``outline_side``: by day behind the filter, lit from one
   side, its other side as bright as the sky) is located by that edge in the matching. Only
   a candidate with the sky clear of other runs beside both boundaries is such a wire: each
   part of a dark silhouette split at its face (a fitting by white daylight) has a steep
   outer edge too.
4. **Wear face** (step 3). The worn face is brighter than the wire's round sides in every
   lighting, so its edges are the strongest rising and falling first differences inside the
   wire (the zero crossings of the second difference). For a bright object they are
   searched over the whole wire; for a dark silhouette inside its boundaries, clear of
   their blurred ramps (a blur of several pixels carries the larger step, from the dark side
   to the sky, well inside the wire: the rising edge is searched before the right
   boundary's ramp, the falling one after the left's), and a face that reaches the
   silhouette on one side (the wire is as bright as the face, not as dark as its sides,
   just inside it, past the ramp) takes that boundary's edge. An edge must be significant
   (``face_k`` noise deviations) and sharp: its first-difference peak falls by three
   quarters ``sharp_px`` away on both sides, which a blurred step does and the smooth
   shading of a round, unworn wire does not (a new wire has no face). The blur that sets
   ``sharp_px`` is the lens's, fixed on the wire in millimetres, not in pixels: a rig's
   config scales it to its coarsest resolution (:meth:`FeatureConfig.from_resolution`).
5. **Sub-pixel.** Each edge is the vertex of the parabola through the logarithm of the three
   first differences around its extremum: exact for a Gaussian-blurred step at any phase,
   where a plain parabola is biased by up to 0.03 px (it is used when the values do not
   allow the logarithm). A blur of several pixels (a rig whose ``sharp_px`` exceeds
   ``_PEAKED_PX``) is mostly defocus, flat-topped, and the vertex wanders over its top with
   the noise: the edge is then a centroid of its first difference within ``sharp_px``
   (:func:`_edge`), unbiased for any symmetric blur. Boundaries are linearly interpolated
   level crossings.
6. **A dark silhouette's face edge next to its silhouette** (white daylight, wide faces):
   the step from the sky down to the wire's dark side and the step up to the face are
   opposite and pull each other's first-difference peaks apart (by about 1 px when 1.5 px
   apart, still 0.1-0.5 px at 3 px under a blur of 1 px, and from further under a blur of
   several: a 16k line's face edge 3.8 px from its silhouette read 1.6 px inward). A wire
   with a face edge from 0.8 to 6 px (``sharp_px`` if more) from its silhouette is fitted
   whole: a blurred four-edge profile (the sky's ramp beside it, one level for both dark
   sides, the face's level, the four edges and a Gaussian blur started from the wider of
   the silhouette edges' peaks) by Gauss-Newton on the smoothed window. A dark side
   narrower than the blur shows its level only together with its width: the other side
   gives it. Closer than 0.8 px the two cannot be told apart: that side keeps its edges
   (and a one-sided face, step 4, its own); so does a face narrower than three blur
   deviations, whose level and width trade off.

Faces narrower than the optical blur (about 2.5-3 px with the smoothing) are not resolved:
their edges read about 2.4-3.3 px apart. Near the wear limit the opposite: a face edge closer
to its silhouette than the blur (the wire's side between them a strip of ``g`` px at level
``D``, the sky ``S`` beyond, the face ``F``) merges with it into one step, to first order a
step from ``S`` to ``F`` at ``g (F - D) / (F - S)`` px from the silhouette: the edge is
located ``g (S - D) / (F - S)`` px inward of the face's. No estimator on one line tells ``g``
from ``D``. Bright faces on a sky brighter than the wire's sides (by day behind the filter: about
``0.1 g``) read narrow; dark silhouettes (white daylight, ``S`` far above ``F``) read wide by
more than ``g`` where the face is taken to reach the silhouette (step 4). Where both dark
sides are narrower than about twice the blur their level is seen nowhere, and the face reads
narrow (on three-level lines with a sharp lens by 0.3 px at sides of 2 px, 1 px at 1 px;
more under defocus).

The point to triangulate (``centre_px``) is the face's centre, the contact point, when a face
is found, else the middle of the wire's boundaries (the wire's axis, a radius above the
contact point; ``has_face`` tells which).

Conventions: the centre of pixel ``i`` is at ``u = i`` (FORMATS.md); the first difference
``x[i + 1] - x[i]`` sits at ``u = i + 0.5``. Everything is vectorised over the block: the
background and detection work on bin sums of every line (cells whose extreme bins stand out
are then looked at bin by bin), the edge work on short pixel windows around the candidates;
lines are processed in groups of rows (the results do not depend on the block or group size:
every step is per line).
"""

from __future__ import annotations

import itertools
import math
import sys
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IndexArray

__all__ = ["FACE_RESOLVED_PX", "FeatureConfig", "LineFeatures", "extract_features", "noise_sigma"]


_GROUP_BYTES = 1 << 22
"""Bytes of line data processed at once: the more lines, the less per-call overhead; the
per-pixel work is done in pieces of ``_CACHE_BYTES``."""
_CACHE_BYTES = 1 << 19
"""Bytes of line data whose per-pixel temporaries stay in the CPU's cache."""
_SUPER = 4
"""Bins per cell: the background windows are laid out on cells."""
_SKY_PX = 4
"""Pixels beside a candidate that measure the sky next to it."""
_EDGE_PX = 4
"""Pixels inside a boundary over which its level is taken (a blurred step's rise)."""
_DARK_RISE = 3
"""A dark silhouette's boundary level is taken over this many ``sharp_px`` inside it."""
_TEXTURE = 3.0
"""A boundary's level is at least this multiple of the sky's texture beside the wire (the
largest deviation of its sky pixels from the ramp between them): texture grows with the
distance from where the sky was measured, and a few DN of cloud must not pass for the wire."""
_GUARD_PX = 3
"""Pixels inside a dark silhouette's boundaries left out of its face search."""
_PROMINENCE = 0.75
"""A face edge's first difference must fall by this fraction of its peak ``sharp_px`` away."""
_SHARP_MM = 1.75
"""Distance on the wire [mm] within which a face edge's first difference falls to a quarter
of its peak: three times the optical blur (sigma). The lens sets that blur on the wire, not
on the sensor: keeping a measuring range of depths about 1:2 in focus, the few millimetres
of aperture a line-scan lens has at f/8-f/16 blur the wire at the range's ends by a defocus
disc of 2-3 mm (sigma about 0.6 mm) whatever the pixels behind it. 4 px at 0.44 mm/px, the
demo rig's coarsest resolution, where ``sharp_px`` was established; a 16,384-px line sees
the same blur over two to three times as many pixels as a 4096-px one (up to ~10 px)."""
_PEAKED_PX = 4
"""Up to this ``sharp_px`` the blur is about a pixel, diffraction's and the lens's, nearly
Gaussian: the log-parabola through three first differences locates an edge exactly. Beyond
it (the lens's blur spread over finer pixels) the blur is mostly defocus, the projection of
a disc: flat-topped over several pixels, where the three top samples wander with the noise
(face widths +-3 px on a 16,384-px line); the edge is then a centroid of its first
difference within ``sharp_px`` (:func:`_edge`)."""
_CENTROID_ITERATIONS = 3
_NEAR_PX = 6.0
FACE_RESOLVED_PX = 0.8
"""A dark silhouette with a face edge between this and ``_NEAR_PX`` (``sharp_px`` if more)
[px] from its silhouette is fitted whole (module docstring, step 6); closer, the two are one
blurred step, and the face edge lies outward of the face's (the matching's face widths)."""
_FIT_ITERATIONS = 8
_FIT_SETTLED_PX = 1e-3
"""A wire whose fitted edges moved less than this in a step [px] is not fitted further."""
_MIXED = 0.5
"""A candidate whose weaker deviation (bright or dark) exceeds this fraction of the stronger
has no polarity (0)."""
_CDF_A = math.sqrt(2.0 / math.pi)
_CDF_B = 0.044715 * math.sqrt(2.0 / math.pi)
_SIZE_CLASSES_PX = (96,)
"""Candidates are processed in classes of window length (padding a short window to the
longest costs time, not results)."""


@dataclass(frozen=True)
class FeatureConfig:
    """Parameters of :func:`extract_features`; the defaults come from the physics.

    Attributes
    ----------
    wire_width_px : (float, float)
        Expected width of a contact wire in pixels over the measuring range: the narrowest
        wire at the coarsest resolution to the widest at the finest. The default is
        10.6-14.8 mm wires (EN 50149 AC-80 to AC-150) at 0.5-0.2 mm/px; a rig's own range
        comes from :meth:`from_resolution`. What is not given below scales with it.
    width_tolerance : (float, float)
        A candidate is kept when its width is within ``[lo * wire_width_px[0],
        hi * wire_width_px[1]]``. The low factor lets through wires whose round sides are
        too dark to be seen at night (the width is then that of the lit part) and messenger
        wires (further away, thinner in pixels: the matcher removes them by height).
    bin_px : int
        Width of the bins detection works on: a wire covers at least two whole bins.
    background_px : float or None
        Width of the mean filter on each side of a bin (beyond a guard of the widest wire)
        that gives its background; default twice the widest wire: long enough to average
        the noise down, short enough to follow the sky.
    detect_k : float
        Detection threshold in noise deviations (of a bin's mean, then of a smoothed pixel
        for the candidate's peak). At 6 no false candidate was seen in 6000 lines of pure
        noise of 4096 px.
    detect_rel : float
        Least contrast of a candidate relative to the sky's level: the sky's own texture
        (clouds) varies by up to a quarter over a few hundred pixels, most behind the
        band-pass filter, where the sky is dim; wires differ from it by half or more.
    edge_rel : float
        Least step between neighbouring bins, relative to their level, next to which half of
        ``detect_rel`` suffices (module docstring).
    boundary_k : float
        Least deviation (noise deviations of a smoothed pixel) of a wire's outermost pixel.
    boundary_rel : float
        The same relative to the candidate's peak deviation: sky texture stays below it.
    face_k : float
        Significance of a face edge: its first difference in noise deviations.
    sharp_px : int
        Distance at which a face edge's first difference must have fallen to a quarter of
        its peak: about three times the optical blur (sigma) in pixels. The default holds
        for pixels of up to 0.44 mm on the wire; :meth:`from_resolution` scales it to a
        rig's (``_SHARP_MM``).
    noise_samples : int
        Pixel pairs per line for the noise estimate.
    noise_floor_lsb : float
        Lowest pixel noise assumed [LSB]: quantisation makes lower estimates meaningless.
    outlines : bool
        Join a bright and a dark run that together span no more than the widest wire and
        report which boundary alone is a faceless wire's outline (``outline_side``; module
        docstring, steps 2-3), which the matching then images at the axis a radius inward.
        Off by default here; the processor turns it on (``ProcessorConfig.outlines``): on the
        scenario sweep it raises the recall of unworn wire behind the band-pass filter and
        lowers its worst heights (README), at some cost to worn 16k scenes (a joined
        candidate may reach on over an undetected neighbour within the widest wire). Off,
        runs one bin apart in opposite polarity are joined and ``outline_side`` is 0.
    """

    wire_width_px: tuple[float, float] = (10.6 / 0.5, 14.8 / 0.2)
    width_tolerance: tuple[float, float] = (0.5, 1.3)
    bin_px: int = 8
    background_px: float | None = None
    detect_k: float = 6.0
    detect_rel: float = 0.25
    edge_rel: float = 0.15
    boundary_k: float = 5.0
    boundary_rel: float = 0.02
    face_k: float = 5.0
    sharp_px: int = 4
    noise_samples: int = 128
    noise_floor_lsb: float = 0.5
    outlines: bool = False

    def __post_init__(self) -> None:
        lo, hi = self.wire_width_px
        if not 2.0 <= lo <= hi:
            raise ValueError(f"wire_width_px must be 2 <= min <= max, got {self.wire_width_px}")
        tlo, thi = self.width_tolerance
        if not 0.0 < tlo <= 1.0 <= thi:
            raise ValueError(f"width_tolerance must be 0 < lo <= 1 <= hi, got {(tlo, thi)}")
        if not 1 <= self.bin_px <= 64:
            raise ValueError(f"bin_px must be 1-64, got {self.bin_px}")
        for name in ("detect_k", "detect_rel", "edge_rel", "boundary_k", "boundary_rel", "face_k"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.background_px is not None and self.background_px < self.bin_px:
            raise ValueError(f"background_px must be at least bin_px, got {self.background_px}")
        if not self.noise_floor_lsb > 0:
            raise ValueError(f"noise_floor_lsb must be positive, got {self.noise_floor_lsb}")
        if self.sharp_px < 1 or self.noise_samples < 16:
            raise ValueError("sharp_px must be at least 1 and noise_samples at least 16")

    @classmethod
    def from_resolution(
        cls,
        wire_width_mm: tuple[float, float],
        mm_per_px: tuple[float, float],
        **overrides: object,
    ) -> FeatureConfig:
        """The config for wires ``wire_width_mm`` (narrowest, widest) seen at ``mm_per_px``
        (finest, coarsest, e.g. from the rig's resolution table) over the measuring range;
        ``sharp_px`` covers the lens's blur on the wire (``_SHARP_MM``) at the coarsest
        resolution, and never less than the default."""
        fine, coarse = sorted(mm_per_px)
        width = (wire_width_mm[0] / coarse, wire_width_mm[1] / fine)
        sharp = max(cls.sharp_px, math.ceil(_SHARP_MM / coarse))
        settings: dict[str, object] = {"wire_width_px": width, "sharp_px": sharp, **overrides}
        return cls(**settings)  # type: ignore[arg-type]

    @property
    def background(self) -> float:
        """Width of each side's background window [px]."""
        return float(self.background_px or 2.0 * self.wire_width_px[1])

    @property
    def min_width(self) -> float:
        """Narrowest candidate kept [px]."""
        return self.width_tolerance[0] * self.wire_width_px[0]

    @property
    def max_width(self) -> float:
        """Widest candidate kept [px]."""
        return self.width_tolerance[1] * self.wire_width_px[1]


@dataclass(frozen=True)
class LineFeatures:
    """Candidates found in a block of one camera's lines, flattened: every field has shape (m,).

    Candidates are ordered by scan, then by position along the line.

    Attributes
    ----------
    scan : int64
        Row of the candidate in the block (0..n-1).
    centre_px : float64
        The point to triangulate [px]: the wear face's centre (the contact point) when a face
        was found, else the wire centre ``wire_centre_px``.
    wire_centre_px : float64
        Middle of the wire's boundaries [px]. For a round wire this images (to first order)
        the wire's axis, a radius above the contact point.
    left_px, right_px : float64
        Wire boundaries (silhouette) [px], sub-pixel. At night the round sides of a wire are
        dark near the silhouette: the boundaries are then those of its lit part.
    face_left_px, face_right_px : float64
        Worn face edges [px], sub-pixel; NaN when no face was found.
    face_width_px : float64
        ``face_right_px - face_left_px`` [px]; NaN when no face was found. A new wire has no
        face; faces narrower than the optical blur (about 2.5-3 px) are not resolved and read
        about 2.4-3.3 px wide.
    face_centre_px : float64
        Middle of the face edges [px]; NaN when no face was found.
    contrast : float64
        Peak ``|signal - background|`` over full scale [-].
    polarity : int8
        +1 bright object on a darker background, -1 dark silhouette on a brighter one; 0
        when it is as much brighter as darker than the sky in places (an unworn wire by day
        behind the band-pass filter: its lit bottom between dark sides).
    outline_side : int8
        Which boundary alone is the wire's outline, for a wire without a face: -1 the left
        (darker than the sky inside it: the wire's dark side against the sky) where the
        right is the end of its lit part (brighter than the sky inside it), +1 the right, 0
        both or neither (the middle of the boundaries is the axis or the lit part's middle).
        An unworn wire by day behind the band-pass filter, lit from one side, shows one
        dark side clearly and the other about as bright as the sky.
    """

    scan: NDArray[np.int64]
    centre_px: FloatArray
    wire_centre_px: FloatArray
    left_px: FloatArray
    right_px: FloatArray
    face_left_px: FloatArray
    face_right_px: FloatArray
    face_width_px: FloatArray
    face_centre_px: FloatArray
    contrast: FloatArray
    polarity: NDArray[np.int8]
    outline_side: NDArray[np.int8]

    def __len__(self) -> int:
        return int(self.scan.shape[0])

    @property
    def has_face(self) -> NDArray[np.bool_]:
        """Whether a wear face was found, per candidate."""
        return np.isfinite(self.face_width_px)

    @classmethod
    def empty(cls) -> LineFeatures:
        """No candidates."""
        values: dict[str, np.ndarray] = {}
        for f in fields(cls):
            dtype = {"scan": np.int64, "polarity": np.int8, "outline_side": np.int8}.get(
                f.name, np.float64
            )
            values[f.name] = np.zeros(0, dtype=dtype)
        return cls(**values)

    def select(self, keep: NDArray[np.bool_]) -> LineFeatures:
        """The candidates where ``keep`` (bool, shape (m,)) is true, in order."""
        return type(self)(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})

    @classmethod
    def concatenate(cls, parts: list[LineFeatures], offsets: list[int]) -> LineFeatures:
        """Join the features of consecutive blocks; ``offsets`` are added to each one's scans."""
        if not parts:
            return cls.empty()
        values = {}
        for f in fields(cls):
            arrays = [getattr(p, f.name) for p in parts]
            if f.name == "scan":
                arrays = [a + o for a, o in zip(arrays, offsets, strict=True)]
            values[f.name] = np.concatenate(arrays)
        return cls(**values)


def extract_features(
    lines: NDArray[np.uint8] | NDArray[np.uint16],
    bit_depth: int,
    *,
    config: FeatureConfig = FeatureConfig(),
) -> LineFeatures:
    """Wire candidates with boundaries and wear faces in a block of one camera's lines.

    Parameters
    ----------
    lines : ndarray (n, W) of uint8 or uint16
        Consecutive scans of one camera (FORMATS.md ``/cameras/{name}/lines``).
    bit_depth : int
        Bits per pixel (1-16); full scale is ``2**bit_depth - 1``.
    config : FeatureConfig

    Returns
    -------
    LineFeatures
        Every candidate of every line, flattened (module docstring).
    """
    data = np.asarray(lines)
    if data.ndim != 2:
        raise ValueError(f"lines must be 2-D (scans, pixels), got shape {data.shape}")
    if data.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"lines must be uint8 or uint16, got {data.dtype}")
    if not 1 <= bit_depth <= 8 * data.dtype.itemsize:
        raise ValueError(f"bit_depth {bit_depth} does not fit {data.dtype}")
    n, width = data.shape
    if n == 0 or width < 4 * config.bin_px or width < 16:
        return LineFeatures.empty()
    data = np.ascontiguousarray(data)
    rows = max(1, _GROUP_BYTES // (width * data.dtype.itemsize))
    parts = []
    offsets = []
    for first in range(0, n, rows):
        parts.append(_extract_group(data[first : first + rows], bit_depth, config))
        offsets.append(first)
    if len(parts) == 1:
        return parts[0]
    return LineFeatures.concatenate(parts, offsets)


# -- the coarse pass: noise, bins, background, detection ------------------------------------


def noise_sigma(data: np.ndarray, samples: int, floor: float) -> NDArray[np.float32]:
    """Pixel noise [DN] ``(r,)`` of each line: MAD of the first difference (grouped median)."""
    width = data.shape[1]
    step = max(1, (width - 1) // samples)
    count = min(samples, (width - 2) // step + 1)
    wide = np.int16 if data.dtype == np.uint8 else np.int32
    diff: NDArray[np.signedinteger[Any]] = data[:, 1 : 1 + count * step : step].astype(wide)
    diff -= data[:, 0 : count * step : step]
    np.abs(diff, out=diff)
    diff.sort(axis=1)
    median = diff[:, count // 2 : count // 2 + 1]
    # grouped median of integers: interpolate within the median's class, the run of the
    # sorted row that holds the median's value (``below`` samples before it, ``at`` in it)
    below = np.argmax(diff >= median, axis=1)
    past = np.where(diff[:, -1] > median[:, 0], np.argmax(diff > median, axis=1), count)
    at = past - below
    m = median[:, 0].astype(np.float32)
    lower = np.where(m < 0.5, np.float32(0.0), m - np.float32(0.5))
    width_class = np.where(m < 0.5, np.float32(0.5), np.float32(1.0))
    grouped = lower + width_class * (np.float32(0.5 * count) - below) / at
    sigma = np.float32(1.4826 / math.sqrt(2.0)) * grouped
    floored: NDArray[np.float32] = np.maximum(sigma, np.float32(floor))
    return floored


_LOW_BYTES = np.uint64(0x00FF00FF00FF00FF)
_LOW_WORDS = np.uint64(0x0000FFFF0000FFFF)
_ADD_WORDS = np.uint64(0x0001000100010001)
_ADD_DWORDS = np.uint64(0x0000000100000001)


def _bin_sums(data: np.ndarray, b: int) -> NDArray[np.float32]:
    """Sums ``(r, W // b)`` of consecutive ``b`` pixels of each line (the tail is dropped).

    Lines whose bytes pack whole bins into 64-bit words are summed in the words (SIMD
    within a register: no per-pixel conversion), a few rows at a time so that the words
    stay in cache; the total lands in the word's top lane, read through a narrower view.
    Others by a float reduction.
    """
    r, width = data.shape
    nb = width // b
    per_word = 8 // data.dtype.itemsize
    if not (width % per_word == 0 and b % per_word == 0 and data.flags.c_contiguous):
        x = data[:, : nb * b].astype(np.float32)
        summed: NDArray[np.float32] = x.reshape(r, nb, b).sum(axis=2)
        return summed
    out = np.empty((r, nb), dtype=np.float32)
    k = b // per_word
    rows = max(1, _CACHE_BYTES // (width * data.dtype.itemsize))
    high = np.empty((rows, width // per_word), dtype=np.uint64)
    shift = 8 * data.dtype.itemsize
    lanes = 4 if per_word == 8 else 2  # the lanes of the word's total: 16 or 32 bits
    top = lanes - 1 if sys.byteorder == "little" else 0
    mask, add = (_LOW_BYTES, _ADD_WORDS) if per_word == 8 else (_LOW_WORDS, _ADD_DWORDS)
    for first in range(0, r, rows):
        words = data[first : first + rows].view(np.uint64)  # (rows, width / per_word)
        pairs = high[: words.shape[0]]
        np.right_shift(words, np.uint64(shift), out=pairs)
        pairs &= mask  # the odd pixels
        pairs *= np.uint64((1 << shift) - 1)
        np.subtract(words, pairs, out=pairs)  # four 16-bit (two 32-bit) sums of pixel pairs
        pairs *= add  # their total in the top lane: the sum of 8 (4) pixels
        total = pairs.view(np.uint16 if per_word == 8 else np.uint32)[:, top::lanes]
        total = total[:, : nb * k]
        part = out[first : first + rows]
        part[:] = total[:, 0::k]
        for i in range(1, k):
            part += total[:, i::k]
    return out


def _window_sums(values: NDArray[np.float32], guard: int, train: int) -> tuple[np.ndarray, ...]:
    """Sums ``(r, n)`` of ``values`` over ``train`` cells on either side of each cell,
    beyond ``guard`` cells; the line's ends are extended by their last cell."""
    r, n = values.shape
    pad = guard + train
    w = n + 2 * pad
    padded = np.empty((r, w), dtype=values.dtype)
    padded[:, pad : pad + n] = values
    padded[:, :pad] = values[:, :1]
    padded[:, pad + n :] = values[:, -1:]
    # summed flat (one long loop, not one per line): total[:, i] sums padded[:, i : i + train]
    # for i < w - train + 1, which is all that is read; cell j sits at padded[:, pad + j]
    flat = padded.ravel()
    span = r * w - train + 1
    total = np.empty(r * w, dtype=values.dtype)
    if train > 1:
        np.add(flat[:span], flat[1 : 1 + span], out=total[:span])
    else:
        total[:span] = flat[:span]
    for k in range(2, train):
        total[:span] += flat[k : k + span]
    total = total.reshape(r, w)
    return total[:, guard : guard + n], total[:, pad + guard + 1 : pad + guard + 1 + n]


def _detect(
    sums: NDArray[np.float32], sigma: NDArray[np.float32], cfg: FeatureConfig
) -> NDArray[np.int8]:
    """Bins ``(r, nb)`` that stand out from the background on both sides (module docstring):
    +1 brighter, -1 darker, 0 not.

    The bins are grouped in cells of ``_SUPER``. A bright object must stand out from the
    mean of the cells' brightest bins, a dark one from the mean of their darkest: another
    object in the background windows then makes detection harder, never easier, so the sky
    between two wires is not taken for an object. Next to a step between neighbouring bins
    half of ``detect_rel`` will do (a wire's silhouette whose mean contrast is low: an
    unworn wire by day behind the band-pass filter); the sky's texture changes far less
    over one bin. Cells whose extreme bins pass the weaker test are then looked at bin by
    bin.
    """
    r, nb = sums.shape
    b = cfg.bin_px
    ns = -(-nb // _SUPER)
    padded = sums
    if ns * _SUPER != nb:
        padded = np.pad(sums, ((0, 0), (0, ns * _SUPER - nb)), mode="edge")
    # flat: no per-line loop in the ufuncs; the sums are non-negative, so that their bits
    # order as they do (integer extremes of strided columns are twice as fast)
    by_cell = padded.view(np.int32).reshape(r * ns, _SUPER)
    lowest = np.minimum(by_cell[:, 0], by_cell[:, 1])
    highest = np.maximum(by_cell[:, 0], by_cell[:, 1])
    for i in range(2, _SUPER):
        np.minimum(lowest, by_cell[:, i], out=lowest)
        np.maximum(highest, by_cell[:, i], out=highest)
    lowest = lowest.view(np.float32).reshape(r, ns)
    highest = highest.view(np.float32).reshape(r, ns)
    cell_px = _SUPER * b
    guard = max(1, math.ceil((cfg.max_width + b) / cell_px))
    train = max(1, round(cfg.background / cell_px))
    noise = np.empty((r, ns), dtype=np.float32)
    noise[:] = (np.float32(cfg.detect_k * math.sqrt(b)) * sigma).astype(np.float32)[:, None]
    rel = np.float32(cfg.detect_rel / train)  # window sums: train cells
    left, right = _window_sums(highest, guard, train)
    bright = np.maximum(left, right)
    left, right = _window_sums(lowest, guard, train)
    dark = np.minimum(left, right)
    bright_t = np.maximum(noise, rel * bright)
    dark_t = np.maximum(noise, rel * dark)
    bright *= np.float32(1.0 / train)
    dark *= np.float32(1.0 / train)
    weak_bright = bright + np.maximum(noise, np.float32(0.5) * bright_t)
    weak_dark = dark - np.maximum(noise, np.float32(0.5) * dark_t)
    hit = np.flatnonzero((highest > weak_bright) | (lowest < weak_dark))
    detected = np.zeros((r, nb), dtype=np.int8)
    if hit.shape[0] == 0:
        return detected
    row = hit // ns
    cell = hit - row * ns
    # the cell's bins and one more on each side, for the steps between them, transposed
    # ``(_SUPER + 2, k)`` so that the ufuncs run along the hits
    bins = np.clip(cell * _SUPER + np.arange(-1, _SUPER + 1)[:, None], 0, nb - 1)
    near = sums.ravel()[row * nb + bins]
    cells = near[1:-1]
    # the strong thresholds, needed at the hits only
    strong_bright = bright.ravel()[hit] + bright_t.ravel()[hit]
    strong_dark = dark.ravel()[hit] - dark_t.ravel()[hit]
    weak_bright = weak_bright.ravel()[hit]
    strong = (cells > strong_bright) | (cells < strong_dark)
    brighter = cells > weak_bright
    weak = brighter | (cells < weak_dark.ravel()[hit])
    step = np.abs(near[1:] - near[:-1])
    level = np.maximum(near[1:], near[:-1])
    level *= np.float32(cfg.edge_rel)
    np.maximum(level, np.float32(math.sqrt(2.0)) * noise.ravel()[hit], out=level)
    edge = step > level  # (_SUPER + 1, k): edge[i] lies before bin i of the cell
    weak &= edge[:-1] | edge[1:]
    strong |= weak
    # +1 for a bright bin, -1 for a dark one (0: not detected)
    sign = np.where(brighter, 1, -1).astype(np.int8) * strong
    inside = bins[1:-1] == cell * _SUPER + np.arange(_SUPER)[:, None]  # not past the end
    where = row * nb + bins[1:-1]
    detected.ravel()[where[inside]] = sign[inside]
    return detected


def _runs(mask: NDArray[np.bool_]) -> tuple[IndexArray, IndexArray, IndexArray]:
    """Runs of True along axis 1: ``(row, start, stop)`` in raster order."""
    r, c = mask.shape
    padded = np.empty((r, c + 1), dtype=np.int8)
    padded[:, 0] = 0
    padded[:, 1:] = mask
    flat = padded.ravel()
    change = np.flatnonzero(flat[1:] != flat[:-1])
    starts = change[0::2]
    stops = change[1::2]
    row = starts // (c + 1)
    base = row * (c + 1)
    return row, starts - base, stops - base


# -- the fine pass: boundaries and faces on windows around the candidates -------------------


def _float32_below(x: FloatArray) -> NDArray[np.float32]:
    """The largest float32 at or below each non-negative value of ``x``: for float32 ``a``,
    ``a > x`` exactly when ``a > _float32_below(x)`` (a float32 comparison is faster). A
    positive float32 rounded up steps down by one in its bits."""
    near = x.astype(np.float32)
    return (near.view(np.int32) - (near > x)).view(np.float32)


def _take(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[i, idx[i]]`` for a 2-D C-contiguous ``a`` and an index per row."""
    taken: np.ndarray = a.ravel()[np.arange(a.shape[0]) * a.shape[1] + idx]
    return taken


def _rows(a: np.ndarray, first: np.ndarray, count: int) -> np.ndarray:
    """``a[i, first[i] : first[i] + count]`` stacked ``(m, count)`` for a 2-D ``a`` (the
    slices must lie within the rows)."""
    rows: np.ndarray = sliding_window_view(a, count, axis=1)[np.arange(a.shape[0]), first]
    return rows


def _windows(data: np.ndarray, row: IndexArray, first: IndexArray, count: int) -> np.ndarray:
    """Pixels ``first .. first + count - 1`` of lines ``row`` ``(m, count)``; pixels past a
    line's ends repeat its end pixel."""
    width = data.shape[1]
    if width < count:
        cols = np.clip(first[:, None] + np.arange(count), 0, width - 1)
        gathered: np.ndarray = data[row[:, None], cols]
        return gathered
    at = np.clip(first, 0, width - count)
    out: np.ndarray = sliding_window_view(data, count, axis=1)[row, at]
    ends = np.flatnonzero(at != first)
    if ends.shape[0]:
        cols = np.clip(first[ends, None] + np.arange(count), 0, width - 1)
        out[ends] = data[row[ends, None], cols]
    return out


def _extremum_offset(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Sub-pixel offset of a peak ``b`` from its neighbours ``a``, ``c``: the vertex of the
    parabola through their logarithms (exact for a Gaussian) when all are positive, else
    through the values; clipped to +-0.5."""
    with np.errstate(divide="ignore", invalid="ignore"):
        positive = (a > 0) & (b > 0) & (c > 0)
        la = np.log(np.where(positive, a, 1.0))
        lb = np.log(np.where(positive, b, 1.0))
        lc = np.log(np.where(positive, c, 1.0))
        den_log = la - 2.0 * lb + lc
        den = a - 2.0 * b + c
        use_log = positive & (den_log < 0)
        off = np.where(
            use_log,
            0.5 * (la - lc) / np.where(use_log, den_log, -1.0),
            0.5 * (a - c) / np.where(den < 0, den, -1.0),
        )
    return np.clip(off, -0.5, 0.5)


def _edge(
    d: np.ndarray, rows: np.ndarray, k: np.ndarray, sign: np.ndarray, window: int = 0
) -> FloatArray:
    """Sub-pixel positions (window coordinates) of the first-difference extrema ``d[rows, k]``:
    ``sign`` +1 for rising edges, -1 for falling ones. The vertex of the log-parabola through
    the three first differences around each extremum; with ``window`` > 0 then, from it, the
    centroid within ``window`` px of the squared excess of the first difference over a
    quarter of the extremum (step 5): the excess leaves out the noise and the shading slopes
    beside the edge, its square is smooth where it starts (its samples locate a symmetric
    profile at any phase), the window's end samples count by their part inside it."""
    width = d.shape[1]
    k = np.clip(k, 1, width - 2)
    at = rows * width + k + np.arange(-1, 2)[:, None]
    three = d.ravel()[at].astype(np.float64)  # (3, m)
    three *= sign
    position: FloatArray = k + 0.5 + _extremum_offset(three[0], three[1], three[2])
    if window <= 0:
        return position
    steps = np.arange(-window - 1, window + 2)[None, :]
    flat = d.ravel()
    signs = np.broadcast_to(np.asarray(sign, dtype=np.float64), k.shape)[:, None]
    floor = 0.25 * three[1][:, None]
    for _ in range(_CENTROID_ITERATIONS):
        j = np.floor(position - 0.5).astype(np.intp)[:, None] + steps
        x = j + 0.5  # where each first difference sits
        inside = np.clip(window + 0.5 - np.abs(x - position[:, None]), 0.0, 1.0)
        values = flat[rows[:, None] * width + np.clip(j, 0, width - 1)] * signs
        mass = np.maximum(values - floor, 0.0) ** 2 * inside
        total = mass.sum(axis=1)
        position = np.where(
            total > 0, (mass * x).sum(axis=1) / np.where(total > 0, total, 1.0), position
        )
    return position


def _sharp(
    d: np.ndarray, rows: np.ndarray, k: np.ndarray, sign: np.ndarray, t: np.ndarray, reach: int
) -> np.ndarray:
    """Whether the first-difference extrema ``d[rows, k]`` are significant, sharp edges."""
    width = d.shape[1]
    flat = d.ravel()
    at = rows * width
    peak = flat[at + k] * sign
    before = flat[at + np.clip(k - reach, 0, width - 1)] * sign
    after = flat[at + np.clip(k + reach, 0, width - 1)] * sign
    sharp: np.ndarray = (peak > t) & (np.maximum(before, after) < (1.0 - _PROMINENCE) * peak)
    return sharp


def _boundary(dev: np.ndarray, k0: np.ndarray, direction: int, rise: int = _EDGE_PX) -> FloatArray:
    """Sub-pixel boundaries from transposed sub-windows ``dev`` ``(count, m)`` of absolute
    deviations: where ``dev`` crosses half of its level over the ``rise`` pixels inside
    the outermost significant pixel ``k0`` ``(m,)``; ``direction`` +1 for a left boundary
    (the object lies at higher indices), -1 for a right one. Sub-window coordinates."""
    count, m = dev.shape
    # pixels k0 - direction (outside), k0, ..., k0 + rise * direction (inside)
    first = np.clip(k0 - 1 if direction > 0 else k0 - rise, 0, count - rise - 2)
    steps = np.arange(rise + 2)[:, None]
    seg = dev.ravel()[(first[None, :] + steps) * m + np.arange(m)]  # (rise + 2, m)
    if direction < 0:
        seg = seg[::-1]
    level = 0.5 * seg[1:].max(axis=0)
    # the first pixel from k0 inward at or above the level; the crossing lies before it
    weight = np.arange(rise + 1, 0, -1)[:, None]
    reach = rise + 2 - ((seg[1:] >= level) * weight).max(axis=0)
    cols = np.arange(m)
    inside = seg[reach, cols]
    outside = seg[reach - 1, cols]
    frac = np.clip((level - outside) / np.maximum(inside - outside, 1e-6), 0.0, 1.0)
    boundary: FloatArray = (
        first + reach - 1 + frac if direction > 0 else first + rise + 1 - (reach - 1) - frac
    )
    return boundary


def _candidates(
    detected: NDArray[np.int8],
    data: np.ndarray,
    sums: NDArray[np.float32],
    sigma: NDArray[np.float32],
    cfg: FeatureConfig,
) -> tuple[IndexArray, IndexArray, IndexArray, IndexArray, IndexArray]:
    """Candidate runs of bins ``(row, start, stop)`` and the limits of the sky beside them
    ``(gap_l, gap_r)`` [px]: a bin clear of the neighbouring runs (if any)."""
    b = cfg.bin_px
    row, start, stop = _runs(detected != 0)
    if row.shape[0] == 0:
        return row, start, stop, start, stop
    # one candidate: runs of a row that end and begin in opposite polarity within a wire's
    # width (by day behind the filter: a bright face or lit bottom and its dark sides, the
    # zero crossing between them undetected, over several bins on an unworn wire's shading)
    flat = detected.ravel()
    width = detected.shape[1]
    end_sign = flat[row * width + stop - 1]
    start_sign = flat[row * width + start]
    same_row = row[1:] == row[:-1]
    new = np.ones(row.shape[0], dtype=bool)
    widest = cfg.wire_width_px[1] + 2 * b  # [px]
    one_bin_apart = start[1:] - stop[:-1] <= 1
    apart = (stop[1:] - start[:-1]) * b > widest if cfg.outlines else ~one_bin_apart
    new[1:] = ~same_row | apart | (end_sign[:-1] == start_sign[1:])
    if cfg.outlines:
        # runs each within a wire's width of the next may chain wider than a wire (two wires
        # side by side at a turnout's crossing): there, only runs one bin apart join
        first, last = _groups(new)
        wide = (stop[last] - start[first]) * b > widest
        new[1:] |= wide[np.cumsum(new)[1:] - 1] & ~one_bin_apart
    # one candidate too: a dark silhouette split at its worn face (white daylight: the face
    # may be almost as bright as the sky, so that it is not detected)
    joined = _dark_joins(detected, data, sums, sigma, cfg, row, start, stop, end_sign, start_sign)
    if joined is not None:
        new[1:] &= ~joined
    first, last = _groups(new)
    row, start, stop = row[first], start[first], stop[last]
    start, stop = _dark_faces(detected, sums, sigma, cfg, row, start, stop)
    start, stop = _extents(sums, sigma, cfg, row, start, stop)
    # the sky beside a candidate is measured clear of its neighbours' runs by a bin
    same = row[1:] == row[:-1]
    far = 1 << 30
    gap_l = np.concatenate(([-far], np.where(same, (stop[:-1] + 1) * b, -far)))
    gap_r = np.concatenate((np.where(same, (start[1:] - 1) * b, far), [far]))
    keep = (stop - start) * b <= cfg.max_width + 2 * b
    return row[keep], start[keep], stop[keep], gap_l[keep], gap_r[keep]


def _groups(new: NDArray[np.bool_]) -> tuple[IndexArray, IndexArray]:
    """The first and last run of each group of runs, ``(g,)`` each; a group begins at each
    run where ``new`` ``(m,)`` is true (``new[0]`` is)."""
    first = np.flatnonzero(new)
    return first, np.append(first[1:] - 1, new.shape[0] - 1)


def _extents(
    sums: NDArray[np.float32],
    sigma: NDArray[np.float32],
    cfg: FeatureConfig,
    row: IndexArray,
    start: IndexArray,
    stop: IndexArray,
) -> tuple[IndexArray, IndexArray]:
    """The candidates ``[start, stop)`` [bins] of lines ``row`` ``(m,)`` extended to where the
    sky begins beside them.

    Detection compares a bin with the background a wire's width away, whose texture may
    differ by ``detect_rel``: parts of a wire whose mean contrast over a bin is low (the dark
    side of an unworn wire by day behind the band-pass filter, a few pixels of a few DN beside
    its lit bottom, and that lit bottom itself) may stay undetected, and step 3 would then
    measure the sky inside the wire and lose its boundary. The wire ends at the nearest bin
    (within the widest wire, and half-way to a neighbouring run) that differs from the sky
    just beyond it, the mean of the next two bins, where that sky is flat (the two agree) and
    agrees with the sky beyond the run's other end (not a neighbouring object): each within
    ``detect_k`` noise deviations or the sky's texture (half ``detect_rel`` between
    neighbouring bins, ``detect_rel`` pro rata over ``background`` across the wire).
    """
    b = cfg.bin_px
    nb = sums.shape[1]
    reach = int(cfg.wire_width_px[1] // b)
    same = row[1:] == row[:-1]
    half_gap = (start[1:] - stop[:-1] - 1) // 2
    room_r = np.append(np.where(same, half_gap, reach), reach)
    room_l = np.concatenate(([reach], np.where(same, half_gap, reach)))
    noise = (sigma[row] * np.float32(cfg.detect_k * math.sqrt(1.5 * b))).astype(np.float32)
    flat = sums.ravel()
    base = row * nb
    rel = np.float32(0.5 * cfg.detect_rel)
    across_rel = np.float32(b * cfg.detect_rel / cfg.background)
    steps = np.arange(1, reach + 3)[:, None]

    def extension(
        out: int, sel: IndexArray, first: IndexArray, far: IndexArray, room: IndexArray
    ) -> IndexArray:
        """Bins ``(len(sel),)`` to add to candidates ``sel`` beyond their bin ``first`` in
        direction ``out``, at most ``room``; ``far`` is the first bin beyond their other end."""
        pos = first + out * steps  # (reach + 2, k): bin ``first + out * e`` at row e - 1
        strip = flat[base[sel] + np.clip(pos, 0, nb - 1)]
        found = np.zeros(sel.shape[0], dtype=np.intp)
        # a bin differs from the sky beyond it by more than the noise only where the bins
        # beyond the run are not all within the noise of each other (the sky, mostly)
        live = np.flatnonzero(strip.max(axis=0) - strip.min(axis=0) > noise[sel])
        if live.shape[0] == 0:
            return found
        at = base[sel[live]]
        strip, first, far, room = strip[:, live], first[live], far[live], room[live]
        near_noise = noise[sel[live]]
        other = flat[at + np.clip(far, 0, nb - 1)] + flat[at + np.clip(far - out, 0, nb - 1)]
        other *= np.float32(0.5)
        # the two bins beyond the last one added stay on the line
        room = np.minimum(room, nb - 3 - first if out > 0 else first - 2)
        one, two = strip[1:-1], strip[2:]  # the sky beyond each candidate end
        sky = one + two
        sky *= np.float32(0.5)
        level = np.maximum(near_noise, rel * sky)
        ends = np.abs(strip[:-2] - sky) > level
        ends &= np.abs(one - two) <= level
        distance = (np.abs(first - far) + 2).astype(np.float32) + steps[:-2].astype(np.float32)
        across = distance * across_rel
        across *= sky
        sky -= other
        ends &= np.abs(sky) <= np.maximum(near_noise, across)
        ends &= steps[:-2] <= room
        nearest = np.argmax(ends, axis=0)
        found[live] = np.where(ends[nearest, np.arange(live.shape[0])], nearest + 1, 0)
        return found

    # each side against the sky beyond the other end, once that end is extended (a run may
    # hold the middle of a wire only): right, left, and right again where it was not extended;
    # no further than half-way to a neighbour, no wider than the widest wire
    every = np.arange(row.shape[0])
    right = extension(1, every, stop - 1, start - 1, np.minimum(room_r, reach - (stop - start)))
    stop = stop + right
    left = extension(-1, every, start, stop, np.minimum(room_l, reach - (stop - start)))
    start = start - left
    again = np.flatnonzero((right == 0) & (left > 0))
    if again.shape[0]:
        room = np.minimum(room_r[again], reach - (stop - start)[again])
        stop[again] += extension(1, again, stop[again] - 1, start[again] - 1, room)
    return start, stop


def _dark_faces(
    detected: NDArray[np.int8],
    sums: NDArray[np.float32],
    sigma: NDArray[np.float32],
    cfg: FeatureConfig,
    row: IndexArray,
    start: IndexArray,
    stop: IndexArray,
) -> tuple[IndexArray, IndexArray]:
    """Candidate runs ``[start, stop)`` [bins] extended over an undetected worn face beside a
    dark run (white daylight near the wear limit).

    When a face is almost as wide as its wire, a camera that looks at the wire obliquely sees
    the face reach the silhouette on one side: the wire's only dark part is its side beyond
    the face's other edge, and the face, lit from below, may be too little darker than the
    darker of the two background windows (a sky that brightens toward the sun) to be
    detected. The run is then the wire's dark side alone. A face is there when the bins after
    the run (before it, mirrored) step up to the sky within the widest wire, two bins out at
    least (a wire covers two whole bins at least; one bin is the partial bin at the end of a
    dark wire), darker than the sky just beyond that step by ``detect_rel`` of it (the test
    that detects any object, against the sky beside it rather than the darker background
    window) and the noise, and lit: brighter than the run's darkest bin (the wire's side) by a
    step of ``edge_rel`` of the sky (a neighbour's dark silhouette beside the wire is not);
    the run takes them.
    """
    b = cfg.bin_px
    nb = sums.shape[1]
    widest = cfg.wire_width_px[1] + 2 * b
    room = np.floor(widest / b).astype(np.intp) - (stop - start)  # bins a face may take
    flat = detected.ravel()
    base = row * nb
    dark_end = (flat[base + stop - 1] < 0) & (room > 1)
    dark_start = (flat[base + start] < 0) & (room > 1)
    # at once, most of them: a face's second bin is darker than the sky beyond its room (the
    # second bin beside a dark wire's run is the sky)
    level = sums.ravel()
    darker = np.float32(1.0 - cfg.edge_rel)
    far = darker * level[base + np.minimum(stop + room + 2, nb - 1)]
    dark_end &= level[base + np.minimum(stop + 1, nb - 1)] < far
    far = darker * level[base + np.maximum(start - room - 3, 0)]
    dark_start &= level[base + np.maximum(start - 2, 0)] < far
    if not (np.any(dark_end) or np.any(dark_start)):
        return start, stop
    # both sides at once: the bins from the run outward, the right sides then the left ones
    pick = np.concatenate([np.flatnonzero(dark_end), np.flatnonzero(dark_start)])
    out = np.concatenate(
        [
            np.ones(np.count_nonzero(dark_end), np.intp),
            -np.ones(np.count_nonzero(dark_start), np.intp),
        ]
    )
    reach = int(room[pick].max())
    k = np.arange(reach + 3)
    at = np.where(out > 0, stop[pick], start[pick] - 1)[:, None] + out[:, None] * k
    inside = (at >= 0) & (at < nb)
    at = np.clip(at, 0, nb - 1)
    r = row[pick][:, None]
    vals = sums[r, at] * np.float32(1.0 / b)
    taken = (detected[r, at] != 0) | ~inside
    # the step up to the sky: the largest rise over the face's room, two bins out at least
    # (one bin between a dark run and the sky is its edge's partial bin, not a face)
    rise = vals[:, 1:] - vals[:, :-1]
    within = (k[None, :-1] >= 1) & (k[None, :-1] < room[pick][:, None])
    rise = np.where(within, rise, -np.inf)
    e = np.argmax(rise, axis=1)
    rows = np.arange(pick.shape[0])
    sky = np.maximum(
        vals[rows, np.minimum(e + 2, reach + 2)], vals[rows, np.minimum(e + 3, reach + 2)]
    )
    face_bins = k[None, :] <= e[:, None]
    # its level: the median of its bins (those at its ends may hold the side or the sky)
    ordered = np.sort(np.where(face_bins, vals, np.inf), axis=1)
    face = 0.5 * (ordered[rows, e // 2] + ordered[rows, (e + 1) // 2])
    # the run's darkest bin: the wire's dark side (a run here is narrower than a wire)
    cols = start[pick][:, None] + np.arange(int((stop - start)[pick].max()))
    own = np.where(cols < stop[pick][:, None], sums[r, np.minimum(cols, nb - 1)], np.inf)
    side = own.min(axis=1) * np.float32(1.0 / b)
    lit = np.where(face_bins, vals, np.inf).min(axis=1) - side
    free = ~np.any(taken & (k[None, :] <= e[:, None] + 3), axis=1)  # no other run in it
    noise = cfg.detect_k * sigma[row[pick]] * math.sqrt(2.0 / b)
    step = np.maximum(cfg.edge_rel * sky, noise)
    dark = sky - face > np.maximum(cfg.detect_rel * sky, noise)
    ok = free & (rise[rows, e] > step) & (lit > step) & dark
    start, stop = start.copy(), stop.copy()
    right = ok & (out > 0)
    left = ok & (out < 0)
    stop[pick[right]] += e[right] + 1
    start[pick[left]] -= e[left] + 1
    return start, stop


def _dark_joins(
    detected: NDArray[np.int8],
    data: np.ndarray,
    sums: NDArray[np.float32],
    sigma: NDArray[np.float32],
    cfg: FeatureConfig,
    row: IndexArray,
    start: IndexArray,
    stop: IndexArray,
    end_sign: np.ndarray,
    start_sign: np.ndarray,
) -> NDArray[np.bool_] | None:
    """Which consecutive runs (``i`` with ``i + 1``) are one dark silhouette split at its worn
    face or its lit bottom; None when none are.

    Two dark runs are one wire when the bright run between them is narrower than the widest
    wire, together they span no more than the widest wire (and the two bins its ends may
    reach into), and that bright run is not the sky: a face is a surface of the wire lit by
    what lies below it (the ground, the vehicle), darker than the sky, and an unworn wire's
    bottom lit by the vehicle's strobe behind the band-pass filter is brighter than the dim
    sky (by less than ``detect_rel`` over a bin, its dark sides beside it), while the sky
    between two separate objects (two messengers side by side) is the sky's level. The sky is
    the brightest of the two bins on either side beyond a bin clear of the pair that no run
    holds (``detected``; all four where every one is held): a dark neighbour would make the
    gap look like a face, and so would a bright one, a contact wire's lit face or bottom
    beside its messenger behind the filter; the gap's level is its brightest three-pixel mean
    (clear of the blurred dark sides). Sky texture allowed: ``detect_rel`` of the sky's level over a
    background window, pro rata over the distance from the gap to the sky measured. A group
    of such runs wider than a wire is not joined.
    """
    b = cfg.bin_px
    nb = sums.shape[1]
    widest = cfg.wire_width_px[1] + 2 * b
    gap_bins = start[1:] - stop[:-1]
    pair = np.flatnonzero(
        (row[1:] == row[:-1])
        & (end_sign[:-1] < 0)
        & (start_sign[1:] < 0)
        & (gap_bins * b < cfg.wire_width_px[1])
        & ((stop[1:] - start[:-1]) * b <= widest)
    )
    if pair.shape[0] == 0:
        return None
    r = row[pair]
    g0 = stop[pair] * b  # the gap's pixels: [g0, g1)
    g1 = start[pair + 1] * b
    span = int((g1 - g0).max())
    cols = g0[:, None] + np.arange(span)
    inside = cols < g1[:, None]
    px = data[r[:, None], np.minimum(cols, data.shape[1] - 1)].astype(np.float32)
    trio = px[:, :-2] + px[:, 1:-1] + px[:, 2:] if span >= 3 else px.sum(axis=1, keepdims=True)
    gap = np.where(inside[:, 2:] if span >= 3 else inside[:, :1], trio, -np.inf).max(axis=1)
    gap *= np.float32(1.0 / 3.0) if span >= 3 else np.float32(1.0 / max(span, 1))
    beside = np.concatenate(
        [start[pair, None] - np.arange(2, 4), stop[pair + 1, None] + np.arange(1, 3)], axis=1
    )
    beside = np.clip(beside, 0, nb - 1)
    clear = detected[r[:, None], beside] == 0
    clear[~clear.any(axis=1)] = True  # no bin clear of every run: all four
    sky = np.where(clear, sums[r[:, None], beside], -np.inf).max(axis=1) * np.float32(1.0 / b)
    middle = 0.5 * (g0 + g1)
    reach = np.maximum(middle - (start[pair] - 2.5) * b, (stop[pair + 1] + 2.5) * b - middle)
    texture = cfg.detect_rel * reach / cfg.background * sky
    noise = cfg.detect_k * sigma[r] * math.sqrt(1.0 / 3.0 + 1.0 / b)
    face = np.abs(sky - gap) > np.maximum(texture, noise)
    pair = pair[face]
    if pair.shape[0] == 0:
        return None
    join = np.zeros(row.shape[0] - 1, dtype=bool)
    join[pair] = True
    # groups of runs joined so: not wider than a wire
    head = np.ones(row.shape[0], dtype=bool)
    head[1:] = ~join
    heads, tails = _groups(head)
    fits = ((stop[tails] - start[heads]) * b <= widest)[np.cumsum(head) - 1]
    joins: NDArray[np.bool_] = join & fits[1:]
    return joins


@dataclass
class _Found:
    """Per-candidate results of the fine pass (window-independent, line coordinates)."""

    row: IndexArray
    start: IndexArray
    left: FloatArray
    right: FloatArray
    face_left: FloatArray
    face_right: FloatArray
    peak_dev: FloatArray
    polarity: NDArray[np.int8]
    outline_side: NDArray[np.int8]

    @classmethod
    def empty(cls) -> _Found:
        ints = np.zeros(0, dtype=np.intp)
        floats = np.zeros(0, dtype=np.float64)
        none = np.zeros(0, np.int8)
        return cls(ints, ints, floats, floats, floats, floats, floats, none, none)


def _fine(
    data: np.ndarray,
    cand: tuple[IndexArray, ...],
    sigma: NDArray[np.float32],
    cfg: FeatureConfig,
    full: float,
) -> _Found:
    """Boundaries and faces of candidates on pixel windows (module docstring, steps 3-6).

    ``cand`` is ``(row, start, stop, gap_l, gap_r)`` of :func:`_candidates`, each ``(m,)``.
    """
    row, start, stop, gap_l, gap_r = cand
    windows = _pixel_windows(data, row, start, stop, sigma, cfg, full)
    sky = _sky(windows, gap_l, gap_r)
    contrast = _contrast(windows, sky, cfg)
    boundaries = _boundaries(windows, sky, contrast, cfg)
    sel = np.flatnonzero(boundaries.ok)
    if sel.shape[0] == 0:
        return _Found.empty()
    wires = _kept_wires(windows, sky, contrast, boundaries, sel, cfg)
    edges = _face_edges(wires, cfg)
    faces = _one_sided_faces(wires, edges, cfg)
    fitted = _near_silhouette_fit(wires, faces, cfg)
    # a wire whose sides are too dark to be seen (at night) is narrow but has its face
    keep = boundaries.wide_enough[sel] | fitted.has_face
    sel = sel[keep]
    has_face = fitted.has_face[keep]
    offset = windows.first_px[sel].astype(np.float64)
    nan = np.float64(np.nan)
    if cfg.outlines:
        outline_side = _outline_sides(windows, sky, boundaries, sel, (gap_l, gap_r), cfg)
        outline_side[has_face] = 0
    else:
        outline_side = np.zeros(sel.shape[0], np.int8)
    return _Found(
        row=row[sel],
        start=start[sel],
        left=fitted.left[keep] + offset,
        right=fitted.right[keep] + offset,
        face_left=np.where(has_face, fitted.face_left[keep] + offset, nan),
        face_right=np.where(has_face, fitted.face_right[keep] + offset, nan),
        peak_dev=contrast.peak_dev[sel] / 4.0,
        polarity=np.where(contrast.mixed[sel], 0, contrast.polarity[sel]).astype(np.int8),
        outline_side=outline_side,
    )


@dataclass(frozen=True)
class _Windows:
    """Pixel windows around ``m`` candidates, as four times the ``[1, 2, 1] / 4`` smoothed line
    (``xs4``), flat: window ``i`` pixel ``j`` at ``i * stride + j``, window pixel ``j`` being
    line pixel ``first_px[i] + j``. A window runs ``margin`` pixels either side of its run,
    ``own`` pixels in all, and is padded with line pixels to the longest."""

    xs4: NDArray[np.float32]  # (m * stride,)
    stride: int
    margin: int
    base: IndexArray  # (m,) each window's first index in xs4: i * stride
    run_px: IndexArray  # (m,) the run's length [px]
    own: IndexArray  # (m,) the window's own length [px]
    first_px: IndexArray  # (m,)
    sigma: NDArray[np.float32]  # (m,) the line's pixel noise [DN]
    s4: NDArray[np.float32]  # (m,) the noise of xs4
    saturated: NDArray[np.bool_]  # (m,) a pixel of the window at full scale


def _pixel_windows(
    data: np.ndarray,
    row: IndexArray,
    start: IndexArray,
    stop: IndexArray,
    sigma: NDArray[np.float32],
    cfg: FeatureConfig,
    full: float,
) -> _Windows:
    """The smoothed pixel windows of the candidate runs ``[start, stop)`` [bins] of lines
    ``row`` ``(m,)``; ``sigma`` is every line's noise ``(r,)``, ``full`` the full scale."""
    b = cfg.bin_px
    m = row.shape[0]
    margin = b + 2 * cfg.sharp_px + _SKY_PX
    run_px = (stop - start) * b
    own = run_px + 2 * margin
    stride = int(own.max()) + 2
    first_px = start * b - margin
    raw = _windows(data, row, first_px - 1, stride).ravel()  # pixel j at i * stride + j + 1
    base = np.arange(m) * stride
    saturated = np.maximum.reduceat(raw, base) >= full
    pixels = raw.astype(np.float32)
    pairs = pixels[:-1] + pixels[1:]
    xs4 = np.empty(m * stride, dtype=np.float32)
    np.add(pairs[:-1], pairs[1:], out=xs4[:-2])  # xs4[i * stride + j]: pixel j, j < own
    xs4[-2:] = 0.0
    s = sigma[row]
    s4 = s * np.float32(4.0 * math.sqrt(6.0 / 16.0))
    return _Windows(xs4, stride, margin, base, run_px, own, first_px, s, s4, saturated)


@dataclass(frozen=True)
class _Sky:
    """The sky beside each of ``m`` candidates: ``_SKY_PX`` pixels from window positions
    ``at_l`` and ``at_r`` on, and the ramp between their means (xs4 units)."""

    at_l: IndexArray  # (m,)
    at_r: IndexArray  # (m,)
    pixels: NDArray[np.float32]  # (_SKY_PX, 2m): the left sides, then the right sides
    level: NDArray[np.float32]  # (2m,) their means
    slope: NDArray[np.float32]  # (m,) the ramp's slope per window pixel
    ramp0: FloatArray  # (m,) the ramp at window pixel 0

    @property
    def left(self) -> NDArray[np.float32]:
        return self.level[: self.slope.shape[0]]

    @property
    def right(self) -> NDArray[np.float32]:
        return self.level[self.slope.shape[0] :]


def _sky(windows: _Windows, gap_l: IndexArray, gap_r: IndexArray) -> _Sky:
    """Step 3's sky on either side: at the window's ends, or clear of a nearer neighbour
    (``gap_l``, ``gap_r`` [line px], ``(m,)``)."""
    w = windows
    margin, own = w.margin, w.own
    at_l = np.clip(gap_l - w.first_px, 0, margin - _SKY_PX)
    at_r = np.clip(gap_r - _SKY_PX - w.first_px, own - margin, own - _SKY_PX)
    quad = np.arange(_SKY_PX)[:, None]
    pixels = w.xs4[quad + np.concatenate([w.base + at_l, w.base + at_r])]  # (_SKY_PX, 2m)
    level = pixels.mean(axis=0)
    m = at_l.shape[0]
    slope = (level[m:] - level[:m]) / (at_r - at_l).astype(np.float32)
    ramp0 = level[:m] - slope * (at_l + np.float32(0.5 * (_SKY_PX - 1)))
    return _Sky(at_l, at_r, pixels, level, slope, ramp0)


@dataclass(frozen=True)
class _Contrast:
    """Each candidate's extreme deviation from the sky over its run, ``(m,)`` each."""

    peak_dev: FloatArray  # signed [xs4 units]: positive brighter than the sky
    polarity: NDArray[np.int8]  # +1 bright, -1 dark
    mixed: NDArray[np.bool_]  # as bright as dark somewhere: the polarity is unknown
    strong: NDArray[np.bool_]  # passes detect_k and detect_rel at pixel level


def _contrast(windows: _Windows, sky: _Sky, cfg: FeatureConfig) -> _Contrast:
    """Step 3's polarity and contrast: the run's peak deviation from the sky's ramp."""
    w = windows
    bounds = np.stack([w.base + w.margin, w.base + w.margin + w.run_px], axis=1).ravel()
    top = np.maximum.reduceat(w.xs4, bounds)[::2]
    bottom = np.minimum.reduceat(w.xs4, bounds)[::2]
    sky_mid = sky.ramp0 + sky.slope * (w.margin + 0.5 * w.run_px)
    bright = top - sky_mid
    dark = sky_mid - bottom
    polarity = np.where(bright >= dark, 1, -1).astype(np.int8)
    # as bright as dark (an unworn wire behind the band-pass filter: a lit bottom between
    # dark sides): the polarity is unknown
    mixed = np.minimum(bright, dark) > _MIXED * np.maximum(bright, dark)
    peak_dev = np.where(bright >= dark, bright, -dark)
    floor = np.maximum(cfg.detect_k * w.s4, cfg.detect_rel * np.maximum(sky.left, sky.right))
    return _Contrast(peak_dev, polarity, mixed, np.abs(peak_dev) > floor)


@dataclass(frozen=True)
class _Boundaries:
    """The wire boundaries of ``m`` candidates [window px, sub-pixel] and which are wires."""

    left: FloatArray  # (m,)
    right: FloatArray  # (m,)
    ok: NDArray[np.bool_]  # (m,) strong, unsaturated, both found, no wider than a wire
    wide_enough: NDArray[np.bool_]  # (m,) at least the narrowest wire wide


def _boundaries(
    windows: _Windows, sky: _Sky, contrast: _Contrast, cfg: FeatureConfig
) -> _Boundaries:
    """Step 3's boundaries, on transposed sub-windows ``(count, 2m)`` running from the sky
    beside each end of the run to two bins inside it (left ends, then right ends reversed):
    where the deviation from the sky's ramp crosses half its level just inside the outermost
    significant pixel."""
    w = windows
    m = w.own.shape[0]
    peak = np.abs(contrast.peak_dev)
    level = np.maximum(cfg.boundary_k * w.s4, cfg.boundary_rel * peak)
    # and above the sky's texture: the largest deviation of each side's sky pixels from the
    # ramp (which runs through their mean): what the ramp does not model beside the wire
    quad = np.arange(_SKY_PX)[:, None]
    off_ramp = sky.pixels - sky.level
    off_ramp -= np.concatenate([sky.slope, sky.slope]) * (quad - np.float32(0.5 * (_SKY_PX - 1)))
    # (more than ``detect_rel`` of the wire's contrast is not the sky's texture but a
    # neighbour's edge reaching into the sky pixels: the level is capped there)
    texture = np.abs(off_ramp).max(axis=0)
    texture *= np.float32(_TEXTURE)
    np.minimum(texture, np.float32(cfg.detect_rel) * np.tile(peak, 2), out=texture)
    level2 = np.maximum(np.concatenate([level, level]), texture)
    count = w.margin + max(2 * cfg.bin_px, _DARK_RISE * cfg.sharp_px + 2)
    k = np.arange(count)[:, None]
    dev = np.empty((count, 2 * m), dtype=np.float32)
    dev[:, :m] = w.xs4.reshape(m, w.stride)[:, :count].T
    dev[:, m:] = w.xs4[(w.base + w.own - 1) - k]
    # the sky's ramp at each pixel, in float64 (as the deviations have always been taken)
    k_px = k.astype(np.float64)
    ramp = np.empty((count, 2 * m))
    ramp[:, :m] = k_px
    np.subtract((w.own - 1).astype(np.float64), k_px, out=ramp[:, m:])  # the pixels, then
    ramp *= np.tile(sky.slope, 2)  # the ramp
    ramp += np.tile(sky.ramp0, 2)
    np.subtract(dev, ramp, out=dev)
    np.abs(dev, out=dev)
    first_k = np.concatenate([sky.at_l + _SKY_PX, w.own - sky.at_r])  # past the sky
    above = dev > _float32_below(level2)
    above &= k >= first_k
    # a significant pixel starts the wire only when the next one is significant too: one
    # pixel of the sky's texture past the level, then the sky again, is not the wire's edge
    above[:-1] &= above[1:]
    weight = (count - k).astype(np.min_scalar_type(count))
    k0 = count - (above * weight).max(axis=0).astype(np.intp)  # the first above (count: none)
    inside = (k0 >= first_k) & (k0 < count)
    start = np.minimum(k0, count - 1)
    # a dark silhouette occludes the sky: its level is its plateau, past a blurred step's
    # whole rise from its first significant pixel (the blur's reach, ``sharp_px``, each side
    # of the edge, and as much again for a blur wider than the one ``sharp_px`` was set for)
    rise = _DARK_RISE * cfg.sharp_px
    dark = np.tile((contrast.polarity < 0) & ~contrast.mixed, 2)
    edge: FloatArray
    if rise > _EDGE_PX and dark.any():
        edge = np.empty(2 * m)
        edge[dark] = _boundary(dev[:, dark], start[dark], +1, rise)
        if not dark.all():
            edge[~dark] = _boundary(dev[:, ~dark], start[~dark], +1)
    else:
        edge = _boundary(dev, start, +1)
    left = edge[:m]
    right = w.own - 1 - edge[m:]
    width = right - left
    ok = contrast.strong & ~w.saturated & inside[:m] & inside[m:]
    ok &= (width <= cfg.max_width) & (width > 0)
    return _Boundaries(left, right, ok, width >= cfg.min_width)


def _outline_sides(
    windows: _Windows,
    sky: _Sky,
    boundaries: _Boundaries,
    sel: IndexArray,
    gaps: tuple[IndexArray, IndexArray],
    cfg: FeatureConfig,
) -> NDArray[np.int8]:
    """Which boundary alone of candidates ``sel`` ``(s,)`` is the wire's outline (module
    docstring, step 3): -1 the left, +1 the right, 0 both or neither.

    A boundary is the outline (the wire occludes the sky there) when the line has fallen to
    half the candidate's darkest deviation from the sky just inside it, as a blurred step
    does (on average over the pixels 1 to ``sharp_px // 2``, at least 2, inside). The end of
    a lit part is brighter than the sky inside; an unworn wire's shading, from a dark side
    to a lit bottom as bright as the sky, darkens over a good part of the wire. Only a
    candidate with the sky clear of other runs for half the narrowest wire's width on both
    sides (``gaps``: the sky's limits ``gap_l, gap_r`` [line px], ``(m,)`` each) is a whole
    wire: a dark silhouette split at a face (a fitting's, by white daylight) has its other
    part just beyond the face, and each part's outer edge is an outline."""
    w = windows
    inward = np.arange(1, max(2, cfg.sharp_px // 2) + 1)
    last = (w.own[sel] - 1)[:, np.newaxis]
    left = np.clip(np.ceil(boundaries.left[sel]).astype(np.intp)[:, np.newaxis] + inward, 0, last)
    right = np.clip(
        np.floor(boundaries.right[sel]).astype(np.intp)[:, np.newaxis] - inward, 0, last
    )
    base = w.base[sel][:, np.newaxis]
    ramp0, slope = sky.ramp0[sel][:, np.newaxis], sky.slope[sel][:, np.newaxis]
    level_l = (w.xs4[base + left] - (ramp0 + slope * left)).mean(axis=1)
    level_r = (w.xs4[base + right] - (ramp0 + slope * right)).mean(axis=1)
    # the sky beside both boundaries clear of other runs for a narrow wire's radius [line px]
    radius, first = 0.5 * cfg.wire_width_px[0], w.first_px[sel]
    clear = (boundaries.left[sel] + first - gaps[0][sel] >= radius) & (
        gaps[1][sel] - (boundaries.right[sel] + first) >= radius
    )
    # the darkest pixel between the boundaries, where a boundary may be an outline (darker
    # than the sky inside it: half the darkest deviation is below the sky's level)
    maybe = np.flatnonzero(clear & (np.minimum(level_l, level_r) < 0.0))
    darkest = np.zeros(sel.shape[0])
    if maybe.shape[0]:
        px = np.arange(w.stride)
        deviation = w.xs4.reshape(-1, w.stride)[sel[maybe]] - (ramp0[maybe] + slope[maybe] * px)
        between = (px >= left[maybe, :1]) & (px <= right[maybe, :1])
        darkest[maybe] = -np.where(between, deviation, np.inf).min(axis=1)
    half = np.where(darkest > cfg.boundary_k * w.s4[sel], -0.5 * darkest, -np.inf)
    outline_l, outline_r = (level_l <= half) & clear, (level_r <= half) & clear
    side = np.where(outline_l & ~outline_r, -1, np.where(outline_r & ~outline_l, 1, 0))
    return side.astype(np.int8)


@dataclass(frozen=True)
class _Wires:
    """The ``s`` candidates still standing after step 3, on their own rows: the windows
    ``xs`` ``(s, stride)`` and their first difference ``d4`` (``d4[i, j]`` sits at window
    position ``j + 0.5``), the boundaries and the sky beside them."""

    xs: NDArray[np.float32]  # (s, stride)
    d4: NDArray[np.float32]  # (s, stride)
    left: FloatArray  # (s,) boundaries [window px]
    right: FloatArray  # (s,)
    lb: IndexArray  # (s,) the pixels at or outside them
    rb: IndexArray  # (s,)
    top_k: IndexArray  # (s,) the last pixel a face edge may take
    dark: NDArray[np.bool_]  # (s,) a dark silhouette
    t_face: NDArray[np.float32]  # (s,) a face edge's least first difference
    sky_ramp0: FloatArray  # (s,) the sky's ramp beside the wire at window pixel 0
    sky_slope: NDArray[np.float32]  # (s,) its slope per window pixel


def _kept_wires(
    windows: _Windows,
    sky: _Sky,
    contrast: _Contrast,
    boundaries: _Boundaries,
    sel: IndexArray,
    cfg: FeatureConfig,
) -> _Wires:
    """The candidates ``sel`` (those that passed step 3) for the face search."""
    w = windows
    xs = w.xs4.reshape(-1, w.stride)[sel]
    d4 = np.empty_like(xs)
    np.subtract(xs.ravel()[1:], xs.ravel()[:-1], out=d4.ravel()[:-1])
    d4.ravel()[-1] = 0.0
    left, right = boundaries.left[sel], boundaries.right[sel]
    return _Wires(
        xs=xs,
        d4=d4,
        left=left,
        right=right,
        lb=np.floor(left).astype(np.intp),
        rb=np.ceil(right).astype(np.intp),
        top_k=w.own[sel] - 3,
        dark=contrast.polarity[sel] < 0,
        t_face=cfg.face_k * 2.0 * w.sigma[sel],  # noise of d4: 2 sigma
        sky_ramp0=sky.ramp0[sel],
        sky_slope=sky.slope[sel],
    )


@dataclass(frozen=True)
class _FaceEdges:
    """The strongest rising and falling first difference inside each wire, ``(s,)`` each:
    where (``rise_k``, ``fall_k``), whether significant and sharp, and sub-pixel [window px];
    ``window``: the centroid's half-width [px] (0: the log-parabola's vertex, :func:`_edge`);
    ``inner_left``, ``inner_right``: a dark silhouette's first pixels inside the ramps of its
    left and right boundaries [window px]."""

    rise_k: IndexArray
    fall_k: IndexArray
    rise_ok: NDArray[np.bool_]
    fall_ok: NDArray[np.bool_]
    left: FloatArray
    right: FloatArray
    window: int
    inner_left: IndexArray
    inner_right: IndexArray


def _face_edges(wires: _Wires, cfg: FeatureConfig) -> _FaceEdges:
    """Step 4: the face's edges, searched over the whole wire for a bright object and inside
    the boundaries (clear by ``_GUARD_PX``) for a dark silhouette; the falling edge after the
    rising one."""
    d4 = wires.d4
    lb, rb, top_k = wires.lb, wires.rb, wires.top_k
    ms, stride = d4.shape
    zone_lo = np.clip(np.where(wires.dark, lb + _GUARD_PX, lb - 2), 1, top_k)
    zone_hi = np.clip(np.where(wires.dark, rb - _GUARD_PX - 1, rb + 1), 1, top_k)
    # the zone's first differences, gathered from its start (dz[:, j] = d4[:, at + j])
    wide = min(stride, max(1, int((zone_hi - zone_lo).max()) + 1))
    offsets = np.arange(wide, dtype=np.int16)[None, :]
    at = np.clip(zone_lo, 0, stride - wide)
    dz = _rows(d4, at, wide)
    first = (zone_lo - at).astype(np.int16)[:, None]
    last = (zone_hi - at).astype(np.int16)[:, None]
    dz *= (offsets >= first) & (offsets <= last)
    rise_dz, fall_dz, rise_end, fall_start = _clear_of_ramps(dz, offsets, first, last, wires)
    k1 = at + np.argmax(rise_dz, axis=1)
    k2 = at + np.argmin(fall_dz, axis=1)
    rows = np.arange(ms)
    sign2 = np.repeat(np.array([1.0, -1.0], dtype=np.float32), ms)
    reach = cfg.sharp_px
    rise_ok = (zone_hi >= zone_lo) & _sharp(d4, rows, k1, sign2[:ms], wires.t_face, reach)
    # the falling edge after the rising one (anywhere in the zone when there is none)
    again = np.flatnonzero(rise_ok & (k2 <= k1))
    if again.shape[0]:
        later = offsets > (k1[again] - at[again])[:, None]
        k2[again] = at[again] + np.argmin(fall_dz[again] * later, axis=1)
    fall_ok = _sharp(d4, rows, k2, sign2[ms:], wires.t_face, reach) & (~rise_ok | (k2 > k1))
    window = cfg.sharp_px if cfg.sharp_px > _PEAKED_PX else 0
    both = _edge(d4, np.tile(rows, 2), np.concatenate([k1, k2]), sign2, window)
    # past the ramps where they reach into the zone, else just inside the guard
    inner_left = np.where(fall_start[:, 0] > first[:, 0], at + fall_start[:, 0], lb + _GUARD_PX)
    inner_right = np.where(rise_end[:, 0] < last[:, 0], at + rise_end[:, 0], rb - _GUARD_PX)
    return _FaceEdges(
        k1, k2, rise_ok, fall_ok, both[:ms], both[ms:], window, inner_left, inner_right
    )


def _clear_of_ramps(
    dz: NDArray[np.float32],
    offsets: NDArray[np.int16],
    first: NDArray[np.int16],
    last: NDArray[np.int16],
    wires: _Wires,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.int16], NDArray[np.int16]]:
    """The face search's first differences ``dz`` ``(s, wide)`` (zone ``[first, last]``,
    ``(s, 1)`` each) for the rising edge and for the falling one, and where the right
    boundary's ramp begins and the left one's ends (``(s, 1)``, zone offsets): a dark silhouette's
    boundaries are blurred steps whose ramps reach inside it further than ``_GUARD_PX``
    where the blur spreads over several pixels (16,384-px lines), and the step from the
    dark side to the sky is larger than the one to the face. The rising edge is searched
    before the right boundary's ramp (the run of significant rises that reaches the zone's
    end), the falling edge after the left boundary's; a face that reaches the silhouette is
    one-sided and takes the boundary's edge (:func:`_one_sided_faces`)."""
    rise_end, fall_start = last.copy(), first.copy()
    dark = np.flatnonzero(wires.dark)
    if dark.shape[0] == 0:
        return dz, dz, rise_end, fall_start
    d, t = dz[dark], wires.t_face[dark, None]
    calm = (d <= t) & (offsets <= last[dark])
    rise_end[dark] = np.where(calm, offsets, -1).max(axis=1, keepdims=True)
    calm = (d >= -t) & (offsets >= first[dark])
    fall_start[dark] = np.where(calm, offsets, offsets.shape[1]).min(axis=1, keepdims=True)
    rise_dz, fall_dz = dz.copy(), dz.copy()
    rise_dz[dark] = np.where(offsets > rise_end[dark], np.float32(0.0), d)
    fall_dz[dark] = np.where(offsets < fall_start[dark], np.float32(0.0), d)
    return rise_dz, fall_dz, rise_end, fall_start


@dataclass(frozen=True)
class _Faces:
    """Each wire's face edges [window px] and whether it has a face, ``(s,)`` each; a
    one-sided face took the boundary's edge on one side (the right one: ``took_right``)."""

    left: FloatArray
    right: FloatArray
    found: NDArray[np.bool_]
    one_sided: NDArray[np.bool_]
    took_right: NDArray[np.bool_]


def _one_sided_faces(wires: _Wires, edges: _FaceEdges, cfg: FeatureConfig) -> _Faces:
    """Step 4's one-sided faces: a dark silhouette's face may reach the silhouette on one
    side. Then it has one inner edge, and the wire is as bright as the face, not as dark as
    its sides, just inside that boundary; the face takes the boundary's edge."""
    rise_ok, fall_ok = edges.rise_ok, edges.fall_ok
    face_left, face_right = edges.left, edges.right
    ms, stride = wires.xs.shape
    one = np.flatnonzero(wires.dark & (rise_ok ^ fall_ok))
    one_sided = np.zeros(ms, dtype=bool)
    took_right = np.zeros(ms, dtype=bool)
    if one.shape[0]:
        lb, rb, top_k = wires.lb[one], wires.rb[one], wires.top_k[one]
        rising = rise_ok[one]
        xs_one = wires.xs[one]
        cols = np.arange(stride, dtype=np.int16)[None, :]
        interior = (cols > lb[:, None]) & (cols < rb[:, None])
        darkest = np.where(interior, xs_one, np.inf).min(axis=1)
        edge_k = np.where(rising, edges.rise_k[one], edges.fall_k[one])
        face_level = np.maximum(
            _take(xs_one, np.clip(edge_k + np.where(rising, 2, -1), 0, top_k)),
            _take(xs_one, np.clip(edge_k + np.where(rising, 3, -2), 0, top_k)),
        )
        # the wire just inside the boundary, past its blurred ramp
        inner_k = np.where(rising, edges.inner_right[one], edges.inner_left[one])
        inner = _take(xs_one, np.clip(inner_k, 0, top_k))
        reaches = inner - darkest > 0.5 * (face_level - darkest)
        d_one = wires.d4[one]
        kb = np.where(
            rising,
            _zone_argmax(d_one, rb - _GUARD_PX, rb + 1),
            _zone_argmax(-d_one, lb - 2, lb + _GUARD_PX - 1),
        )
        boundary_edge = _edge(
            d_one, np.arange(one.shape[0]), kb, np.where(rising, 1.0, -1.0), edges.window
        )
        face_left, face_right = face_left.copy(), face_right.copy()
        face_right[one] = np.where(rising & reaches, boundary_edge, face_right[one])
        face_left[one] = np.where(~rising & reaches, boundary_edge, face_left[one])
        one_sided[one] = reaches
        took_right[one] = reaches & rising
    # a one-sided face's inner edge within the blur's sigma (a third of sharp_px) of the
    # boundary's edge is that edge found twice: the silhouette's own blurred ramp
    apart = face_right - face_left
    found = (rise_ok & fall_ok & (apart > 0.0)) | (one_sided & (apart > cfg.sharp_px / 3.0))
    return _Faces(face_left, face_right, found, one_sided, took_right)


@dataclass(frozen=True)
class _Fitted:
    """The wires' boundaries and faces after step 6 [window px], ``(s,)`` each."""

    left: FloatArray
    right: FloatArray
    face_left: FloatArray
    face_right: FloatArray
    has_face: NDArray[np.bool_]


def _near_silhouette_fit(wires: _Wires, faces: _Faces, cfg: FeatureConfig) -> _Fitted:
    """Step 6: a dark silhouette with a face edge between ``FACE_RESOLVED_PX`` and ``_NEAR_PX``
    (``sharp_px`` if more: a blur of several pixels) from its silhouette is fitted whole
    (:func:`_fit_wire`); a side whose edges are closer than ``FACE_RESOLVED_PX`` (one step)
    keeps them. A one-sided face keeps the edges it has."""
    clear_l = faces.left - wires.left
    clear_r = wires.right - faces.right
    reach = max(_NEAR_PX, float(cfg.sharp_px))
    near = (clear_l > FACE_RESOLVED_PX) & (clear_l < reach)
    near |= (clear_r > FACE_RESOLVED_PX) & (clear_r < reach)
    pick = np.flatnonzero(wires.dark & faces.found & ~faces.one_sided & near)
    if pick.shape[0] == 0:
        return _Fitted(wires.left, wires.right, faces.left, faces.right, faces.found)
    edges = np.stack([wires.left, faces.left, faces.right, wires.right], axis=1)
    held = np.stack([clear_l[pick], clear_r[pick]], axis=1)[:, [0, 0, 1, 1]] <= FACE_RESOLVED_PX
    edges[pick] = _fit_wire(wires, pick, edges[pick], held)
    left, face_left, face_right, right = edges.T
    return _Fitted(left, right, face_left, face_right, faces.found & (face_right > face_left))


def _fit_wire(
    wires: _Wires, pick: IndexArray, edges: FloatArray, held: NDArray[np.bool_]
) -> FloatArray:
    """Edges ``(k, 4)`` (silhouette left, face left, face right, silhouette right; window
    px) of the dark silhouettes ``pick`` ``(k,)``, fitted whole; the edges ``held``
    ``(k, 4)`` stay where they are.

    A face edge near its silhouette and the silhouette's edge are opposite blurred steps
    that pull each other's first-difference peaks apart. The wire is fitted as a blurred
    four-edge profile on the smoothed window, from four pixels of sky beside it on each
    side: the sky's ramp, the dark sides' level (one for both), the face's level, the four
    edges and the blur (a Gaussian; its start from the wider of the silhouette edges'
    first-difference peaks) by Gauss-Newton. A side narrower than the blur gives its
    level only together with its width: the other side gives it. A face narrower than three
    blur deviations never shows its level either, and its level and width trade off: it
    keeps the edges found, as does a fit that moves an edge by 3 px or more.
    """
    xs = wires.xs[pick]
    k, width = xs.shape
    rows = np.arange(k)
    lb = np.floor(edges[:, 0]).astype(np.intp)
    rb = np.ceil(edges[:, 3]).astype(np.intp)
    # the blur to start from: the wider of the silhouette edges' first-difference peaks
    d = wires.d4[pick]
    variance = np.zeros(k)
    for at, falling in ((lb, -1.0), (rb, 1.0)):
        first = np.clip(at - 2, 1, width - 6)
        peak = first + np.argmax(_rows(d, first, 5) * falling, axis=1)
        logs = np.log(np.maximum(_rows(d, peak - 1, 3).astype(np.float64) * falling, 1e-6))
        curv = np.minimum(logs[:, 0] - 2.0 * logs[:, 1] + logs[:, 2], -1e-6)
        variance = np.maximum(variance, np.clip(-1.0 / curv - 1.0 / 12.0, 0.36, 9.0))
    scale = 1.0 / np.sqrt(variance)
    # the window: four pixels of sky beside the silhouette on each side
    t = np.clip(lb[:, None] - 4 + np.arange(int((rb - lb).max()) + 9), 0, width - 1)
    weight = (t <= np.minimum(rb + 4, width - 1)[:, None]).astype(np.float32)
    v = xs[rows[:, None], t]
    interior = (t > lb[:, None]) & (t < rb[:, None])
    t = t.astype(np.float32)
    sky = (wires.sky_ramp0[pick, None] + wires.sky_slope[pick, None] * t).astype(np.float32)
    dark = np.where(interior, v, np.inf).min(axis=1).astype(np.float64)
    middle = np.rint(0.5 * (edges[:, 1] + edges[:, 2])).astype(np.intp)
    face = xs[rows, np.clip(middle, 0, width - 1)].astype(np.float64)
    fitted = edges.copy()
    active = np.arange(k)  # the wires whose edges still move
    for _ in range(_FIT_ITERATIONS):
        a = active
        delta = _fit_step(
            t[a], weight[a], v[a], sky[a], scale[a], fitted[a], dark[a], face[a], held[a]
        )
        moved = np.clip(delta[:, :4], -1.0, 1.0)
        moved_edges = fitted[a] + moved
        np.maximum.accumulate(moved_edges, axis=1, out=moved_edges)  # in their order
        fitted[a] = np.where(held[a], edges[a], moved_edges)
        dark[a] += delta[:, 4]
        face[a] += delta[:, 5]
        scale[a] *= np.exp(np.clip(delta[:, 6] / scale[a], -0.5, 0.5))
        active = a[np.abs(moved).max(axis=1) >= _FIT_SETTLED_PX]
        if active.shape[0] == 0:
            break
    good = np.all(np.abs(fitted - edges) < 3.0, axis=1)
    good &= edges[:, 2] - edges[:, 1] > 3.0 * np.sqrt(variance)
    out: FloatArray = np.where(good[:, None], fitted, edges)
    return out


def _fit_step(
    t: NDArray[np.float32],
    weight: NDArray[np.float32],
    v: NDArray[np.float32],
    sky: NDArray[np.float32],
    scale: FloatArray,
    edges: FloatArray,
    dark: FloatArray,
    face: FloatArray,
    held: NDArray[np.bool_],
) -> FloatArray:
    """One Gauss-Newton step of :func:`_fit_wire`'s model for ``k`` wires: the windows'
    pixel positions ``t``, weights, values ``v`` and sky ramp ``(k, n)``, the blur's inverse
    deviation ``scale`` ``(k,)`` [1/px], the four edges ``(k, 4)`` [px] (those ``held`` stay)
    and the dark and face levels ``(k,)``; the change ``(k, 7)`` of the edges, the two
    levels and ``scale``. The model and its derivatives are computed in single precision
    (positions to 1e-5 px, levels to 1e-7 of their value), the step solved in double."""
    f32 = np.float32
    k, n = t.shape
    inverse = scale.astype(f32)[:, None, None]
    z = t[:, None, :] - edges.astype(f32)[:, :, None]  # (k, 4, n)
    cdf, pdf = _normal_cdf(z * inverse)
    dark_step = dark.astype(f32)[:, None] - sky  # (k, n)
    face_step = (face - dark).astype(f32)[:, None]  # (k, 1)
    wire = cdf[:, 0] - cdf[:, 3]
    flat = cdf[:, 1] - cdf[:, 2]
    residual = v - sky
    residual -= dark_step * wire
    residual -= face_step * flat
    # d model / d (the four edges, dark level, face level, blur scale), in place: each
    # edge's signed step times its density, then the sum of those times z for the blur
    jac = np.empty((k, 7, n), dtype=f32)
    np.multiply(pdf[:, 0], dark_step, out=jac[:, 0])
    np.multiply(pdf[:, 1], face_step, out=jac[:, 1])
    np.multiply(pdf[:, 2], -face_step, out=jac[:, 2])
    np.multiply(pdf[:, 3], -dark_step, out=jac[:, 3])
    np.sum(np.multiply(jac[:, :4], z, out=z), axis=1, out=jac[:, 6])
    jac[:, :4] *= np.where(held, f32(0.0), -inverse[:, :, 0])[:, :, None]
    np.subtract(wire, flat, out=jac[:, 4])
    jac[:, 5] = flat
    weighted = jac * weight[:, None, :]  # the weights are 0 or 1: applied once
    normal = (weighted @ jac.transpose(0, 2, 1)).astype(np.float64)
    normal += np.eye(7) * (1e-9 * np.trace(normal, axis1=1, axis2=2) + 1e-12)[:, None, None]
    rhs = (weighted @ residual[:, :, None]).astype(np.float64)
    delta = np.linalg.solve(normal, rhs)[:, :, 0]
    return np.where(np.isfinite(delta), delta, 0.0)


def _normal_cdf(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The standard normal distribution function and its derivative, by the hyperbolic
    tangent approximation ``(1 + tanh(z (a + b z^2))) / 2`` (error below 2e-4: far below the
    noise of the levels it scales; ten times faster than ``erf``), in the precision of ``z``."""
    z2 = z * z
    th = np.tanh(z * (_CDF_A + _CDF_B * z2))
    return 0.5 * (1.0 + th), 0.5 * (1.0 - th * th) * (_CDF_A + 3.0 * _CDF_B * z2)


def _zone_argmax(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> IndexArray:
    """Argmax of each row over columns ``[lo, hi]`` (clipped to the row)."""
    last = values.shape[1] - 1
    lo = np.clip(lo, 0, last)
    hi = np.clip(hi, 0, last)
    cols = np.arange(values.shape[1])[None, :]
    inside = (cols >= lo[:, None]) & (cols <= hi[:, None])
    best: IndexArray = np.argmax(np.where(inside, values, -np.inf), axis=1)
    return best


def _extract_group(data: np.ndarray, bit_depth: int, cfg: FeatureConfig) -> LineFeatures:
    """Features of a group of rows (every step per line; see :func:`extract_features`)."""
    full = float((1 << bit_depth) - 1)
    sigma = noise_sigma(data, cfg.noise_samples, cfg.noise_floor_lsb)  # (r,)
    sums = _bin_sums(data, cfg.bin_px)
    cand = _candidates(_detect(sums, sigma, cfg), data, sums, sigma, cfg)
    if cand[0].shape[0] == 0:
        return LineFeatures.empty()
    own = (cand[2] - cand[1]) * cfg.bin_px + 2 * (cfg.bin_px + 2 * cfg.sharp_px + _SKY_PX)
    limits = (0, *_SIZE_CLASSES_PX, 1 << 30)
    parts = []
    for lo, hi in itertools.pairwise(limits):
        pick = np.flatnonzero((own > lo) & (own <= hi))
        if pick.shape[0]:
            parts.append(_fine(data, tuple(c[pick] for c in cand), sigma, cfg, full))
    found = parts[0] if len(parts) == 1 else _join(parts)
    if found.row.shape[0] == 0:
        return LineFeatures.empty()
    fl, fr = found.face_left, found.face_right
    wire_centre = 0.5 * (found.left + found.right)
    face_centre = 0.5 * (fl + fr)
    return LineFeatures(
        scan=found.row.astype(np.int64),
        centre_px=np.where(np.isfinite(face_centre), face_centre, wire_centre),
        wire_centre_px=wire_centre,
        left_px=found.left,
        right_px=found.right,
        face_left_px=fl,
        face_right_px=fr,
        face_width_px=fr - fl,
        face_centre_px=face_centre,
        contrast=np.abs(found.peak_dev).astype(np.float64) / full,
        polarity=found.polarity,
        outline_side=found.outline_side,
    )


def _join(parts: list[_Found]) -> _Found:
    """Concatenate fine-pass results, in raster order."""
    joined = {f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(_Found)}
    order = np.lexsort((joined["start"], joined["row"]))
    return _Found(**{k: v[order] for k, v in joined.items()})
