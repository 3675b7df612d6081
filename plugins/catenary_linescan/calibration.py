"""Camera calibration from ``(x, z, u)`` points, and the resolution look-up table.

Camera: normalised direct linear transform (DLT) for a starting matrix, then non-linear least
squares on the reprojection error over the camera's physical parameters (focal length,
principal point, tilt, centre, and the radial term ``k1`` when the data support it), with
robust rejection of gross outliers.

Resolution: the paper's look-up table (section 3.2) from the flat-face widths of the
calibration tool's targets, interpolated bilinearly instead of cell-constant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy import optimize, stats

from catenary.arrays import BoolArray, FloatArray, IndexArray
from catenary.errors import UserError

from .camera import LineScanCamera, camera_from_pose

__all__ = [
    "CameraCalibration",
    "ResolutionTable",
    "build_resolution_table",
    "calibrate_camera",
    "direct_linear_transform",
    "resolution_table_from_camera",
]

MIN_POINTS = 6
"""Fewest calibration points accepted for one camera (5 parameters, plus one to check)."""

MAD_TO_SIGMA = 1.4826
"""Standard deviation of a normal distribution over its median absolute deviation."""

DISTORTION_P_VALUE = 1e-3
"""F-test significance at which ``distortion=None`` adds the radial term."""

DISTORTION_MIN_POINTS = 12
"""Fewest inlier points for ``distortion=None`` to consider the radial term."""

DISTORTION_MIN_SPAN = 0.5
"""Fraction of the line the points must span for ``distortion=None`` to consider ``k1``."""

_MAX_REJECTION_ROUNDS = 10


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """The outcome of :func:`calibrate_camera`.

    Attributes
    ----------
    camera : LineScanCamera
        The calibrated camera, matrix normalised (FORMATS.md); ``k1 == 0.0`` when the radial
        term was not estimated.
    rms_px : float
        Reprojection RMS over the points used [px].
    max_px : float
        Largest absolute reprojection residual over the points used [px].
    points_used : int
        Points kept.
    points_rejected : int
        Points rejected as outliers.
    residuals_px : ndarray, shape (n,)
        Observed minus re-projected image coordinate of every input point, rejected ones
        included [px].
    inliers : ndarray of bool, shape (n,)
        Which input points were used.
    """

    camera: LineScanCamera
    rms_px: float
    max_px: float
    points_used: int
    points_rejected: int
    residuals_px: FloatArray
    inliers: BoolArray


# -- the camera -------------------------------------------------------------------------------


def _check_points(
    name: str, x: FloatArray, z: FloatArray, u: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    if not (x.ndim == z.ndim == u.ndim == 1 and x.shape == z.shape == u.shape):
        raise UserError(
            f"camera {name!r}: calibration points x_mm, z_mm, u_px have shapes "
            f"{x.shape}, {z.shape}, {u.shape}; expected three arrays of one length"
        )
    bad = ~(np.isfinite(x) & np.isfinite(z) & np.isfinite(u))
    if np.any(bad):
        raise UserError(
            f"camera {name!r}: calibration point {int(np.argmax(bad))} has a non-finite value"
        )
    n = x.shape[0]
    if n < MIN_POINTS:
        raise UserError(
            f"camera {name!r}: {n} calibration points, at least {MIN_POINTS} are needed"
        )
    scale = max(float(np.ptp(x)), float(np.ptp(z)), 1.0)
    if np.ptp(z) <= 1e-9 * scale:
        raise UserError(
            f"camera {name!r}: all {n} calibration points are at one height "
            f"(z = {z[0]:g} mm); points at two heights at least are needed"
        )
    centred = np.stack([x - x.mean(), z - z.mean()], axis=1)
    singular = np.linalg.svd(centred, compute_uv=False)
    if singular[1] <= 1e-9 * singular[0]:
        raise UserError(
            f"camera {name!r}: all {n} calibration points lie on one line; "
            "points off that line are needed"
        )
    if np.ptp(u) <= 1e-6:
        raise UserError(
            f"camera {name!r}: all {n} calibration points are at one pixel (u = {u[0]:g} px)"
        )
    return x, z, u


def _normalising_transform(values: FloatArray) -> FloatArray:
    """Hartley normalisation: affine map to zero mean and RMS distance sqrt(dim).

    ``values`` is (n, d); returns the (d+1, d+1) homogeneous transform.
    """
    dim = values.shape[1]
    centre = values.mean(axis=0)
    rms = math.sqrt(float(np.mean(np.sum((values - centre) ** 2, axis=1))))
    scale = math.sqrt(dim) / rms
    transform = np.eye(dim + 1)
    transform[:dim, :dim] *= scale
    transform[:dim, dim] = -scale * centre
    return transform


def direct_linear_transform(
    x_mm: ArrayLike, z_mm: ArrayLike, u_px: ArrayLike
) -> tuple[FloatArray, float]:
    """Normalised DLT estimate of a line-scan camera's 2x3 matrix (no distortion).

    Each point gives ``u (m2 · X) - m1 · X = 0`` with ``X = (x, z, 1)``; with ``(x, z)`` and
    ``u`` first normalised (Hartley), the matrix is the right singular vector of the smallest
    singular value, then denormalised.

    Parameters
    ----------
    x_mm, z_mm, u_px : array_like, shape (n,), n >= 5
        Roof-frame positions [mm] and their observed image coordinates [px].

    Returns
    -------
    matrix : ndarray, shape (2, 3)
        The projection matrix (arbitrary scale).
    conditioning : float
        Second-smallest over largest singular value of the normalised system [-]: near zero
        when the points do not determine the camera.
    """
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    u = np.asarray(u_px, dtype=np.float64)
    world = _normalising_transform(np.stack([x, z], axis=1))
    image = _normalising_transform(u[:, np.newaxis])
    xn, zn = world[0, 0] * x + world[0, 2], world[1, 1] * z + world[1, 2]
    un = image[0, 0] * u + image[0, 1]
    ones = np.ones_like(xn)
    system = np.stack([-xn, -zn, -ones, un * xn, un * zn, un], axis=1)
    _, singular, vt = np.linalg.svd(system, full_matrices=False)
    normalised = vt[-1].reshape(2, 3)
    matrix = np.linalg.solve(image, normalised @ world)
    return matrix, float(singular[-2] / singular[0])


def _physical_parameters(camera: LineScanCamera) -> FloatArray:
    centre = camera.centre_mm
    return np.array(
        [
            camera.focal_px,
            camera.principal_point_px,
            math.radians(camera.tilt_deg),
            centre[0],
            centre[1],
        ]
    )


def _camera(name: str, pixels: int, parameters: FloatArray) -> LineScanCamera:
    f, u0, tilt, cx, cz = parameters[:5]
    k1 = float(parameters[5]) if parameters.shape[0] > 5 else 0.0
    return camera_from_pose(name, pixels, cx, cz, math.degrees(tilt), f, u0, k1)


def _predict(parameters: FloatArray, x: FloatArray, z: FloatArray) -> FloatArray:
    """Observed image coordinate [px] for physical parameters (f, u0, tilt, cx, cz[, k1])."""
    f, u0, tilt, cx, cz = parameters[:5]
    sin, cos = math.sin(tilt), math.cos(tilt)
    dx, dz = x - cx, z - cz
    xn = (cos * dx - sin * dz) / (sin * dx + cos * dz)
    if parameters.shape[0] > 5:
        xn = xn * (1.0 + parameters[5] * xn * xn)
    return np.asarray(u0 + f * xn, dtype=np.float64)


def _refine(
    parameters: FloatArray,
    x: FloatArray,
    z: FloatArray,
    u: FloatArray,
    *,
    loss: str = "linear",
    f_scale: float = 1.0,
) -> FloatArray:
    def residuals(p: FloatArray) -> FloatArray:
        return _predict(p, x, z) - u

    result = optimize.least_squares(
        residuals, parameters, method="trf", loss=loss, f_scale=f_scale, x_scale="jac"
    )
    return np.asarray(result.x, dtype=np.float64)


@dataclass(frozen=True)
class _Fit:
    parameters: FloatArray
    inliers: BoolArray
    residuals: FloatArray  # observed minus predicted, all points

    @property
    def rss(self) -> float:
        return float(np.sum(self.residuals[self.inliers] ** 2))


def _robust_fit(
    name: str,
    parameters: FloatArray,
    x: FloatArray,
    z: FloatArray,
    u: FloatArray,
    *,
    outlier_px: float,
    outlier_sigmas: float,
) -> _Fit:
    """Robust start (soft-L1 loss), then reject points beyond
    ``max(outlier_px, outlier_sigmas · sigma)`` and refit until the kept set is stable."""
    n_parameters = parameters.shape[0]
    parameters = _refine(parameters, x, z, u, loss="soft_l1", f_scale=outlier_px)
    inliers = np.ones(x.shape, dtype=bool)
    parameters = _refine(parameters, x, z, u)
    for _ in range(_MAX_REJECTION_ROUNDS):
        residuals = u - _predict(parameters, x, z)
        sigma = MAD_TO_SIGMA * float(np.median(np.abs(residuals[inliers])))
        threshold = max(outlier_px, outlier_sigmas * sigma)
        kept = np.abs(residuals) <= threshold
        if np.array_equal(kept, inliers):
            break
        inliers = kept
        if np.count_nonzero(inliers) < max(MIN_POINTS, n_parameters + 1):
            raise UserError(
                f"camera {name!r}: only {np.count_nonzero(inliers)} of {x.shape[0]} "
                f"calibration points agree within {threshold:.3g} px; at least "
                f"{max(MIN_POINTS, n_parameters + 1)} are needed"
            )
        parameters = _refine(parameters, x[inliers], z[inliers], u[inliers])
    residuals = u - _predict(parameters, x, z)
    return _Fit(parameters, inliers, residuals)


def calibrate_camera(
    name: str,
    pixels: int,
    x_mm: ArrayLike,
    z_mm: ArrayLike,
    u_px: ArrayLike,
    *,
    distortion: bool | None = None,
    outlier_px: float = 1.0,
    outlier_sigmas: float = 4.0,
    max_rms_px: float = 2.0,
) -> CameraCalibration:
    """Calibrate one line-scan camera from roof-frame points and their image coordinates.

    1. Normalised DLT (:func:`direct_linear_transform`) gives a starting matrix, decomposed
       into focal length, principal point, tilt and centre.
    2. Non-linear least squares (``scipy.optimize.least_squares``) on the reprojection error
       over those physical parameters (and ``k1``), first with a robust ``soft_l1`` loss of
       scale ``outlier_px`` so that gross outliers cannot drag the start away.
    3. Outlier rejection: reject points whose residual exceeds
       ``max(outlier_px, outlier_sigmas · 1.4826 · MAD)`` (MAD of the kept points' residuals),
       refit with a plain squared loss, until the kept set no longer changes.

    With ``distortion=None`` the radial term is fitted and kept only when the data support it:
    at least ``DISTORTION_MIN_POINTS`` kept points spanning ``DISTORTION_MIN_SPAN`` of the
    line, and an F-test of the fits with and without ``k1`` on the same points significant at
    ``DISTORTION_P_VALUE``. Otherwise the camera has ``k1 = 0``.

    Parameters
    ----------
    name : str
        Camera name (for the result and for error messages).
    pixels : int
        Pixels on the line.
    x_mm, z_mm : array_like, shape (n,)
        Roof-frame positions of the calibration points [mm].
    u_px : array_like, shape (n,)
        Their observed image coordinates [px].
    distortion : bool or None, default None
        Estimate ``k1`` (True), never (False), or when the data support it (None).
    outlier_px : float, default 1.0
        Smallest residual rejected as an outlier [px].
    outlier_sigmas : float, default 4.0
        Rejection threshold in robust standard deviations of the residuals [-].
    max_rms_px : float, default 2.0
        Largest reprojection RMS of the kept points accepted [px]; above it the points do not
        describe one line-scan camera (wrong camera, units or target assignment).

    Returns
    -------
    CameraCalibration

    Raises
    ------
    catenary.errors.UserError
        When the points cannot constrain the camera: fewer than 6, non-finite values, all at
        one height, all on one line, too few left after outlier rejection, or a reprojection
        RMS above ``max_rms_px``.
    """
    x, z, u = _check_points(
        name,
        np.asarray(x_mm, dtype=np.float64),
        np.asarray(z_mm, dtype=np.float64),
        np.asarray(u_px, dtype=np.float64),
    )
    matrix, conditioning = direct_linear_transform(x, z, u)
    if conditioning < 1e-10:
        raise UserError(
            f"camera {name!r}: the {x.shape[0]} calibration points do not determine the "
            "camera (degenerate arrangement); add points at other heights and positions"
        )
    try:
        start = _physical_parameters(LineScanCamera(name, pixels, matrix))
    except ValueError as error:
        raise UserError(f"camera {name!r}: calibration points give no camera ({error})") from None

    fit_options = {"outlier_px": outlier_px, "outlier_sigmas": outlier_sigmas}
    if distortion is True and x.shape[0] < MIN_POINTS + 1:
        raise UserError(
            f"camera {name!r}: {x.shape[0]} calibration points, at least {MIN_POINTS + 1} "
            "are needed to estimate the distortion k1"
        )
    consider_k1 = distortion is True or (
        distortion is None
        and x.shape[0] >= DISTORTION_MIN_POINTS
        and np.ptp(u) >= DISTORTION_MIN_SPAN * pixels
    )
    if consider_k1:
        with_k1 = _robust_fit(name, np.append(start, 0.0), x, z, u, **fit_options)
        fit = with_k1
        if distortion is None and not _distortion_supported(with_k1, x, z, u, pixels):
            fit = _robust_fit(name, with_k1.parameters[:5], x, z, u, **fit_options)
    else:
        fit = _robust_fit(name, start, x, z, u, **fit_options)

    camera = _camera(name, pixels, fit.parameters)
    residuals = u - camera.project(x, z)
    used = residuals[fit.inliers]
    rms = float(np.sqrt(np.mean(used**2)))
    if not rms <= max_rms_px:
        raise UserError(
            f"camera {name!r}: reprojection RMS {rms:.3g} px over {used.shape[0]} points "
            f"exceeds {max_rms_px:g} px; the points do not fit one line-scan camera "
            "(wrong camera, units or target assignment?)"
        )
    return CameraCalibration(
        camera=camera,
        rms_px=rms,
        max_px=float(np.max(np.abs(used))),
        points_used=int(np.count_nonzero(fit.inliers)),
        points_rejected=int(np.count_nonzero(~fit.inliers)),
        residuals_px=residuals,
        inliers=fit.inliers,
    )


def _distortion_supported(
    with_k1: _Fit, x: FloatArray, z: FloatArray, u: FloatArray, pixels: int
) -> bool:
    """F-test of ``k1`` on the points ``with_k1`` kept, if they are enough and spread out."""
    inliers = with_k1.inliers
    n = int(np.count_nonzero(inliers))
    if n < DISTORTION_MIN_POINTS or np.ptp(u[inliers]) < DISTORTION_MIN_SPAN * pixels:
        return False
    without = _refine(with_k1.parameters[:5], x[inliers], z[inliers], u[inliers])
    rss_without = float(np.sum((u[inliers] - _predict(without, x[inliers], z[inliers])) ** 2))
    rss_with = with_k1.rss
    dof = n - with_k1.parameters.shape[0]
    if rss_with <= 0.0:
        return rss_without > 0.0
    statistic = (rss_without - rss_with) / (rss_with / dof)
    return bool(stats.f.sf(statistic, 1, dof) < DISTORTION_P_VALUE)


# -- the resolution look-up table --------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ResolutionTable:
    """Image resolution of one camera over the measurement range (the paper's look-up table).

    Attributes
    ----------
    x_mm : ndarray, shape (nx,)
        Lateral grid [mm], strictly increasing (the calibration targets' positions).
    z_mm : ndarray, shape (nz,)
        Height grid [mm], strictly increasing (the calibration bar's heights).
    mm_per_px : ndarray, shape (nz, nx)
        Resolution at each grid node [mm/px].
    filled : ndarray of bool, shape (nz, nx)
        True where a node was not measured but interpolated or extrapolated along ``x``.
    """

    x_mm: FloatArray
    z_mm: FloatArray
    mm_per_px: FloatArray
    filled: BoolArray

    def __post_init__(self) -> None:
        x = np.asarray(self.x_mm, dtype=np.float64)
        z = np.asarray(self.z_mm, dtype=np.float64)
        values = np.asarray(self.mm_per_px, dtype=np.float64)
        filled = np.asarray(self.filled, dtype=bool)
        if x.ndim != 1 or z.ndim != 1 or x.shape[0] < 1 or z.shape[0] < 1:
            raise ValueError("resolution table grids must be non-empty 1-D arrays")
        if np.any(np.diff(x) <= 0) or np.any(np.diff(z) <= 0):
            raise ValueError("resolution table grids must be strictly increasing")
        if values.shape != (z.shape[0], x.shape[0]) or filled.shape != values.shape:
            raise ValueError(
                f"resolution table values have shape {values.shape}, grids "
                f"({z.shape[0]}, {x.shape[0]})"
            )
        for field, value in (("x_mm", x), ("z_mm", z), ("mm_per_px", values), ("filled", filled)):
            value.setflags(write=False)
            object.__setattr__(self, field, value)

    def at(self, x_mm: ArrayLike, z_mm: ArrayLike) -> FloatArray:
        """Bilinear interpolation of the resolution [mm/px].

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        ndarray, broadcast shape
            Resolution [mm/px]. Outside the grid the border cells are extended linearly; a
            grid of one node along an axis is constant along it.
        """
        x, z = np.broadcast_arrays(
            np.asarray(x_mm, dtype=np.float64), np.asarray(z_mm, dtype=np.float64)
        )
        ix, tx = _cell(self.x_mm, x)
        iz, tz = _cell(self.z_mm, z)
        v = self.mm_per_px
        ix1 = np.minimum(ix + 1, self.x_mm.shape[0] - 1)
        iz1 = np.minimum(iz + 1, self.z_mm.shape[0] - 1)
        bottom = v[iz, ix] * (1.0 - tx) + v[iz, ix1] * tx
        top = v[iz1, ix] * (1.0 - tx) + v[iz1, ix1] * tx
        result = bottom * (1.0 - tz) + top * tz
        return np.asarray(np.where(np.isnan(x) | np.isnan(z), np.nan, result), np.float64)

    def at_cell(self, x_mm: ArrayLike, z_mm: ArrayLike) -> FloatArray:
        """The paper's cell-constant look-up: the value of the nearest grid node [mm/px].

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        ndarray, broadcast shape
            Resolution [mm/px] of the node nearest along each axis (for comparison with
            :meth:`at`).
        """
        x, z = np.broadcast_arrays(
            np.asarray(x_mm, dtype=np.float64), np.asarray(z_mm, dtype=np.float64)
        )
        ix = _nearest(self.x_mm, x)
        iz = _nearest(self.z_mm, z)
        result = self.mm_per_px[iz, ix]
        return np.asarray(np.where(np.isnan(x) | np.isnan(z), np.nan, result), np.float64)


def _cell(grid: FloatArray, values: FloatArray) -> tuple[IndexArray, FloatArray]:
    """Index of the grid cell holding each value and the fraction across it (any real)."""
    if grid.shape[0] == 1:
        return np.zeros(values.shape, dtype=np.intp), np.zeros(values.shape)
    index = np.clip(np.searchsorted(grid, values, side="right") - 1, 0, grid.shape[0] - 2)
    fraction = (values - grid[index]) / (grid[index + 1] - grid[index])
    return index, np.nan_to_num(fraction)


def _nearest(grid: FloatArray, values: FloatArray) -> IndexArray:
    if grid.shape[0] == 1:
        return np.zeros(values.shape, dtype=np.intp)
    index, fraction = _cell(grid, values)
    return np.clip(index + (fraction > 0.5), 0, grid.shape[0] - 1)


def build_resolution_table(
    x_mm: ArrayLike,
    z_mm: ArrayLike,
    width_px: ArrayLike,
    flat_width_mm: float,
    *,
    camera: str = "",
) -> ResolutionTable:
    """The look-up table from the calibration targets' flat-face widths (paper section 3.2).

    Each measured node's resolution is ``flat_width_mm / width_px``. Nodes a camera did not
    see are filled along ``x`` within their height row: linearly between measured nodes, and
    beyond the outermost measured nodes by a least-squares polynomial in ``x`` through the
    row's measured nodes (degree 2 with three or more, 1 with two, constant with one), which
    follows the smooth growth of the resolution toward the edge of the field better than a
    constant.

    Parameters
    ----------
    x_mm : array_like, shape (T,)
        Targets' positions [mm], distinct, any order.
    z_mm : array_like, shape (H,)
        Bar heights [mm], distinct, any order.
    width_px : array_like, shape (H, T)
        Flat-face width of each target at each height [px]; NaN (or not positive) where the
        target was not seen.
    flat_width_mm : float
        Width of the targets' flat faces [mm] (the paper: 6.0).
    camera : str, optional
        Camera name, for error messages.

    Returns
    -------
    ResolutionTable
        Grids sorted ascending; ``filled`` marks the nodes that were not measured.

    Raises
    ------
    catenary.errors.UserError
        When a whole height row was not seen, or the inputs' shapes disagree.
    """
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    widths = np.asarray(width_px, dtype=np.float64)
    who = f"camera {camera!r}: " if camera else ""
    if widths.shape != (z.shape[0], x.shape[0]) or x.ndim != 1 or z.ndim != 1:
        raise UserError(
            f"{who}target widths have shape {widths.shape}, expected "
            f"({z.shape[0]} heights, {x.shape[0]} targets)"
        )
    if not (math.isfinite(flat_width_mm) and flat_width_mm > 0.0):
        raise UserError(f"{who}flat_width_mm = {flat_width_mm} is not a positive length")
    x_order = np.argsort(x)
    z_order = np.argsort(z)
    x, z = x[x_order], z[z_order]
    if np.any(np.diff(x) <= 0) or np.any(np.diff(z) <= 0):
        raise UserError(f"{who}target positions or bar heights are repeated")
    widths = widths[np.ix_(z_order, x_order)]
    with np.errstate(invalid="ignore", divide="ignore"):
        seen = np.isfinite(widths) & (widths > 0.0)
        values = np.where(seen, flat_width_mm / widths, np.nan)
    missing_rows = np.flatnonzero(~seen.any(axis=1))
    if missing_rows.size:
        heights = ", ".join(f"{value:g}" for value in z[missing_rows])
        raise UserError(f"{who}no calibration target seen at bar height(s) {heights} mm")
    for row in np.flatnonzero(~seen.all(axis=1)):  # one loop step per incomplete height
        values[row] = _fill_row(x, values[row], seen[row])
    return ResolutionTable(x_mm=x, z_mm=z, mm_per_px=values, filled=~seen)


def _fill_row(x: FloatArray, values: FloatArray, seen: BoolArray) -> FloatArray:
    xs, vs = x[seen], values[seen]
    filled = np.interp(x, xs, vs)
    outside = (x < xs[0]) | (x > xs[-1])
    if np.any(outside):
        degree = min(2, xs.shape[0] - 1)
        if degree == 0:
            filled[outside] = vs[0]
        else:
            scale = max(float(np.ptp(x)), 1.0)
            coefficients = np.polynomial.polynomial.polyfit(xs / scale, vs, degree)
            filled[outside] = np.polynomial.polynomial.polyval(x[outside] / scale, coefficients)
    return np.where(seen, values, filled)


def resolution_table_from_camera(
    camera: LineScanCamera, x_mm: ArrayLike, z_mm: ArrayLike
) -> ResolutionTable:
    """The look-up table the camera model predicts on a grid (analytic ``1 / |du/dx|``).

    Parameters
    ----------
    camera : LineScanCamera
        A calibrated camera.
    x_mm : array_like, shape (nx,)
        Lateral grid [mm], strictly increasing.
    z_mm : array_like, shape (nz,)
        Height grid [mm], strictly increasing.

    Returns
    -------
    ResolutionTable
        ``mm_per_px[i, j] = camera.resolution_mm_per_px(x_mm[j], z_mm[i])``, nothing filled.
    """
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    values = camera.resolution_mm_per_px(x[np.newaxis, :], z[:, np.newaxis])
    return ResolutionTable(x, z, values, np.zeros(values.shape, dtype=bool))
