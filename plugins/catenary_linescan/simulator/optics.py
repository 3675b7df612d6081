"""A simulated camera's optics: rays of sub-pixel positions, relative illumination and blur.

- **Rays**: the angle from vertical of the ray that images at ``u`` (distortion included) is
  tabulated from the true camera model every 1/32 px and linearly interpolated (the angle is
  smooth in ``u``; the error is below 1e-9 rad).
- **Relative illumination**: ``(8 / N)²`` (the aperture relative to f/8, the unit of
  :mod:`.radiometry`) times the camera's relative exposure time (``SimCamera.exposure``)
  times the natural vignetting ``cos⁴`` of the field angle.
- **Blur**: the line spread of a defocused thin lens is the projection of a uniform disc of
  diameter ``b`` (:meth:`SimCamera.defocus_diameter_px`), whose Fourier transform is the jinc
  ``2 J1(π b ν) / (π b ν)``; diffraction (``0.42 λ N``) and aberrations (``lens_blur_px``) are
  Gaussian. The optical transfer function is their product, applied per object at its own
  distance (:mod:`.render`). Pixel integration (the box of one pixel) is done separately and
  exactly by the renderer.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from catenary.arrays import FloatArray
from catenary_linescan.camera import LineScanCamera

from .rig import SimCamera

__all__ = ["CameraOptics"]

_TABLE_STEPS_PER_PX = 32
_DIAMETER_STEP_PX = 0.01
_CACHE_MAX_SAMPLES = 2048  # only narrow windows (wires) are cached ...
_CACHE_ENTRIES = 512  # ... and at most 512 of them (8 MiB)


class CameraOptics:
    """Optics of one simulated camera, with its true model and ray table.

    Parameters
    ----------
    camera : SimCamera
    wavelength_nm : float
        Light the camera sees (diffraction).
    pad_px : int
        The ray table covers ``u`` from ``-pad_px`` to ``pixels - 1 + pad_px``.
    """

    def __init__(self, camera: SimCamera, wavelength_nm: float, pad_px: int = 96) -> None:
        self.camera = camera
        self.model: LineScanCamera = camera.model()
        self.centre_mm: FloatArray = np.array([camera.x_mm, camera.z_mm], dtype=np.float64)
        self.pixels = camera.pixels
        self.pad_px = int(pad_px)
        self._u_start = -float(self.pad_px) - 0.5
        count = (self.pixels + 2 * self.pad_px) * _TABLE_STEPS_PER_PX + 1
        u = self._u_start + np.arange(count) / _TABLE_STEPS_PER_PX
        _, direction = self.model.ray(u)
        angle = np.arctan2(direction[:, 0], direction[:, 1])
        if not np.all(np.isfinite(angle)) or not (
            np.all(np.diff(angle) > 0) or np.all(np.diff(angle) < 0)
        ):
            raise ValueError(
                f"camera {camera.name!r}: rays are not monotonic over the line (distortion "
                f"k1 = {camera.k1} too strong for the field of view)"
            )
        self._angle_table = angle
        self._transfer_cache: dict[tuple[int, int, int], FloatArray] = {}
        self.sigma_px = math.hypot(camera.diffraction_sigma_px(wavelength_nm), camera.lens_blur_px)
        pixel_u = np.arange(self.pixels, dtype=np.float64)
        field = self.ray_angle(pixel_u) - math.radians(camera.tilt_deg)
        self.relative_illumination: FloatArray = (
            (8.0 / camera.f_number) ** 2 * camera.exposure * np.cos(field) ** 4
        )
        self.pixel_angle: FloatArray = self.ray_angle(pixel_u)

    def ray_angle(self, u_px: FloatArray) -> FloatArray:
        """Angle from vertical [rad] (positive toward ``+x``) of the rays imaging at ``u_px``.

        ``u_px`` any shape, within the table (``-pad_px`` to ``pixels - 1 + pad_px``); values
        outside are clamped to its ends.
        """
        position = (np.asarray(u_px, dtype=np.float64) - self._u_start) * _TABLE_STEPS_PER_PX
        last = self._angle_table.shape[0] - 1
        position = np.clip(position, 0.0, last - 1e-9)
        index = position.astype(np.intp)
        frac = position - index
        table = self._angle_table
        return np.asarray(table[index] * (1.0 - frac) + table[index + 1] * frac, np.float64)

    def directions(self, u_px: FloatArray) -> FloatArray:
        """Unit ray directions ``(..., 2)`` for image positions ``u_px`` (any shape)."""
        angle = self.ray_angle(u_px)
        return np.stack([np.sin(angle), np.cos(angle)], axis=-1)

    def transfer(self, freq_per_px: FloatArray, depth_mm: FloatArray) -> FloatArray:
        """Optical transfer function ``[r, L]`` at frequencies ``[L]`` [cycles/px] for objects
        at depths ``[r]`` [mm] (defocus disc, diffraction and aberrations)."""
        diameter = self.camera.defocus_diameter_px(depth_mm)
        x = math.pi * diameter[:, None] * np.abs(freq_per_px)[None, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            jinc = np.where(x < 1e-6, 1.0, 2.0 * special.j1(x) / x)
        gauss = np.exp(-2.0 * (math.pi * self.sigma_px * freq_per_px) ** 2)
        return np.asarray(jinc * gauss[None, :], dtype=np.float64)

    def sampled_transfer(self, samples: int, subsamples: int, depth_mm: FloatArray) -> FloatArray:
        """DFT ``[r, samples]`` of the blur acting on sub-pixel averages (spacing ``1/S``).

        A sub-pixel holds the average of the image over its width ``h = 1/S``; the average of
        the blurred image over another sub-pixel is then a sum over sub-pixels with the kernel
        ``PSF ⊗ triangle(h)`` sampled every ``h``: non-negative (no ringing), summing to one
        (energy is conserved) and exact for an image constant within each sub-pixel. Its DFT
        is the alias sum ``Σ_k OTF(ν + k S) · sinc²((ν + k S) / S)``, taken over the ``k``
        where the Gaussian part of the OTF is above 1e-12. Rows are grouped by blur diameter
        in steps of 0.01 px (a blur changed by 0.005 px is not measurable).
        """
        diameter = self.camera.defocus_diameter_px(depth_mm)
        bins = np.round(diameter / _DIAMETER_STEP_PX).astype(np.int64)
        unique, inverse = np.unique(bins, return_inverse=True)
        table = np.stack([self._sampled(samples, subsamples, int(b)) for b in unique])
        return np.asarray(table[inverse.reshape(-1)], dtype=np.float64)

    def _sampled(self, samples: int, subsamples: int, diameter_bin: int) -> FloatArray:
        key = (samples, subsamples, diameter_bin)
        cached = self._transfer_cache.get(key)
        if cached is not None:
            return cached
        diameter = diameter_bin * _DIAMETER_STEP_PX
        freq = np.fft.fftfreq(samples, d=1.0 / subsamples)
        sigma = max(self.sigma_px, 1e-3)
        # aliases beyond (|k| - 1/2) S > reach add less than 1e-12
        reach = math.sqrt(math.log(1e12) / (2.0 * math.pi**2 * sigma**2))
        aliases = max(1, math.ceil(reach / subsamples + 0.5))
        total = np.zeros(samples)
        for k in range(-aliases, aliases + 1):
            shifted = freq + k * subsamples
            x = math.pi * diameter * np.abs(shifted)
            with np.errstate(invalid="ignore", divide="ignore"):
                jinc = np.where(x < 1e-6, 1.0, 2.0 * special.j1(x) / x)
            gauss = np.exp(-2.0 * (math.pi * self.sigma_px * shifted) ** 2)
            total += jinc * gauss * np.sinc(shifted / subsamples) ** 2
        if samples <= _CACHE_MAX_SAMPLES:
            if len(self._transfer_cache) >= _CACHE_ENTRIES:
                self._transfer_cache.clear()
            self._transfer_cache[key] = total
        return total

    def blur_reach_px(self, depth_mm: FloatArray) -> float:
        """How far [px] the blur of objects at ``depth_mm`` spreads (for window margins)."""
        diameter = float(np.max(self.camera.defocus_diameter_px(depth_mm), initial=0.0))
        return diameter / 2.0 + 4.0 * self.sigma_px + 1.0
