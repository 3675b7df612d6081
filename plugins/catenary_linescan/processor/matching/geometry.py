"""The cameras' ideal models in arrays, shared by the matching's steps: projection and its
gradient, the rays of equation 10, undistortion by table, and gathers of candidates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray
from catenary_linescan.camera import LineScanCamera


@dataclass(frozen=True)
class _Geometry:
    """A camera's ideal (undistorted) model in arrays: ``M``, centre and optical axis."""

    m: FloatArray
    centre: FloatArray
    axis: FloatArray

    @classmethod
    def of(cls, camera: LineScanCamera) -> _Geometry:
        # the centre and axis cost tens of microseconds: computed once per camera model
        matrix = camera.matrix
        key = matrix.tobytes()
        geometry = _geometries.get(key)
        if geometry is None:
            geometry = cls(matrix.copy(), camera.centre_mm, camera.optical_axis)
            _geometries[key] = geometry
        return geometry

    def project(self, x: FloatArray, z: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Ideal ``u`` and its gradient ``(du/dx, du/dz)`` at roof-frame points."""
        m = self.m
        with np.errstate(divide="ignore", invalid="ignore"):
            den = m[1, 0] * x + m[1, 1] * z + m[1, 2]
            u = (m[0, 0] * x + m[0, 1] * z + m[0, 2]) / den
            gx = (m[0, 0] - u * m[1, 0]) / den
            gz = (m[0, 1] - u * m[1, 1]) / den
        return u, gx, gz


_geometries: dict[bytes, _Geometry] = {}


_WHOLE = 0.9
"""A silhouette within this fraction of the wire's diameter (and no wider than the diameter
over it) shows the wire's whole outline."""


def _outline_axis(
    left_px: FloatArray,
    right_px: FloatArray,
    side: NDArray[np.int8],
    px_per_mm: FloatArray,
    radius_mm: float | FloatArray,
) -> FloatArray:
    """The image [px] of a round wire's axis from its silhouette ``left_px, right_px`` whose
    outline shows on the left only where ``side`` is -1, the right only where +1: the ray
    through an outline edge is tangent to the wire, ``radius_mm`` from its axis, which lies
    inward of the edge by that many millimetres across the ray at the wire (``px_per_mm``).
    A silhouette as wide as the wire (within :data:`_WHOLE` of its diameter there, whatever
    its shading said) and one of ``side`` 0 give their middle; a wider one is wires in line,
    and its outline's edge is the wire's at that end. Arrays broadcast."""
    half = radius_mm * px_per_mm
    width = right_px - left_px
    one_side = (side != 0) & ((width < _WHOLE * 2.0 * half) | (width * _WHOLE > 2.0 * half))
    edge = np.where(side < 0, left_px, right_px)
    axis: FloatArray = np.where(one_side, edge - side * half, 0.5 * (left_px + right_px))
    return axis


def _line_coefficients(m: FloatArray, u: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Equation 10's ``p, q, k``: the ray of ideal coordinate ``u`` is ``p x + q z = k``."""
    return m[0, 0] - u * m[1, 0], m[0, 1] - u * m[1, 1], u * m[1, 2] - m[0, 2]


_UNDISTORT_STEP_PX = 0.25
"""Spacing of the undistortion table [px]: linear interpolation between its nodes is off
by ``k1``-small second-order terms, below 1e-6 px for any lens the model is meant for."""


_undistort_tables: dict[tuple[float, int, bytes], tuple[FloatArray, FloatArray]] = {}


def _undistort(camera: LineScanCamera, u_px: FloatArray) -> FloatArray:
    """``camera.undistort`` by interpolation in a table computed once per camera.

    The radial model's inverse is smooth, so a table over ``[-W/2, 3W/2]`` at
    ``_UNDISTORT_STEP_PX`` and linear interpolation give it to 1e-6 px at the cost of one
    ``np.interp``; values outside the table (and NaN padding) go through the exact inverse.
    """
    if camera.k1 == 0.0:
        return u_px.copy()
    key = (camera.k1, camera.pixels, camera.matrix.tobytes())
    table = _undistort_tables.get(key)
    if table is None:
        grid = np.arange(-0.5 * camera.pixels, 1.5 * camera.pixels, _UNDISTORT_STEP_PX)
        table = (grid, camera.undistort(grid))
        if not np.all(np.isfinite(table[1])):
            return camera.undistort(u_px)
        _undistort_tables[key] = table  # only finite tables are kept
    grid, ideal = table
    # the grid is uniform: the cell is found by arithmetic, not by a search
    position = (u_px - grid[0]) / _UNDISTORT_STEP_PX
    inside = (position >= 0.0) & (position < grid.shape[0] - 1)  # False for NaN
    cell = np.where(inside, position, 0.0).astype(np.intp)
    fraction = np.where(inside, position - cell, 0.0)
    out = np.where(inside, ideal[cell] + fraction * (ideal[cell + 1] - ideal[cell]), np.nan)
    outside = ~inside & np.isfinite(u_px)
    if np.any(outside):
        out[outside] = camera.undistort(u_px[outside])
    return np.asarray(out, dtype=np.float64)


def _pinhole(camera: LineScanCamera) -> LineScanCamera:
    """The camera without its radial term (equation 8 alone)."""
    if camera.k1 == 0.0:
        return camera
    key = (camera.name, camera.pixels, camera.matrix.tobytes())
    pinhole = _pinholes.get(key)
    if pinhole is None:  # built once per camera model (the cameras are immutable)
        pinhole = LineScanCamera(camera.name, camera.pixels, camera.matrix, 0.0)
        _pinholes[key] = pinhole
    return pinhole


_pinholes: dict[tuple[str, int, bytes], LineScanCamera] = {}


def _gather(scan: IntArray, slot: IntArray, *values: FloatArray) -> list[FloatArray]:
    """``v[scan, c, slot[:, c]]`` per camera of each ``(n, C, K)`` array of ``values``, NaN
    where ``slot`` is -1: each ``(m, C)``."""
    _, n_cameras, k = values[0].shape
    # one flat index, for all the arrays: far cheaper than three broadcast ones
    index = (scan[:, np.newaxis] * n_cameras + np.arange(n_cameras)) * k + np.maximum(slot, 0)
    missing = slot < 0
    out = []
    for v in values:
        gathered = v.reshape(-1)[index]
        gathered[missing] = np.nan
        out.append(gathered)
    return out
