"""Roof-frame positions from the pixel coordinates of the same point in several cameras.

Two cameras: the paper's closed form (equations 9-10). Any number of cameras: linear least
squares on the back-projected rays of the cameras that saw each point, refined by Gauss-Newton
on the reprojection error, with the position's covariance for a given pixel noise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray, IntArray

from .camera import LineScanCamera

__all__ = ["TriangulationResult", "triangulate", "triangulate_pair"]

# Below this reciprocal condition number (det / trace²) of the 2x2 normal matrix the rays are
# taken as parallel and the point as undetermined.
_MIN_RECIPROCAL_CONDITION = 1e-12


def triangulate_pair(
    camera_a: LineScanCamera,
    camera_b: LineScanCamera,
    u_a_px: ArrayLike,
    u_b_px: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """Intersect the rays of two cameras: the paper's closed form (equations 9-10).

    Parameters
    ----------
    camera_a, camera_b : LineScanCamera
        The two cameras.
    u_a_px, u_b_px : array_like, broadcastable
        Observed image coordinates of the same points in each camera [px]; distortion is
        removed first.

    Returns
    -------
    x_mm, z_mm : ndarray, broadcast shape
        Roof-frame position [mm]; NaN where the rays are parallel or an input is NaN.
    """
    u_a = camera_a.undistort(u_a_px)
    u_b = camera_b.undistort(u_b_px)
    ma = camera_a.matrix
    mb = camera_b.matrix
    p1 = ma[0, 0] - u_a * ma[1, 0]
    p2 = mb[0, 0] - u_b * mb[1, 0]
    q1 = ma[0, 1] - u_a * ma[1, 1]
    q2 = mb[0, 1] - u_b * mb[1, 1]
    k1 = u_a * ma[1, 2] - ma[0, 2]
    k2 = u_b * mb[1, 2] - mb[0, 2]
    denominator = p1 * q2 - p2 * q1
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (q2 * k1 - q1 * k2) / denominator
        z = (p1 * k2 - p2 * k1) / denominator
    parallel = ~np.isfinite(x) | ~np.isfinite(z)
    return (
        np.asarray(np.where(parallel, np.nan, x), dtype=np.float64),
        np.asarray(np.where(parallel, np.nan, z), dtype=np.float64),
    )


@dataclass(frozen=True, eq=False)
class TriangulationResult:
    """Positions of ``n`` points triangulated from several cameras; NaN where undetermined.

    Attributes
    ----------
    x_mm, z_mm : ndarray, shape (n,)
        Roof-frame position [mm].
    rms_reprojection_px : ndarray, shape (n,)
        RMS over the cameras used of observed minus re-projected image coordinate [px]
        (zero with two cameras: two rays always meet).
    sigma_x_mm, sigma_z_mm : ndarray, shape (n,)
        Standard deviation of the position [mm] for independent pixel noise ``sigma_px``.
    cameras_used : ndarray of int, shape (n,)
        Number of cameras that saw the point (finite image coordinate).
    """

    x_mm: FloatArray
    z_mm: FloatArray
    rms_reprojection_px: FloatArray
    sigma_x_mm: FloatArray
    sigma_z_mm: FloatArray
    cameras_used: IntArray


def _solve_2x2(
    a11: FloatArray, a12: FloatArray, a22: FloatArray, b1: FloatArray, b2: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Batched solution of symmetric ``[[a11, a12], [a12, a22]] · (s1, s2) = (b1, b2)``."""
    det = a11 * a22 - a12 * a12
    trace = a11 + a22
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = det > _MIN_RECIPROCAL_CONDITION * trace * trace
        s1 = np.where(ok, (a22 * b1 - a12 * b2) / det, np.nan)
        s2 = np.where(ok, (a11 * b2 - a12 * b1) / det, np.nan)
    return s1, s2


def triangulate(
    cameras: Sequence[LineScanCamera],
    u_px: ArrayLike,
    *,
    sigma_px: float = 0.1,
    iterations: int = 2,
) -> TriangulationResult:
    """Triangulate points from every camera that saw them.

    1. Linear least squares: each camera's observation ``u`` constrains the point to its ray
       ``p x + q z = k`` (equation 10's ``p``, ``q``, ``k``); the rows are scaled to unit
       ``(p, q)`` so that the sum of squared perpendicular distances to the rays [mm²] is
       minimised, by batched 2x2 normal equations.
    2. ``iterations`` Gauss-Newton steps on the reprojection error in observed pixels
       (distortion included), which is the maximum-likelihood estimate for independent pixel
       noise.
    3. Covariance ``sigma_px² · (JᵀJ)⁻¹`` from the reprojection Jacobian ``J`` [px/mm].

    Parameters
    ----------
    cameras : sequence of LineScanCamera, length C
        The cameras, in the order of the columns of ``u_px``.
    u_px : array_like, shape (n, C)
        Observed image coordinate of each point in each camera [px]; NaN where a camera did
        not see the point.
    sigma_px : float, default 0.1
        Standard deviation of the image coordinates [px], for the covariance.
    iterations : int, default 2
        Gauss-Newton steps after the linear solution.

    Returns
    -------
    TriangulationResult
        Each field shape (n,). Points seen by fewer than two cameras, or whose rays are
        (nearly) parallel, are NaN (``cameras_used`` still counts their observations).
    """
    u_observed = np.asarray(u_px, dtype=np.float64)
    n_cameras = len(cameras)
    if u_observed.ndim != 2 or u_observed.shape[1] != n_cameras:
        raise ValueError(
            f"u_px has shape {u_observed.shape}, expected (n, {n_cameras}) for {n_cameras} cameras"
        )
    seen = np.isfinite(u_observed)
    cameras_used = seen.sum(axis=1).astype(np.int64)
    # camera-major (C, n): each step is one NumPy call for all cameras, the cameras' matrix
    # coefficients broadcast from (C, 1) columns; sums over the cameras run in camera order
    observed = np.ascontiguousarray(u_observed.T)
    seen = seen.T
    m00, m01, m02, m10, m11, m12 = (
        np.array([camera.matrix.ravel() for camera in cameras], dtype=np.float64)
        .reshape(n_cameras, 6)
        .T[:, :, np.newaxis]
    )
    # the radial term's constants (C', 1) of the cameras that have one
    distorted = [c for c, camera in enumerate(cameras) if camera.k1 != 0.0]
    u0, f, k1 = (
        np.array([getattr(cameras[c], name) for c in distorted], dtype=np.float64)[:, np.newaxis]
        for name in ("principal_point_px", "focal_px", "k1")
    )

    # 1. linear least squares on perpendicular distances to the rays
    u = observed.copy()
    for c in distorted:
        u[c] = cameras[c].undistort(observed[c])
    p = m00 - u * m10
    q = m01 - u * m11
    k = u * m12 - m02
    with np.errstate(divide="ignore", invalid="ignore"):
        norm = np.hypot(p, q)
        p, q, k = p / norm, q / norm, k / norm
    use = seen & np.isfinite(p) & np.isfinite(q) & np.isfinite(k)
    p, q, k = (np.where(use, value, 0.0) for value in (p, q, k))
    x, z = _solve_2x2(
        (p * p).sum(axis=0),
        (p * q).sum(axis=0),
        (q * q).sum(axis=0),
        (p * k).sum(axis=0),
        (q * k).sum(axis=0),
    )
    enough = cameras_used >= 2
    x = np.where(enough, x, np.nan)
    z = np.where(enough, z, np.nan)

    # 2. Gauss-Newton on reprojection error; 3. covariance at the solution
    def normal_equations(
        x: FloatArray, z: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        """``JᵀJ``, ``Jᵀr`` and ``rᵀr`` of the reprojection in observed pixels at ``(x, z)``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            # LineScanCamera.project_jacobian of every camera at once
            den = m10 * x + m11 * z + m12
            u = (m00 * x + m01 * z + m02) / den  # ideal, (C, n)
            du_dx = (m00 - u * m10) / den
            du_dz = (m01 - u * m11) / den
            if distorted:
                xn = (u[distorted] - u0) / f
                gain = 1.0 + 3.0 * k1 * xn * xn
                du_dx[distorted] = du_dx[distorted] * gain
                du_dz[distorted] = du_dz[distorted] * gain
                u[distorted] = u0 + f * xn * (1.0 + k1 * xn * xn)
        residual = u - observed
        use = seen & np.isfinite(residual)
        residual = np.where(use, residual, 0.0)
        du_dx = np.where(use, du_dx, 0.0)
        du_dz = np.where(use, du_dz, 0.0)
        return (
            (du_dx * du_dx).sum(axis=0),
            (du_dx * du_dz).sum(axis=0),
            (du_dz * du_dz).sum(axis=0),
            (du_dx * residual).sum(axis=0),
            (du_dz * residual).sum(axis=0),
            (residual * residual).sum(axis=0),
        )

    for _ in range(iterations):
        j11, j12, j22, g1, g2, _ = normal_equations(x, z)
        dx, dz = _solve_2x2(j11, j12, j22, g1, g2)
        x = x - dx
        z = z - dz
    j11, j12, j22, _, _, sum_r2 = normal_equations(x, z)
    det = j11 * j22 - j12 * j12
    with np.errstate(divide="ignore", invalid="ignore"):
        variance_x = sigma_px**2 * j22 / det
        variance_z = sigma_px**2 * j11 / det
        rms = np.sqrt(sum_r2 / cameras_used)
        sigma_x = np.sqrt(variance_x)
        sigma_z = np.sqrt(variance_z)
    valid = enough & np.isfinite(x) & np.isfinite(z)
    nan = np.float64(np.nan)
    return TriangulationResult(
        x_mm=np.where(valid, x, nan),
        z_mm=np.where(valid, z, nan),
        rms_reprojection_px=np.where(valid, rms, nan),
        sigma_x_mm=np.where(valid, sigma_x, nan),
        sigma_z_mm=np.where(valid, sigma_z, nan),
        cameras_used=cameras_used,
    )
