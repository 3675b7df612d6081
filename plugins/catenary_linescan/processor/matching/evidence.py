"""The cameras that saw nothing where a point would be: evidence against a ghost.

Rays of different wires that some cameras pair meet where there is no wire (a ghost). A wire
in view shows in every camera's line, as a silhouette or a lit part, whether or not the
features made a candidate of it; a ghost falls on the sky of the cameras that did not
confirm it. The evidence is read from the lines' pixels, not from the candidates: a real
wire that a camera's features missed (merged with a clamp, too faint to pass a boundary
test) still stands out of the sky there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from catenary.arrays import BoolArray
from catenary_linescan.camera import LineScanCamera

from ..features import FeatureConfig, noise_sigma
from .candidates import Candidates
from .triangulate import Matches

SKY_PX = 6
"""Pixels of sky on each side of a point's window that give the sky's ramp across it."""
BLUR_PX = 3.0
"""Added to the wire's half-width in pixels for the window: the optical blur's reach."""


def unseen_in_lines(
    cameras: Sequence[LineScanCamera],
    lines: Sequence[np.ndarray],
    offsets_px: Sequence[int],
    full_scale: Sequence[float],
    candidates: Candidates,
    matches: Matches,
    width_mm: float,
    features: FeatureConfig,
) -> BoolArray:
    """Whether a camera that confirmed none of each verified point's candidates, though it
    made candidates in that scan (it was not blind), shows only sky where the point would be:
    ``(m,)``.

    The window is the wire's width (``width_mm`` at the point) and the blur, around the
    point's projection; the sky is a ramp between ``SKY_PX`` pixels beyond either end. The
    camera saw something there when a mean of three pixels stands out of the ramp by
    ``detect_k`` of the line's noise and by half ``detect_rel`` of the sky's level (the
    ``features``' thresholds and noise estimate); a window off the line, or holding a
    saturated pixel, is no evidence; nor is a window that a candidate of the camera's own
    reaches into. ``lines`` ``(n, W_c)`` per camera from pixel ``offsets_px``."""
    against = np.zeros(matches.count, dtype=bool)
    seeing: BoolArray = np.asarray(np.isfinite(candidates.left_px).any(axis=2))  # (n, C)
    for c, camera in enumerate(cameras):
        rows = np.flatnonzero(matches.verified & (matches.slot[:, c] < 0) & seeing[matches.scan, c])
        if rows.shape[0] == 0:
            continue
        scan = matches.scan[rows]
        u, du_dx, du_dz = camera.project_jacobian(matches.x_mm[rows], matches.z_mm[rows])
        reach = 0.5 * width_mm * np.hypot(du_dx, du_dz) + BLUR_PX
        line = lines[c]
        centre = u - offsets_px[c]
        finite = np.isfinite(centre) & np.isfinite(reach)
        # a silhouette of the camera's own within reach: it sees something there (a merged
        # silhouette that supports the point, a neighbour in line); its pixels need no look
        with np.errstate(invalid="ignore"):
            at, near = u[:, np.newaxis], reach[:, np.newaxis]
            lo, hi = candidates.left_px[scan, c, :], candidates.right_px[scan, c, :]
            finite &= ~((lo - near <= at) & (at <= hi + near)).any(axis=1)
        reach = np.where(finite, reach, 0.0)  # the window: as wide as the rows looked at need
        half = math.ceil(float(reach.max()))
        span = np.arange(-half - SKY_PX, half + SKY_PX + 1)
        start = np.rint(np.where(finite, centre, -1.0)).astype(np.int64)
        usable = finite & (start - half - SKY_PX >= 0)
        usable &= start + half + SKY_PX < line.shape[1]
        if not np.any(usable):
            continue
        rows, scan, reach, start = rows[usable], scan[usable], reach[usable], start[usable]
        pixels = line[scan[:, None], start[:, None] + span].astype(np.float64)  # (r, L)
        offset = span[None, :].astype(np.float64)
        inner = np.abs(offset) <= reach[:, None]
        outer = (np.abs(offset) > reach[:, None]) & (np.abs(offset) <= reach[:, None] + SKY_PX)
        left_sky = outer & (offset < 0)
        right_sky = outer & (offset > 0)
        level_l = (pixels * left_sky).sum(axis=1) / left_sky.sum(axis=1)
        level_r = (pixels * right_sky).sum(axis=1) / right_sky.sum(axis=1)
        at_l = (offset * left_sky).sum(axis=1) / left_sky.sum(axis=1)
        at_r = (offset * right_sky).sum(axis=1) / right_sky.sum(axis=1)
        slope = (level_r - level_l) / (at_r - at_l)
        ramp = level_l[:, None] + slope[:, None] * (offset - at_l[:, None])
        deviation = pixels - ramp
        mean3 = (deviation[:, :-2] + deviation[:, 1:-1] + deviation[:, 2:]) / 3.0
        within = inner[:, :-2] & inner[:, 2:]
        sigma = noise_sigma(line[scan], features.noise_samples, features.noise_floor_lsb)
        threshold = np.maximum(
            features.detect_k * sigma.astype(np.float64) / math.sqrt(3.0),
            0.5 * features.detect_rel * np.maximum(level_l, level_r),
        )
        seen = (np.abs(mean3) * within).max(axis=1) > threshold
        saturated = ((pixels >= full_scale[c]) & (inner | outer)).any(axis=1)
        against[rows] |= ~seen & ~saturated
    return against
