"""The image sensor: electrons to grey levels, with noise, saturation and quantisation.

Per pixel, in this order:

1. photo-response non-uniformity: a fixed gain per pixel, ``N(1, prnu)``, the same for a
   camera in every run (seeded by the camera's name);
2. photon shot noise, Poisson in electrons;
3. full-well saturation: the charge is clipped at ``full_well_e`` (a sun-blinded pixel);
4. read noise, ``N(0, read_noise_e)``, added at read-out (after the clip).

   With ``shot_noise="poisson"`` (the default) the Poisson law is drawn exactly wherever the
   sum of shot and read noise is noticeably skewed (skewness ``λ / (λ + σr²)^1.5`` above
   :data:`SKEW_LIMIT`: few electrons and a quiet read-out), and elsewhere from the normal law
   of the same mean and variance, indistinguishable from it there and much faster to draw
   (for the demo rig's 20 e- read noise the skewness never exceeds 0.02, so no pixel needs
   the exact draw). Where the charge cannot come near the full well, shot and read noise are
   one normal draw of variance ``λ + σr²`` (the same law); pixels within six standard
   deviations of the full well, and exact-Poisson pixels, get the two draws and the clip in
   between. ``"gaussian"`` uses the normal law everywhere;
5. gain ``gain_dn_per_e`` plus ``black_level_dn``, rounded to the nearest grey level and
   clipped to ``0 .. 2**bit_depth - 1`` (ADC saturation).

Lines are uint8 for bit depths up to 8 and uint16 above (FORMATS.md).
"""

from __future__ import annotations

import math
import zlib

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import Float32Array, UInt8Array, UInt16Array

from .rig import SimCamera

__all__ = ["SHOT_NOISE", "SKEW_LIMIT", "expose", "prnu_map"]

SHOT_NOISE = ("poisson", "gaussian")
SKEW_LIMIT = 0.02
"""Skewness of shot plus read noise above which the Poisson law is drawn exactly."""


def prnu_map(camera: SimCamera) -> Float32Array:
    """The camera's fixed per-pixel gain ``[W]`` (mean 1, spread ``camera.prnu``)."""
    rng = np.random.default_rng(zlib.crc32(f"prnu:{camera.name}".encode()))
    gain = 1.0 + camera.prnu * rng.standard_normal(camera.pixels)
    return np.asarray(np.maximum(gain, 0.0), dtype=np.float32)


def expose(
    electrons: NDArray[np.floating],
    camera: SimCamera,
    rng: np.random.Generator | None,
    *,
    prnu: Float32Array | None = None,
    shot_noise: str = "poisson",
) -> UInt8Array | UInt16Array:
    """Grey levels ``[n, W]`` from the mean electrons ``[n, W]`` of each pixel.

    With ``rng`` None no noise is added (PRNU, saturation and quantisation still apply).
    """
    if shot_noise not in SHOT_NOISE:
        raise ValueError(f"shot_noise must be one of {', '.join(SHOT_NOISE)}, got {shot_noise!r}")
    signal = np.array(electrons, dtype=np.float32)  # a copy: worked on in place
    if prnu is not None:
        signal *= prnu[None, :]
    np.maximum(signal, 0.0, out=signal)
    full_well = np.float32(camera.full_well_e)
    if rng is None:
        np.minimum(signal, full_well, out=signal)
    else:
        mean = signal
        read2 = np.float32(camera.read_noise_e) ** 2
        z = rng.standard_normal(signal.shape, dtype=np.float32)
        # shot and read noise in one normal draw of variance λ + σr² where the charge cannot
        # reach the full well; near it (saturation clips the charge before read-out) and where
        # the Poisson law must be drawn exactly, shot and read noise are drawn separately
        signal = mean + np.sqrt(mean + read2) * z
        peak = float(mean.max(initial=0.0))
        if peak + 6.0 * math.sqrt(peak) > full_well:
            special = mean + 6.0 * np.sqrt(mean) > full_well
        else:
            special = np.zeros(mean.shape, dtype=bool)
        exact = np.zeros_like(special)
        # the skewness λ / (λ + σr²)^1.5 peaks at 0.385 / σr (at λ = 2 σr²)
        if shot_noise == "poisson" and 0.385 / max(math.sqrt(read2), 1e-12) > SKEW_LIMIT:
            exact = mean * mean > SKEW_LIMIT**2 * (mean + read2) ** 3
            special |= exact
        if np.any(special):
            lam = mean[special]
            shot = lam + np.sqrt(lam) * z[special]
            if shot_noise == "poisson":
                pick = exact[special]
                shot[pick] = rng.poisson(lam[pick]).astype(np.float32)
            np.minimum(shot, full_well, out=shot)
            read = rng.standard_normal(lam.shape, dtype=np.float32)
            signal[special] = shot + np.float32(camera.read_noise_e) * read
    signal *= np.float32(camera.gain_dn_per_e)
    signal += np.float32(camera.black_level_dn)
    np.rint(signal, out=signal)
    np.clip(signal, 0, camera.max_dn, out=signal)
    if camera.bit_depth <= 8:
        return signal.astype(np.uint8)
    return signal.astype(np.uint16)
