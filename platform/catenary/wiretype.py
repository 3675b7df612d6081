"""Contact wire profiles: residual thickness, worn area and worn fraction from wear width.

A grooved contact wire seen from below has a round lower part of radius ``R = B / 2``, with
``A`` the height of a new wire (its nominal residual thickness) and ``B`` its width. A flat
wear face of width ``w`` leaves (``reference/wire-profiles.md``; the paper's eq. 1 when
``A = B``)::

    h = (A - R) + sqrt(R**2 - (w / 2)**2)

and cuts off a circular segment of depth ``d = A - h``; the worn fraction is the segment's
area over the profile's cross-section. A worn fraction (an operator's limit) is turned back
into a wear width by bisection on the segment's half-angle (``wear_width_for_worn_area_mm``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray


class ProfileRangeError(ValueError):
    """A wear width or residual thickness outside what the profile can have."""


def residual_thickness_mm(
    wear_width_mm: ArrayLike, height_mm: float, width_mm: float
) -> FloatArray:
    """Residual thickness ``h`` [mm] from wear-face width ``w`` [mm], any shape.

    ``h = (A - R) + sqrt(R**2 - (w/2)**2)`` with ``A = height_mm``, ``R = width_mm / 2``.
    Widths must lie in ``[0, width_mm]``; the caller checks (see ``WireType``).
    """
    w = np.asarray(wear_width_mm, dtype=np.float64)
    radius = width_mm / 2.0
    return (height_mm - radius) + np.sqrt(np.maximum(radius**2 - (w / 2.0) ** 2, 0.0))


def wear_width_mm(
    residual_thickness_mm: ArrayLike, height_mm: float, width_mm: float
) -> FloatArray:
    """Wear-face width ``w`` [mm] from residual thickness ``h`` [mm]: the inverse of eq. 1.

    ``w = 2 sqrt(R**2 - (h - A + R)**2)``, for ``h`` in ``[A - R, A]``.
    """
    h = np.asarray(residual_thickness_mm, dtype=np.float64)
    radius = width_mm / 2.0
    offset = h - (height_mm - radius)
    return 2.0 * np.sqrt(np.maximum(radius**2 - offset**2, 0.0))


def worn_area_mm2(wear_width_mm: ArrayLike, width_mm: float) -> FloatArray:
    """Area [mm²] of the circular segment cut off by a flat face of width ``w`` [mm].

    ``R**2 * asin(c) - (w/2) * sqrt(R**2 - (w/2)**2)`` with ``c = w / (2R)``: the sector of
    half-angle ``asin(c)`` minus the triangle under the chord.
    """
    w = np.asarray(wear_width_mm, dtype=np.float64)
    radius = width_mm / 2.0
    half = np.minimum(w / 2.0, radius)
    area = radius**2 * np.arcsin(half / radius) - half * np.sqrt(radius**2 - half**2)
    return np.asarray(area, dtype=np.float64)


def _x_minus_sin_x(x: FloatArray) -> FloatArray:
    """``x - sin(x)`` without cancellation for small ``x`` (Taylor series below 0.1)."""
    x2 = x * x
    series = x * x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0)))
    return np.where(np.abs(x) < 0.1, series, x - np.sin(x))


def wear_width_for_worn_area_mm(
    worn_area_mm2: ArrayLike, width_mm: float, iterations: int = 64
) -> FloatArray:
    """Wear-face width ``w`` [mm] whose circular segment has area ``worn_area_mm2`` [mm²].

    The inverse of ``worn_area_mm2``, any shape. With ``theta`` the segment's half-angle the
    area is ``R**2 / 2 * (2 theta - sin 2 theta)`` (increasing on ``[0, pi/2]``) and
    ``w = 2 R sin(theta)``; ``theta`` is found by vectorised bisection, ``iterations`` halvings
    of ``[0, pi/2]`` (64 reach the float64 resolution, far below 1e-6 mm of thickness).
    Areas must lie in ``[0, pi R**2 / 2]`` (the caller checks); NaN stays NaN.
    """
    target = np.asarray(worn_area_mm2, dtype=np.float64)
    radius = width_mm / 2.0
    low = np.zeros_like(target)
    high = np.full_like(target, np.pi / 2.0)
    for _ in range(iterations):
        mid = 0.5 * (low + high)
        below = 0.5 * radius**2 * _x_minus_sin_x(2.0 * mid) < target
        low = np.where(below, mid, low)
        high = np.where(below, high, mid)
    width = 2.0 * radius * np.sin(0.5 * (low + high))
    return np.where(np.isnan(target), np.nan, width)


STANDARD_WORN_FRACTION = 0.30
"""The manufacturers' allowable wear (a 30 % wear mark, reference/wire-profiles.md): the
standard limit of a wire type with no published minimum residual thickness."""


@dataclass(frozen=True)
class WireType:
    """A contact wire profile registered by a wire-type plugin.

    ``height_mm`` (A) and ``width_mm`` (B) are the new wire's dimensions; ``area_mm2`` is the
    cross-section the worn fraction is taken of (the calculated area where the standard gives
    one). ``legacy`` marks profiles withdrawn from the current edition of their standard.
    ``published_min_mm`` is the profile's published minimum residual thickness (None: none
    published; its standard limit is then ``STANDARD_WORN_FRACTION``).
    """

    name: str
    standard: str
    height_mm: float
    width_mm: float
    area_mm2: float
    nominal_area_mm2: float
    legacy: bool = False
    source: str = ""
    published_min_mm: float | None = None

    def __post_init__(self) -> None:
        if not (self.height_mm > 0 and self.width_mm > 0 and self.area_mm2 > 0):
            raise ValueError(f"wire type {self.name!r}: dimensions must be positive")
        if self.height_mm < self.width_mm / 2:
            raise ValueError(
                f"wire type {self.name!r}: height {self.height_mm} mm is less than the "
                f"radius {self.width_mm / 2} mm of its round part"
            )
        low, high = self.min_residual_thickness_mm, self.height_mm
        if self.published_min_mm is not None and not low <= self.published_min_mm < high:
            raise ValueError(
                f"wire type {self.name!r}: published minimum {self.published_min_mm} mm is "
                f"outside its profile ({low:.2f} to {high:.2f} mm)"
            )

    @property
    def standard_limit(self) -> str:
        """The wire type's own standard limit in words: its published minimum, or the
        manufacturers' 30 % rule."""
        if self.published_min_mm is not None:
            return f"residual thickness {self.published_min_mm:g} mm (published minimum)"
        return (
            f"{100 * STANDARD_WORN_FRACTION:g} % loss of cross-section "
            "(the manufacturers' rule: no published minimum)"
        )

    @property
    def min_residual_thickness_mm(self) -> float:
        """Thickness left when the flat face spans the whole width (``A - R``) [mm]."""
        return self.height_mm - self.width_mm / 2.0

    @property
    def max_worn_fraction(self) -> float:
        """Worn fraction when the flat face spans the whole width (half the round part)."""
        return float(np.pi * (self.width_mm / 2.0) ** 2 / 2.0 / self.area_mm2)

    def _check_range(
        self, values: FloatArray, low: float, high: float, what: str, unit: str = " mm"
    ) -> None:
        # NaN (no measurement) passes through; infinities are outside every profile.
        bad = ~np.isnan(values) & ((values < low - 1e-9) | (values > high + 1e-9))
        if np.any(bad):
            first = float(values[bad].flat[0])
            raise ProfileRangeError(
                f"{what} {first:.3f}{unit} is outside wire type {self.name}'s profile "
                f"({low:.2f} to {high:.2f}{unit})"
            )

    def residual_thickness_mm(self, wear_width_mm: ArrayLike) -> FloatArray:
        """Residual thickness [mm] from wear width [mm] (any shape; NaN stays NaN)."""
        w = np.asarray(wear_width_mm, dtype=np.float64)
        self._check_range(w, 0.0, self.width_mm, "wear width")
        return residual_thickness_mm(w, self.height_mm, self.width_mm)

    def wear_width_mm(self, residual_thickness_mm: ArrayLike) -> FloatArray:
        """Wear width [mm] from residual thickness [mm] (any shape; NaN stays NaN)."""
        h = np.asarray(residual_thickness_mm, dtype=np.float64)
        self._check_range(h, self.min_residual_thickness_mm, self.height_mm, "residual thickness")
        return wear_width_mm(h, self.height_mm, self.width_mm)

    def worn_area_mm2(self, wear_width_mm: ArrayLike) -> FloatArray:
        """Worn cross-section [mm²] from wear width [mm]."""
        w = np.asarray(wear_width_mm, dtype=np.float64)
        self._check_range(w, 0.0, self.width_mm, "wear width")
        return worn_area_mm2(w, self.width_mm)

    def worn_fraction(self, wear_width_mm: ArrayLike) -> FloatArray:
        """Worn fraction of the cross-section (0 new, 0.2 = 20 % loss) from wear width [mm]."""
        return self.worn_area_mm2(wear_width_mm) / self.area_mm2

    def wear_width_for_worn_fraction(self, worn_fraction: ArrayLike) -> FloatArray:
        """Wear width [mm] at which the worn fraction is reached: the inverse of ``worn_fraction``.

        Fractions must lie in ``[0, max_worn_fraction]`` (any shape; NaN stays NaN).
        """
        f = np.asarray(worn_fraction, dtype=np.float64)
        self._check_range(f, 0.0, self.max_worn_fraction, "worn fraction", unit="")
        area = np.clip(f, 0.0, self.max_worn_fraction) * self.area_mm2
        return wear_width_for_worn_area_mm(area, self.width_mm)
