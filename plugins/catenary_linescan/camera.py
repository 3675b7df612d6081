"""The projective line-scan camera: 2x3 matrix model with an optional radial term.

A line-scan camera images the ``x``-``z`` plane of the roof frame onto one line of pixels
(the paper's equation 8, FORMATS.md)::

    u_ideal = (m11 x + m12 z + m13) / (m21 x + m22 z + m23)

The matrix factors as ``M = s · M1 · M2`` (the paper's equations 4-6) with intrinsics
``M1 = [[f, u0, 0], [0, 1, 0]]`` and the rigid motion ``M2 = [[R, T], [0, 0, 1]]`` from the
roof frame to the camera frame, whose ``Zc`` axis is the optical axis and ``Xc`` the axis along
the line of pixels. So ``u_ideal = u0 + f · Xc / Zc``.

Lens distortion, which the paper does not model, is one radial term along the line: with the
normalised image coordinate ``xn = (u_ideal - u0) / f`` the pixel actually observed is::

    u_observed = u0 + f · xn · (1 + k1 · xn²)

:meth:`LineScanCamera.project` applies it; :meth:`LineScanCamera.ray` and
:func:`catenary_linescan.triangulation.triangulate` remove it first.

Conventions
-----------
- Roof frame in mm: ``x`` lateral (positive to the right looking in the direction of travel),
  ``z`` up. The centre of pixel ``i`` is at ``u = i``.
- The 2x3 model does not say which way a camera looks (a 2D rotation by 180° has determinant
  +1, so ``M`` and ``-M`` describe a camera and its mirror image looking backwards). The
  decomposition takes the optical axis to point upward (positive ``z`` component), as every
  roof-mounted camera does; rays point away from the camera into that half-plane.
- ``focal_px`` is signed: negative when the pixel index runs against the camera's ``Xc`` axis
  (a mirrored line).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import BoolArray, FloatArray

__all__ = ["LineScanCamera", "camera_from_pose"]

_NEWTON_MAX_ITERATIONS = 50
_NEWTON_TOLERANCE_PX = 1e-10


@dataclass(frozen=True, eq=False)
class LineScanCamera:
    """A calibrated line-scan camera (the paper's equation 8 plus a radial term).

    Parameters
    ----------
    name : str
        Camera name, as in the run and calibration files.
    pixels : int
        Number of pixels ``W`` on the line.
    matrix : array_like, shape (2, 3)
        Projection matrix ``M`` from roof-frame ``(x, z, 1)`` in [mm] to ``s · (u, 1)`` in [px].
        Any scale; :meth:`normalised` gives the FORMATS.md convention. Stored as a read-only
        float64 copy.
    k1 : float, default 0.0
        Radial distortion coefficient [-] on the normalised image coordinate (module docstring).

    Notes
    -----
    Instances compare equal when name, pixels, ``k1`` and the matrix's values are equal (not
    up to scale: compare ``normalised()`` copies for that).
    """

    name: str
    pixels: int
    matrix: FloatArray
    k1: float = 0.0

    def __post_init__(self) -> None:
        matrix = np.array(self.matrix, dtype=np.float64)
        if matrix.shape != (2, 3):
            raise ValueError(f"camera {self.name!r}: matrix has shape {matrix.shape}, not (2, 3)")
        if not np.all(np.isfinite(matrix)):
            raise ValueError(f"camera {self.name!r}: matrix has non-finite values")
        if math.hypot(matrix[1, 0], matrix[1, 1]) == 0.0:
            raise ValueError(f"camera {self.name!r}: matrix has m21 = m22 = 0 (no centre)")
        if matrix[0, 0] * matrix[1, 1] - matrix[0, 1] * matrix[1, 0] == 0.0:
            raise ValueError(f"camera {self.name!r}: matrix is singular (zero focal length)")
        if int(self.pixels) != self.pixels or self.pixels <= 0:
            raise ValueError(f"camera {self.name!r}: pixels = {self.pixels} is not positive")
        if not math.isfinite(self.k1):
            raise ValueError(f"camera {self.name!r}: k1 = {self.k1} is not finite")
        matrix.setflags(write=False)
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "pixels", int(self.pixels))
        object.__setattr__(self, "k1", float(self.k1))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LineScanCamera):
            return NotImplemented
        return (
            self.name == other.name
            and self.pixels == other.pixels
            and self.k1 == other.k1
            and bool(np.array_equal(self.matrix, other.matrix))
        )

    def __hash__(self) -> int:
        return hash((self.name, self.pixels, self.k1, self.matrix.tobytes()))

    # -- the matrix and its decomposition ----------------------------------------------------

    def normalised(self) -> LineScanCamera:
        """The same camera with ``M`` scaled so that ``(m21, m22, m23)`` has unit norm, ``m23 > 0``.

        This is the FORMATS.md storage convention. When ``m23 == 0`` (the roof origin lies on
        the camera's focal line) the sign makes ``m22 > 0`` (or ``m21 > 0`` if ``m22 == 0``).
        """
        row = self.matrix[1]
        sign = np.sign(row[row != 0.0][-1])  # of m23, else of m22, else of m21
        return LineScanCamera(
            self.name, self.pixels, self.matrix * (sign / np.linalg.norm(row)), self.k1
        )

    def _decomposition(self) -> tuple[float, float, float, FloatArray, FloatArray]:
        """``(scale, u0, f, r0, r1)``: ``M = scale · M1 · M2``; ``r0``, ``r1`` rows of ``R``."""
        m = self.matrix
        axis = m[1, :2]
        scale = float(np.hypot(axis[0], axis[1]))
        if m[1, 1] < 0.0 or (m[1, 1] == 0.0 and m[1, 0] < 0.0):
            scale = -scale
        r1 = axis / scale  # optical axis Zc, pointing up
        r0 = np.array([r1[1], -r1[0]])  # Xc, so that det([r0; r1]) = +1
        u0 = float(m[0, :2] @ r1) / scale
        f = float(m[0, :2] @ r0) / scale
        return scale, u0, f, r0, r1

    @property
    def principal_point_px(self) -> float:
        """Principal point ``u0`` [px] (paper equation 4)."""
        return self._decomposition()[1]

    @property
    def focal_px(self) -> float:
        """Focal length ``f`` [px] (paper equation 4); negative for a mirrored line."""
        return self._decomposition()[2]

    @property
    def optical_axis(self) -> FloatArray:
        """Unit vector ``(x, z)`` of the optical axis in the roof frame, shape (2,)."""
        return self._decomposition()[4].copy()

    @property
    def tilt_deg(self) -> float:
        """Angle of the optical axis from vertical [deg], positive toward ``+x``."""
        axis = self._decomposition()[4]
        return math.degrees(math.atan2(axis[0], axis[1]))

    @property
    def centre_mm(self) -> FloatArray:
        """Camera centre ``(x, z)`` [mm] in the roof frame, shape (2,): the null space of ``M``."""
        c = np.cross(self.matrix[0], self.matrix[1])
        return np.asarray(c[:2] / c[2], dtype=np.float64)

    # -- distortion -------------------------------------------------------------------------

    def distort(self, u_ideal_px: ArrayLike) -> FloatArray:
        """Observed pixel coordinate from the ideal (equation 8) one.

        Parameters
        ----------
        u_ideal_px : array_like, any shape
            Ideal image coordinate [px].

        Returns
        -------
        ndarray, same shape
            ``u0 + f · xn · (1 + k1 · xn²)`` with ``xn = (u_ideal - u0) / f`` [px].
        """
        u = np.asarray(u_ideal_px, dtype=np.float64)
        if self.k1 == 0.0:
            return u.copy()
        _, u0, f, _, _ = self._decomposition()
        xn = (u - u0) / f
        return np.asarray(u0 + f * xn * (1.0 + self.k1 * xn * xn), dtype=np.float64)

    def undistort(self, u_px: ArrayLike) -> FloatArray:
        """Ideal (equation 8) pixel coordinate from the observed one; inverse of :meth:`distort`.

        Solves ``xn + k1 · xn³ = (u - u0) / f`` by Newton's method, vectorised, to 1e-10 px.

        Parameters
        ----------
        u_px : array_like, any shape
            Observed image coordinate [px]; NaN passes through.

        Returns
        -------
        ndarray, same shape
            Ideal image coordinate [px]. NaN where there is no inverse on the monotonic branch
            through the principal point (only for ``k1 < 0``, beyond ``|xn| = 1/sqrt(-3 k1)``,
            far outside any real lens's field for the coefficients this model is meant for).
        """
        u = np.asarray(u_px, dtype=np.float64)
        if self.k1 == 0.0:
            return u.copy()
        _, u0, f, _, _ = self._decomposition()
        k1 = self.k1
        yn = (u - u0) / f
        xn = yn.copy()
        tolerance = _NEWTON_TOLERANCE_PX / abs(f)
        with np.errstate(invalid="ignore", divide="ignore"):
            for _ in range(_NEWTON_MAX_ITERATIONS):
                slope = 1.0 + 3.0 * k1 * xn * xn
                step = (xn + k1 * xn**3 - yn) / slope
                # stay on the branch through xn = 0, where the map is monotonic
                xn = np.where(slope > 0.0, xn - step, np.nan)
                if not np.any(np.abs(step) > tolerance):
                    break
            bad = ~(np.abs(xn + k1 * xn**3 - yn) <= 10.0 * tolerance) | ~(
                1.0 + 3.0 * k1 * xn * xn > 0.0
            )
        xn = np.where(bad, np.nan, xn)
        return np.asarray(u0 + f * xn, dtype=np.float64)

    # -- projection and back-projection -----------------------------------------------------

    def project(self, x_mm: ArrayLike, z_mm: ArrayLike) -> FloatArray:
        """Observed pixel coordinate of roof-frame points (equation 8, then distortion).

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        ndarray, broadcast shape
            Image coordinate ``u`` [px] (pixel ``i`` centred on ``u = i``); not clipped to the
            line. Points on the camera's focal line give ±inf or NaN.
        """
        return self.distort(self._project_ideal(x_mm, z_mm))

    def _project_ideal(self, x_mm: ArrayLike, z_mm: ArrayLike) -> FloatArray:
        x = np.asarray(x_mm, dtype=np.float64)
        z = np.asarray(z_mm, dtype=np.float64)
        m = self.matrix
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (m[0, 0] * x + m[0, 1] * z + m[0, 2]) / (m[1, 0] * x + m[1, 1] * z + m[1, 2])
        return np.asarray(u, dtype=np.float64)

    def project_jacobian(
        self, x_mm: ArrayLike, z_mm: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Observed pixel coordinate and its derivatives with respect to the position.

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        u_px : ndarray, broadcast shape
            As :meth:`project` [px].
        du_dx, du_dz : ndarray, broadcast shape
            Partial derivatives of ``u_px`` [px/mm], distortion included.
        """
        x = np.asarray(x_mm, dtype=np.float64)
        z = np.asarray(z_mm, dtype=np.float64)
        m = self.matrix
        with np.errstate(divide="ignore", invalid="ignore"):
            num = m[0, 0] * x + m[0, 1] * z + m[0, 2]
            den = m[1, 0] * x + m[1, 1] * z + m[1, 2]
            u_ideal = num / den
            du_dx = (m[0, 0] - u_ideal * m[1, 0]) / den
            du_dz = (m[0, 1] - u_ideal * m[1, 1]) / den
        if self.k1 != 0.0:
            _, u0, f, _, _ = self._decomposition()
            xn = (u_ideal - u0) / f
            gain = 1.0 + 3.0 * self.k1 * xn * xn
            du_dx = du_dx * gain
            du_dz = du_dz * gain
        return (
            self.distort(u_ideal),
            np.asarray(du_dx, dtype=np.float64),
            np.asarray(du_dz, dtype=np.float64),
        )

    def depth_mm(self, x_mm: ArrayLike, z_mm: ArrayLike) -> FloatArray:
        """Signed distance of points in front of the camera along its optical axis [mm].

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        ndarray, broadcast shape
            ``Zc`` [mm]: positive in front of (above) the camera, negative behind it.
        """
        x = np.asarray(x_mm, dtype=np.float64)
        z = np.asarray(z_mm, dtype=np.float64)
        axis = self._decomposition()[4]
        centre = self.centre_mm
        return np.asarray(axis[0] * (x - centre[0]) + axis[1] * (z - centre[1]), np.float64)

    def ray(self, u_px: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Back-projection: the half-line of roof-frame points that image at ``u_px``.

        Parameters
        ----------
        u_px : array_like, shape (...)
            Observed image coordinate [px]; distortion is removed first.

        Returns
        -------
        origin_mm : ndarray, shape (..., 2)
            The camera centre ``(x, z)`` [mm], repeated.
        direction : ndarray, shape (..., 2)
            Unit vector ``(dx, dz)`` [-] pointing away from the camera into the half-plane in
            front of it. Every ``origin + t · direction`` (``t > 0`` [mm]) projects to
            ``u_px``.
        """
        u = self.undistort(u_px)
        m = self.matrix
        p = m[0, 0] - u * m[1, 0]
        q = m[0, 1] - u * m[1, 1]
        # the ray's points satisfy p x + q z + r = 0: direction (q, -p), oriented forward
        direction = np.stack([q, -p], axis=-1)
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        axis = self._decomposition()[4]
        forward = direction @ axis
        direction *= np.where(forward < 0.0, -1.0, 1.0)[..., np.newaxis]
        origin = np.broadcast_to(self.centre_mm, direction.shape).copy()
        return origin, direction

    def resolution_mm_per_px(self, x_mm: ArrayLike, z_mm: ArrayLike) -> FloatArray:
        """Local image resolution along ``x`` at roof-frame points [mm/px]: ``1 / |du/dx|``.

        This is what the paper's look-up table measures (a horizontal flat face of known width
        divided by its width in pixels), from the model instead of from targets.

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        ndarray, broadcast shape
            Millimetres along ``x`` per observed pixel [mm/px], distortion included.
        """
        _, du_dx, _ = self.project_jacobian(x_mm, z_mm)
        with np.errstate(divide="ignore"):
            return np.asarray(1.0 / np.abs(du_dx), dtype=np.float64)

    def in_view(self, x_mm: ArrayLike, z_mm: ArrayLike) -> BoolArray:
        """Whether points are in front of the camera and image on the line [bool].

        Parameters
        ----------
        x_mm, z_mm : array_like, broadcastable
            Roof-frame position [mm].

        Returns
        -------
        ndarray of bool, broadcast shape
            True where ``depth > 0`` and ``-0.5 <= u < pixels - 0.5``.
        """
        u = self.project(x_mm, z_mm)
        with np.errstate(invalid="ignore"):
            return np.asarray(
                (self.depth_mm(x_mm, z_mm) > 0.0) & (u >= -0.5) & (u < self.pixels - 0.5),
                dtype=np.bool_,
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain values of the normalised camera: ``name``, ``pixels``, ``matrix``, ``k1``."""
        camera = self.normalised()
        return {
            "name": camera.name,
            "pixels": camera.pixels,
            "matrix": camera.matrix.tolist(),
            "k1": camera.k1,
        }


def camera_from_pose(
    name: str,
    pixels: int,
    centre_x_mm: float,
    centre_z_mm: float,
    tilt_deg: float,
    focal_px: float,
    u0_px: float,
    k1: float = 0.0,
) -> LineScanCamera:
    """A camera from its physical mounting: ``M = M1 · M2`` (paper equations 4-7).

    Parameters
    ----------
    name : str
        Camera name.
    pixels : int
        Number of pixels on the line.
    centre_x_mm, centre_z_mm : float
        Camera (lens) centre in the roof frame [mm].
    tilt_deg : float
        Angle of the optical axis from vertical [deg], positive toward ``+x``: the axis is
        ``(sin tilt, cos tilt)``. A camera on the left (``x < 0``) looking toward the centre
        has a positive tilt.
    focal_px : float
        Focal length [px] (lens focal length over pixel pitch); positive when ``u`` grows with
        ``x`` for a camera looking straight up.
    u0_px : float
        Principal point [px].
    k1 : float, default 0.0
        Radial distortion coefficient [-].

    Returns
    -------
    LineScanCamera
        With the matrix normalised as in FORMATS.md.
    """
    tilt = math.radians(tilt_deg)
    axis = np.array([math.sin(tilt), math.cos(tilt)])  # Zc in the roof frame
    across = np.array([axis[1], -axis[0]])  # Xc
    rotation = np.stack([across, axis])
    translation = -rotation @ np.array([centre_x_mm, centre_z_mm], dtype=np.float64)
    extrinsic = np.eye(3)
    extrinsic[:2, :2] = rotation
    extrinsic[:2, 2] = translation
    intrinsic = np.array([[focal_px, u0_px, 0.0], [0.0, 1.0, 0.0]])
    return LineScanCamera(name, pixels, intrinsic @ extrinsic, k1).normalised()
