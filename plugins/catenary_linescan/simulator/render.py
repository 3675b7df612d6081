"""Render what a line-scan camera sees: objects over the sky, per pixel, for a block of scans.

For one camera and a block of ``n`` scans the renderer returns the electrons each pixel
collects (before noise, :mod:`.sensor`), ``[n, W]``:

1. **Background**: the sky along every pixel's ray (:class:`.radiometry.Sky`), smooth, taken at
   the pixel centres.
2. **Objects**, each a :class:`Layer`: a batch of 2-D cross-sections (:mod:`.shapes`) in some
   rows of the block. Per row the silhouette ``[a, b]`` and the flat face ``[fa, fb]`` are
   exact image intervals (extreme rays through tangent points and face corners, projected by
   the true camera model with its distortion). Each pixel of a window around the object is
   split into ``subsamples`` equal sub-pixels; a sub-pixel's coverage is the exact length of
   its overlap with the silhouette (and with the face), so edges are exact to rounding and
   the energy of an object is conserved whatever the sub-sampling. Radiance is evaluated by
   tracing the ray through the middle of the covered part of each sub-pixel to the surface
   (round part or flat face) and shading it (:func:`.radiometry.surface_radiance_e`).
3. **Blur** per object at its own distance (defocus, diffraction, aberrations: the optical
   transfer function of :class:`.optics.CameraOptics`, as the exact discrete operator on
   sub-pixel averages) applied to the object's coverage and premultiplied radiance on the
   sub-pixel grid by FFT (``coverage + i·radiance`` in one complex transform). A partly
   covered sub-pixel's content is first shared with its neighbour so that its centroid is
   where the covered part lies: edges then do not move with the sub-pixel size.
4. **Pixel integration**: the mean of each pixel's sub-pixels (the box of the pixel).
5. **Occlusion**: objects are composited far to near with the "over" operator on coverage,
   ordered by the height of their lowest point (descending). For the catenary seen from below
   this order is exact: anything wholly above another object's lowest point cannot hide it
   from a camera below, since rays only rise. Compositing at pixel level assumes what lies
   behind is uniform within a pixel (exact for the sky; a pixel holding the edges of two
   overlapping objects at once is mixed approximately).
6. **Relative illumination** of the camera (aperture, ``cos⁴`` vignetting) scales the result.

Everything is vectorised over the rows and the pixels of a window; the Python loop is over
layers only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sfft

from catenary.arrays import Float32Array, FloatArray, IndexArray

from .optics import CameraOptics
from .radiometry import Material, Sky, surface_radiance_e
from .rig import Lamp
from .shapes import Bar, WireSection

__all__ = ["Layer", "LayerFootprint", "Lighting", "footprint", "render_electrons", "sky_e"]

DEFAULT_SUBSAMPLES = 2


@dataclass(frozen=True)
class Lighting:
    """What lights the surfaces: the roof lamps and, by day, ambient light [e-, f/8]."""

    lamps: tuple[Lamp, ...]
    lamp_e: float
    beam_sigma_deg: float
    ambient_e: float

    def radiance(
        self, point: FloatArray, normal: FloatArray, view: FloatArray, m: Material
    ) -> FloatArray:
        """Radiance toward the camera of surface points (:func:`surface_radiance_e`)."""
        return surface_radiance_e(
            point, normal, view, m, self.lamps, self.lamp_e, self.beam_sigma_deg, self.ambient_e
        )


@dataclass(frozen=True)
class Layer:
    """Objects of one kind in some rows of a block.

    ``rows`` ``[r]`` are indices into the block; ``shape`` holds one cross-section per row;
    ``material`` shades the shape (the round part of a wire), ``face_material`` a wire's
    flat face.
    """

    name: str
    rows: IndexArray
    shape: WireSection | Bar
    material: Material
    face_material: Material | None = None


@dataclass(frozen=True)
class LayerFootprint:
    """Where a layer falls in one camera: image intervals per row [px] (``[r]`` each).

    ``face_left/right`` are NaN for shapes without a face; ``depth_mm`` is the distance along
    the optical axis of the shape's centre.
    """

    left: FloatArray
    right: FloatArray
    face_left: FloatArray
    face_right: FloatArray
    depth_mm: FloatArray


def footprint(optics: CameraOptics, shape: WireSection | Bar) -> LayerFootprint:
    """The silhouette and face intervals of ``shape`` in the camera, per row."""
    model = optics.model
    x, z, valid = shape.outline_points(optics.centre_mm)
    u = model.project(x, z)
    u = np.where(valid, u, np.nan)
    with np.errstate(invalid="ignore"):
        left = np.nanmin(u, axis=1)
        right = np.nanmax(u, axis=1)
    if isinstance(shape, WireSection):
        fx, fz = shape.face_corners()
        fu = model.project(fx, fz)
        face_left = fu.min(axis=1)
        face_right = fu.max(axis=1)
    else:
        face_left = np.full(left.shape, np.nan)
        face_right = np.full(left.shape, np.nan)
    depth = model.depth_mm(shape.centre_x_mm, shape.centre_z_mm)
    return LayerFootprint(left, right, face_left, face_right, depth)


def _coverage(
    lo: FloatArray, hi: FloatArray, a: FloatArray, b: FloatArray, inv_step: float
) -> tuple[FloatArray, FloatArray]:
    """Fraction of each sub-pixel ``[lo, hi]`` inside ``[a, b]`` and the middle of that part."""
    start = np.maximum(lo, a)
    stop = np.minimum(hi, b)
    cover = np.clip((stop - start) * inv_step, 0.0, 1.0)
    middle = np.where(cover > 0.0, 0.5 * (start + stop), 0.5 * (lo + hi))
    return cover, middle


def _shade(
    colour: FloatArray,
    moment: FloatArray,
    cover: FloatArray,
    middle: FloatArray,
    centre: FloatArray,
    shape: WireSection | Bar,
    optics: CameraOptics,
    lighting: Lighting,
    material: Material,
    surface: str,
) -> None:
    """Add ``cover · radiance`` to ``colour`` ``[r, m]`` where ``cover > 0`` (only there).

    ``surface`` is ``"round"`` or ``"face"`` for a wire, ``"bar"`` for a bar; the ray through
    ``middle`` (the covered part's middle) is traced to it and shaded. ``moment`` gets the
    contribution times its offset ``middle - centre`` from the sub-pixel's centre.
    """
    rows, cols = np.nonzero(cover > 0.0)
    if rows.shape[0] == 0:
        return
    direction = optics.directions(middle[rows, cols])[:, None, :]
    part = shape.take(rows)
    if surface == "round":
        hit = part.hit_round(optics.centre_mm, direction)  # type: ignore[union-attr]
    elif surface == "face":
        hit = part.hit_face(optics.centre_mm, direction)  # type: ignore[union-attr]
    else:
        hit = part.hit(optics.centre_mm, direction)  # type: ignore[union-attr]
    radiance = lighting.radiance(hit.point[:, 0], hit.normal[:, 0], -direction[:, 0], material)
    contribution = cover[rows, cols] * radiance
    colour[rows, cols] += contribution
    moment[rows, cols] += contribution * (middle[rows, cols] - centre[rows, cols])


def _place_moments(values: FloatArray, moment: FloatArray, step: float) -> FloatArray:
    """Share each sub-pixel's content with a neighbour so its centroid is where it lies.

    A partly covered sub-pixel holds content whose centroid is ``moment / values`` off its
    centre; moving the fraction ``|offset| / step`` of it to the neighbour on that side keeps
    its sum and its first moment, so a symmetric blur then puts it exactly where it belongs
    (without this, sub-pixels of width ``step`` would displace edges by up to ``step / 4``).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = np.where(values > 0.0, moment / values, 0.0) / step
    offset = np.clip(offset, -0.5, 0.5)
    moved = np.abs(offset) * values
    out = values - moved
    out[:, :-1] += np.where(offset[:, 1:] < 0.0, moved[:, 1:], 0.0)
    out[:, 1:] += np.where(offset[:, :-1] > 0.0, moved[:, :-1], 0.0)
    return out


def _fast_width(width: int, subsamples: int) -> int:
    """The smallest width >= ``width`` whose sub-pixel count is a fast FFT length."""
    while sfft.next_fast_len(width * subsamples) != width * subsamples:
        width += 1
    return width


def _layer_window(
    optics: CameraOptics,
    layer: Layer,
    fp: LayerFootprint,
    subsamples: int,
    blur: bool,
    lighting: Lighting,
) -> tuple[IndexArray, IndexArray, FloatArray, FloatArray] | None:
    """Coverage and premultiplied radiance of a layer on pixel windows.

    Returns ``(rows, first_col, alpha, colour)`` with ``alpha``/``colour`` ``[r, w]`` for
    pixels ``first_col + arange(w)`` (in line coordinates, possibly in the pad), or None.
    """
    pixels = optics.pixels
    pad = optics.pad_px
    keep = (
        np.isfinite(fp.left)
        & np.isfinite(fp.right)
        & (fp.right > -pad + 2.0)
        & (fp.left < pixels - 1 + pad - 2.0)
    )
    if not np.any(keep):
        return None
    idx = np.flatnonzero(keep)
    shape = layer.shape.take(idx)
    a = fp.left[idx]
    b = fp.right[idx]
    depth = fp.depth_mm[idx]
    margin = int(np.ceil(optics.blur_reach_px(depth))) + 1 if blur else 1
    lo_limit = -pad
    hi_limit = pixels + pad  # exclusive
    first = np.maximum(np.floor(a + 0.5).astype(np.intp) - margin, lo_limit)
    last = np.minimum(np.floor(b + 0.5).astype(np.intp) + margin + 1, hi_limit)
    width = min(_fast_width(int(np.max(last - first)), subsamples), hi_limit - lo_limit)
    samples = width * subsamples
    first = np.minimum(first, hi_limit - width)

    step = 1.0 / subsamples
    offsets = (np.arange(samples) + 0.5) * step - 0.5
    centre = first[:, None] + offsets[None, :]
    lo = centre - 0.5 * step
    hi = centre + 0.5 * step
    cover, middle = _coverage(lo, hi, a[:, None], b[:, None], subsamples)
    colour = np.zeros_like(cover)
    moment = np.zeros_like(cover)
    centre_b = np.broadcast_to(centre, cover.shape)
    if isinstance(shape, WireSection):
        fa = fp.face_left[idx][:, None]
        fb = fp.face_right[idx][:, None]
        face_cover, face_middle = _coverage(lo, hi, fa, fb, subsamples)
        face_cover = np.minimum(face_cover, cover)
        side_cover = cover - face_cover
        # where a sub-pixel holds a face edge, shade the side through the side part's middle
        edge = (face_cover > 0.0) & (side_cover > 0.0)
        if np.any(edge):
            start = np.maximum(lo, a[:, None])
            stop = np.minimum(hi, b[:, None])
            left_part = np.minimum(stop, fa) > start  # side to the left of the face
            side_middle = np.where(
                left_part,
                0.5 * (start + np.minimum(stop, fa)),
                0.5 * (np.maximum(start, fb) + stop),
            )
            side_mid = np.where(edge, side_middle, middle)
        else:
            side_mid = middle
        _shade(
            colour,
            moment,
            side_cover,
            side_mid,
            centre_b,
            shape,
            optics,
            lighting,
            layer.material,
            "round",
        )
        if layer.face_material is not None:
            _shade(
                colour,
                moment,
                face_cover,
                face_middle,
                centre_b,
                shape,
                optics,
                lighting,
                layer.face_material,
                "face",
            )
    else:
        _shade(
            colour,
            moment,
            cover,
            middle,
            centre_b,
            shape,
            optics,
            lighting,
            layer.material,
            "bar",
        )
    alpha = cover
    if blur:
        alpha = _place_moments(alpha, cover * (middle - centre), step)
        colour = _place_moments(colour, moment, step)
        otf = optics.sampled_transfer(samples, subsamples, depth)
        spectrum = sfft.fft(alpha + 1j * colour, axis=1)
        spectrum *= otf
        blurred = sfft.ifft(spectrum, axis=1)
        alpha = np.clip(blurred.real, 0.0, 1.0)
        colour = np.maximum(blurred.imag, 0.0)
    alpha_px = alpha.reshape(idx.shape[0], width, subsamples).mean(axis=2)
    colour_px = colour.reshape(idx.shape[0], width, subsamples).mean(axis=2)
    return layer.rows[idx], first, alpha_px, colour_px


def render_electrons(
    optics: CameraOptics,
    layers: Sequence[Layer],
    background_e: NDArray[np.floating],
    lighting: Lighting,
    *,
    subsamples: int = DEFAULT_SUBSAMPLES,
    blur: bool = True,
    footprints: Sequence[LayerFootprint] | None = None,
) -> Float32Array:
    """Electrons per pixel ``[n, W]`` (float32) of one camera for a block of scans.

    Parameters
    ----------
    optics : CameraOptics
    layers : sequence of Layer
        The objects; painted in order of decreasing lowest point (module docstring).
    background_e : ndarray ``[n, W]``
        Sky radiance per pixel [e-, f/8 on axis].
    lighting : Lighting
    subsamples : int
        Sub-pixels per pixel for shading and blur (coverage is exact regardless).
    blur : bool
        Apply the optical transfer function (off: a perfectly sharp lens).
    footprints : sequence of LayerFootprint, optional
        Precomputed :func:`footprint` of each layer in this camera.
    """
    n, pixels = background_e.shape
    pad = optics.pad_px
    buffer = np.zeros((n, pixels + 2 * pad), dtype=np.float32)
    buffer[:, pad : pad + pixels] = background_e
    buffer[:, :pad] = background_e[:, :1]
    buffer[:, pad + pixels :] = background_e[:, -1:]
    prints = (
        [footprint(optics, layer.shape) for layer in layers] if footprints is None else footprints
    )
    order = sorted(
        range(len(layers)),
        key=lambda i: (
            -float(np.median(layers[i].shape.bottom_z_mm())) if layers[i].shape.rows else 0.0
        ),
    )
    for i in order:
        layer = layers[i]
        if layer.rows.shape[0] == 0:
            continue
        window = _layer_window(optics, layer, prints[i], subsamples, blur, lighting)
        if window is None:
            continue
        rows, first, alpha, colour = window
        cols = pad + first[:, None] + np.arange(alpha.shape[1])[None, :]
        r = rows[:, None]
        buffer[r, cols] = buffer[r, cols] * (1.0 - alpha) + colour
    out = buffer[:, pad : pad + pixels]
    out *= optics.relative_illumination.astype(np.float32)[None, :]
    return out


def sky_e(optics: CameraOptics, sky: Sky, distance_m: FloatArray, knots: int = 65) -> Float32Array:
    """Sky radiance ``[n, W]`` (float32) along each pixel's ray for scans at ``distance_m``.

    The sky is smooth: it is evaluated at ``knots`` angles across the line and interpolated.
    """
    angle = optics.pixel_angle
    knot_index = np.linspace(0.0, angle.shape[0] - 1.0, knots)
    knot_angle = np.interp(knot_index, np.arange(angle.shape[0]), angle)
    values = sky.radiance_e(knot_angle, np.asarray(distance_m, dtype=np.float64))
    # linear interpolation from the knots to the pixels as a (knots, W) matrix product
    position = np.arange(angle.shape[0]) * (knots - 1) / (angle.shape[0] - 1.0)
    index = np.minimum(position.astype(np.intp), knots - 2)
    frac = position - index
    weights = np.zeros((knots, angle.shape[0]), dtype=np.float32)
    columns = np.arange(angle.shape[0])
    weights[index, columns] = 1.0 - frac
    weights[index + 1, columns] += frac
    return values.astype(np.float32) @ weights
