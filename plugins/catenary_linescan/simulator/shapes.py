"""Cross-sections of catenary objects in the scanning plane: silhouettes and ray hits.

Every object the cameras see is, in the scanning plane (the roof frame's ``x``-``z`` plane), a
convex 2-D shape. Two kinds cover the scene, each held as a batch of ``r`` shapes (one per
scan row, every field an array ``[r]``) in the roof frame [mm]:

- :class:`WireSection`: a round wire cut by the plane, an ellipse of semi-axes
  ``(semi_x_mm, semi_z_mm)`` (a circle of radius ``R`` widened along ``x`` by ``1/cos θ``
  when the plane cuts a staggered wire obliquely), optionally cut by a flat worn face: the
  chord at local height ``face_z_mm`` below the centre (``-semi_z_mm`` for a round wire).
- :class:`Bar`: a rectangle of half sizes ``(half_width_mm, half_height_mm)``, for droppers,
  clamps, steady arms and cantilever tubes. A cylinder cut off its axis by the plane is a
  rectangle whose curved faces have a surface normal partly out of the plane:
  ``normal_scale_x``/``normal_scale_z`` give the in-plane length of the normal of the faces
  across ``x`` and ``z`` (1 for flat faces).

Each shape has a local frame: origin at its centre ``(centre_x_mm, centre_z_mm)`` and axes
rotated by ``angle_rad`` counter-clockwise from the roof frame's (the car body's roll turns
the track-frame objects by ``+roll`` in the roof frame). Rays are half-lines from the camera
centre ``origin`` (shape ``(2,)``) along unit directions ``[r, m, 2]``.
"""

from __future__ import annotations

from dataclasses import Field, dataclass, fields, replace
from typing import Any, ClassVar, Self

import numpy as np

from catenary.arrays import FloatArray, IndexArray

__all__ = ["Bar", "Hit", "WireSection"]


@dataclass(frozen=True)
class Hit:
    """Where rays hit a surface: points and in-plane surface normals, each ``[r, m, 2]``.

    ``normal`` has length 1 on flat or in-plane curved faces and less on faces whose normal
    leaves the plane (its in-plane component).
    """

    point: FloatArray
    normal: FloatArray


def _to_local(
    centre_x: FloatArray,
    centre_z: FloatArray,
    c: FloatArray,
    s: FloatArray,
    x: FloatArray | float,
    z: FloatArray | float,
) -> tuple[FloatArray, FloatArray]:
    """Roof-frame points to the local frame (rotate by -angle; ``c, s`` its cosine, sine)."""
    dx = x - centre_x
    dz = z - centre_z
    return dx * c + dz * s, -dx * s + dz * c


def _dir_to_local(
    c: FloatArray, s: FloatArray, dx: FloatArray, dz: FloatArray
) -> tuple[FloatArray, FloatArray]:
    return dx * c + dz * s, -dx * s + dz * c


def _to_roof(
    centre_x: FloatArray,
    centre_z: FloatArray,
    c: FloatArray,
    s: FloatArray,
    x: FloatArray,
    z: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    return centre_x + x * c - z * s, centre_z + x * s + z * c


def _vec_to_roof(
    c: FloatArray, s: FloatArray, x: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray]:
    return x * c - z * s, x * s + z * c


class _Batch:
    """Row selection and the rotation's cosine and sine, shared by the shape batches.

    Each subclass is a frozen dataclass with (at least) these fields.
    """

    __dataclass_fields__: ClassVar[dict[str, Field[Any]]]
    centre_x_mm: FloatArray
    angle_rad: FloatArray

    def take(self, rows: IndexArray) -> Self:
        """The shapes of the given rows (an index array into ``[r]``)."""
        taken = replace(self, **{f.name: getattr(self, f.name)[rows] for f in fields(self)})
        cached = self.__dict__.get("_rotation")
        if cached is not None:
            object.__setattr__(taken, "_rotation", (cached[0][rows], cached[1][rows]))
        return taken

    @property
    def rows(self) -> int:
        return int(self.centre_x_mm.shape[0])

    def rotation(self) -> tuple[FloatArray, FloatArray]:
        """``(cos, sin)`` of ``angle_rad``, ``[r]`` each (computed once)."""
        cached = self.__dict__.get("_rotation")
        if cached is None:
            angle = self.angle_rad
            cached = (np.cos(angle), np.sin(angle))
            object.__setattr__(self, "_rotation", cached)
        return cached


@dataclass(frozen=True)
class WireSection(_Batch):
    """A batch of round wire sections with an optional flat face at the bottom (module doc)."""

    centre_x_mm: FloatArray
    centre_z_mm: FloatArray
    angle_rad: FloatArray
    semi_x_mm: FloatArray
    semi_z_mm: FloatArray
    face_z_mm: FloatArray

    @property
    def face_half_width_mm(self) -> FloatArray:
        """Half width of the flat face in the plane [mm] (0 for a round wire)."""
        ratio = np.clip(self.face_z_mm / self.semi_z_mm, -1.0, 1.0)
        return np.asarray(self.semi_x_mm * np.sqrt(1.0 - ratio * ratio), dtype=np.float64)

    def face_corners(self) -> tuple[FloatArray, FloatArray]:
        """Roof-frame ``x``, ``z`` of the face's two ends, each ``[r, 2]`` (left, right local)."""
        half = self.face_half_width_mm
        lx = np.stack([-half, half], axis=1)
        lz = np.stack([self.face_z_mm, self.face_z_mm], axis=1)
        c, s = self.rotation()
        return _to_roof(
            self.centre_x_mm[:, None], self.centre_z_mm[:, None], c[:, None], s[:, None], lx, lz
        )

    def contact_point(self) -> tuple[FloatArray, FloatArray]:
        """Roof-frame ``x``, ``z`` of the face's centre (the bottom of a round wire), ``[r]``."""
        zero = np.zeros_like(self.face_z_mm)
        c, s = self.rotation()
        return _to_roof(self.centre_x_mm, self.centre_z_mm, c, s, zero, self.face_z_mm)

    def bottom_z_mm(self) -> FloatArray:
        """Roof-frame height of the lowest point, ``[r]``."""
        return self.contact_point()[1]

    def outline_points(self, origin: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Points whose extreme rays from ``origin`` bound the silhouette.

        Returns roof-frame ``x``, ``z`` ``[r, 4]`` and ``valid`` ``[r, 4]``: the two tangent
        points of the ellipse (valid when not cut away by the face) and the face's ends.
        """
        c, s = self.rotation()
        ox, oz = _to_local(self.centre_x_mm, self.centre_z_mm, c, s, origin[0], origin[1])
        sx = ox / self.semi_x_mm
        sz = oz / self.semi_z_mm
        rho = np.maximum(np.hypot(sx, sz), 1.0 + 1e-12)
        gamma = np.arctan2(sz, sx)
        delta = np.arccos(1.0 / rho)
        angles = np.stack([gamma + delta, gamma - delta], axis=1)
        tx = self.semi_x_mm[:, None] * np.cos(angles)
        tz = self.semi_z_mm[:, None] * np.sin(angles)
        valid_t = tz >= self.face_z_mm[:, None] - 1e-9
        half = self.face_half_width_mm[:, None]
        lx = np.concatenate([tx, np.concatenate([-half, half], axis=1)], axis=1)
        lz = np.concatenate([tz, np.repeat(self.face_z_mm[:, None], 2, axis=1)], axis=1)
        valid = np.concatenate([valid_t, np.ones_like(valid_t)], axis=1)
        x, z = _to_roof(
            self.centre_x_mm[:, None], self.centre_z_mm[:, None], c[:, None], s[:, None], lx, lz
        )
        return x, z, valid

    def hit_round(self, origin: FloatArray, direction: FloatArray) -> Hit:
        """First hit of rays ``[r, m, 2]`` on the full ellipse (ignoring the face cut).

        Rays that graze or just miss (sub-pixel samples at the silhouette) are taken to the
        tangent point. Used for the parts of a pixel outside the face interval, where the
        real surface is the round part.
        """
        c, s = (v[:, None] for v in self.rotation())
        cx = self.centre_x_mm[:, None]
        cz = self.centre_z_mm[:, None]
        ox, oz = _to_local(cx, cz, c, s, origin[0], origin[1])
        dx, dz = _dir_to_local(c, s, direction[..., 0], direction[..., 1])
        ax = self.semi_x_mm[:, None]
        az = self.semi_z_mm[:, None]
        oxs, ozs, dxs, dzs = ox / ax, oz / az, dx / ax, dz / az
        qa = dxs * dxs + dzs * dzs
        qb = oxs * dxs + ozs * dzs
        qc = oxs * oxs + ozs * ozs - 1.0
        disc = np.maximum(qb * qb - qa * qc, 0.0)
        t = (-qb - np.sqrt(disc)) / qa
        px = ox + t * dx
        pz = oz + t * dz
        nx = px / (ax * ax)
        nz = pz / (az * az)
        norm = np.hypot(nx, nz)
        nx, nz = _vec_to_roof(c, s, nx / norm, nz / norm)
        wx, wz = _to_roof(cx, cz, c, s, px, pz)
        return Hit(np.stack([wx, wz], axis=-1), np.stack([nx, nz], axis=-1))

    def hit_face(self, origin: FloatArray, direction: FloatArray) -> Hit:
        """Hit of rays ``[r, m, 2]`` on the plane of the flat face; its normal points down."""
        c, s = (v[:, None] for v in self.rotation())
        cx = self.centre_x_mm[:, None]
        cz = self.centre_z_mm[:, None]
        ox, oz = _to_local(cx, cz, c, s, origin[0], origin[1])
        dx, dz = _dir_to_local(c, s, direction[..., 0], direction[..., 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.face_z_mm[:, None] - oz) / dz
        px = ox + t * dx
        pz = np.broadcast_to(self.face_z_mm[:, None], px.shape)
        wx, wz = _to_roof(cx, cz, c, s, px, pz)
        # the local normal (0, -1) in the roof frame
        nx = np.broadcast_to(s, px.shape)
        nz = np.broadcast_to(-c, px.shape)
        return Hit(np.stack([wx, wz], axis=-1), np.stack([nx, nz], axis=-1))


@dataclass(frozen=True)
class Bar(_Batch):
    """A batch of rectangles (droppers, clamps, arms, tubes) in the scanning plane (module doc)."""

    centre_x_mm: FloatArray
    centre_z_mm: FloatArray
    angle_rad: FloatArray
    half_width_mm: FloatArray
    half_height_mm: FloatArray
    normal_scale_x: FloatArray
    normal_scale_z: FloatArray

    def corners(self) -> tuple[FloatArray, FloatArray]:
        """Roof-frame ``x``, ``z`` of the four corners, each ``[r, 4]``."""
        hw = self.half_width_mm[:, None]
        hh = self.half_height_mm[:, None]
        lx = np.concatenate([-hw, hw, hw, -hw], axis=1)
        lz = np.concatenate([-hh, -hh, hh, hh], axis=1)
        c, s = self.rotation()
        return _to_roof(
            self.centre_x_mm[:, None], self.centre_z_mm[:, None], c[:, None], s[:, None], lx, lz
        )

    def outline_points(self, origin: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The four corners (roof ``x``, ``z`` ``[r, 4]``) and ``valid`` (all true)."""
        x, z = self.corners()
        return x, z, np.ones(x.shape, dtype=bool)

    def bottom_z_mm(self) -> FloatArray:
        """Roof-frame height of the lowest corner, ``[r]``."""
        return np.asarray(self.corners()[1].min(axis=1), dtype=np.float64)

    def hit(self, origin: FloatArray, direction: FloatArray) -> Hit:
        """First hit of rays ``[r, m, 2]`` on the rectangle (slab method).

        Rays that just miss (samples at the silhouette) are taken to the nearest face.
        """
        c, s = (v[:, None] for v in self.rotation())
        cx = self.centre_x_mm[:, None]
        cz = self.centre_z_mm[:, None]
        ox, oz = _to_local(cx, cz, c, s, origin[0], origin[1])
        dx, dz = _dir_to_local(c, s, direction[..., 0], direction[..., 1])
        hw = self.half_width_mm[:, None]
        hh = self.half_height_mm[:, None]
        tiny = 1e-12
        dxs = np.where(np.abs(dx) < tiny, tiny, dx)
        dzs = np.where(np.abs(dz) < tiny, tiny, dz)
        tx = np.minimum((-hw - ox) / dxs, (hw - ox) / dxs)
        tz = np.minimum((-hh - oz) / dzs, (hh - oz) / dzs)
        across_x = tx > tz
        t = np.where(across_x, tx, tz)
        px = ox + t * dx
        pz = oz + t * dz
        nx = np.where(across_x, -np.sign(dxs) * self.normal_scale_x[:, None], 0.0)
        nz = np.where(across_x, 0.0, -np.sign(dzs) * self.normal_scale_z[:, None])
        nx, nz = _vec_to_roof(c, s, nx, nz)
        wx, wz = _to_roof(cx, cz, c, s, px, pz)
        return Hit(np.stack([wx, wz], axis=-1), np.stack([nx, nz], axis=-1))
