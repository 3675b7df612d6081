"""Wire-type geometry: published values, paper eq. 1, and properties of every registered type."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from catenary.plugins import PluginRegistry
from catenary.wiretype import ProfileRangeError, WireType

REGISTERED: dict[str, WireType] = PluginRegistry().wire_types()
NAMES = sorted(REGISTERED)
# The autouse environment fixture (tests/conftest.py) is harmless to share between examples.
PROPERTY = settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
UNIT = st.floats(0.0, 1.0, allow_nan=False)

# reference/wire-profiles.md, equivalents from the circular-segment model:
# wire -> {loss: (depth, residual thickness, flat width)} [mm]
EQUIVALENTS = {
    "AC-100": {0.20: (2.79, 9.21, 10.14), 0.25: (3.27, 8.73, 10.69), 0.30: (3.73, 8.27, 11.11)},
    "AC-120": {0.20: (3.06, 10.14, 11.14), 0.25: (3.58, 9.62, 11.74), 0.30: (4.08, 9.12, 12.20)},
    "CTA110": {0.20: (2.97, 9.37, 10.56), 0.25: (3.49, 8.85, 11.11), 0.30: (3.98, 8.36, 11.53)},
    "CTA120": {0.20: (3.10, 9.80, 11.03), 0.25: (3.64, 9.26, 11.61), 0.30: (4.15, 8.75, 12.05)},
}


@pytest.mark.parametrize(
    ("name", "loss"), [(name, loss) for name, row in EQUIVALENTS.items() for loss in row]
)
def test_equivalents_table(name: str, loss: float) -> None:
    wire = REGISTERED[name]
    depth, thickness, width = EQUIVALENTS[name][loss]
    w = float(wire.wear_width_for_worn_fraction(loss))
    h = float(wire.residual_thickness_mm(w))
    assert w == pytest.approx(width, abs=0.01)
    assert h == pytest.approx(thickness, abs=0.01)
    assert wire.height_mm - h == pytest.approx(depth, abs=0.01)
    assert float(wire.worn_fraction(w)) == pytest.approx(loss, abs=1e-12)


def test_paper_diameters() -> None:
    """The paper: CTA110 rated diameter 12.34 mm; TB/T 2809 size 120: 12.90 mm."""
    assert REGISTERED["CTA110"].height_mm == REGISTERED["CTA110"].width_mm == 12.34
    assert REGISTERED["CTA120"].height_mm == REGISTERED["CTA120"].width_mm == 12.90


def test_sensitivity_near_the_limit() -> None:
    """wire-profiles.md: dh/dw about -0.16 at 4 mm and -0.6 at 10 mm for CTA120."""
    wire, step = REGISTERED["CTA120"], 1e-6

    def slope(w: float) -> float:
        return float(
            wire.residual_thickness_mm(w + step) - wire.residual_thickness_mm(w - step)
        ) / (2 * step)

    assert slope(4.0) == pytest.approx(-0.16, abs=0.01)
    assert slope(10.0) == pytest.approx(-0.6, abs=0.05)


@pytest.mark.parametrize(
    "name", [n for n in NAMES if REGISTERED[n].height_mm == REGISTERED[n].width_mm]
)
@PROPERTY
@given(u=UNIT)
def test_paper_equation_1_when_height_equals_width(name: str, u: float) -> None:
    """h = r + sqrt(r^2 - (w/2)^2) (the paper's eq. 1) for a round profile, A = B = 2r."""
    wire = REGISTERED[name]
    r = wire.width_mm / 2
    w = u * wire.width_mm
    expected = r + math.sqrt(max(r * r - (w / 2) ** 2, 0.0))
    assert float(wire.residual_thickness_mm(w)) == pytest.approx(expected, abs=1e-12)


def test_general_form_when_height_and_width_differ() -> None:
    """TB/T 2809 size 150: A = 14.40, B = 14.10; h = (A - R) + sqrt(R^2 - (w/2)^2)."""
    wire = REGISTERED["CTA150"]
    assert float(wire.residual_thickness_mm(0.0)) == pytest.approx(14.40, abs=1e-12)
    assert float(wire.residual_thickness_mm(14.10)) == pytest.approx(14.40 - 7.05, abs=1e-12)
    w = 10.0
    expected = (14.40 - 7.05) + math.sqrt(7.05**2 - 25.0)
    assert float(wire.residual_thickness_mm(w)) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("name", NAMES)
@PROPERTY
@given(u1=UNIT, u2=UNIT)
def test_thickness_falls_with_width(name: str, u1: float, u2: float) -> None:
    wire = REGISTERED[name]
    w1, w2 = sorted((u1 * wire.width_mm, u2 * wire.width_mm))
    h1, h2 = float(wire.residual_thickness_mm(w1)), float(wire.residual_thickness_mm(w2))
    assert h2 <= h1
    if w2 - w1 > 1e-6:
        assert h2 < h1
        assert float(wire.worn_fraction(w2)) > float(wire.worn_fraction(w1))


@pytest.mark.parametrize("name", NAMES)
def test_thickness_strictly_decreasing_on_a_dense_grid(name: str) -> None:
    wire = REGISTERED[name]
    widths = np.linspace(0.0, wire.width_mm, 20001)
    assert np.all(np.diff(wire.residual_thickness_mm(widths)) < 0)
    assert np.all(np.diff(wire.worn_fraction(widths)) > 0)


@pytest.mark.parametrize("name", NAMES)
@PROPERTY
@given(u=UNIT)
def test_width_thickness_width_round_trip(name: str, u: float) -> None:
    """1e-9 mm wherever the thickness still carries the width in float64 (w >= 1e-4 mm)."""
    wire = REGISTERED[name]
    w = 1e-4 + u * (wire.width_mm - 1e-4)
    back = float(wire.wear_width_mm(wire.residual_thickness_mm(w)))
    assert back == pytest.approx(w, abs=1e-9)
    # Everywhere, down to a new wire: within 1e-6 mm.
    w0 = u * wire.width_mm
    assert float(wire.wear_width_mm(wire.residual_thickness_mm(w0))) == pytest.approx(w0, abs=1e-6)


@pytest.mark.parametrize("name", NAMES)
@PROPERTY
@given(u=UNIT)
def test_thickness_width_thickness_round_trip(name: str, u: float) -> None:
    wire = REGISTERED[name]
    low = wire.min_residual_thickness_mm
    h = low + 1e-4 + u * (wire.height_mm - low - 1e-4)
    assert float(wire.residual_thickness_mm(wire.wear_width_mm(h))) == pytest.approx(h, abs=1e-9)
    h0 = low + u * (wire.height_mm - low)
    back = float(wire.residual_thickness_mm(wire.wear_width_mm(h0)))
    assert back == pytest.approx(h0, abs=1e-6)


@pytest.mark.parametrize("name", NAMES)
@PROPERTY
@given(u=UNIT)
def test_worn_fraction_inverse(name: str, u: float) -> None:
    """Fraction -> width -> fraction; thickness within 1e-6 mm of an independent root."""
    wire = REGISTERED[name]
    fraction = u * wire.max_worn_fraction
    w = float(wire.wear_width_for_worn_fraction(fraction))
    # Near the full width the fraction grows ever faster with the width (dA/dw -> infinity),
    # so the last bit of the width moves the fraction by more than 1e-12 there.
    tolerance = 1e-12 if fraction <= 0.99 * wire.max_worn_fraction else 1e-7
    assert float(wire.worn_fraction(w)) == pytest.approx(fraction, abs=tolerance)
    if 1e-6 < fraction < wire.max_worn_fraction - 1e-6:
        root = brentq(
            lambda x: float(wire.worn_fraction(x)) - fraction, 0.0, wire.width_mm, xtol=1e-14
        )
        h_root = float(wire.residual_thickness_mm(root))
        assert float(wire.residual_thickness_mm(w)) == pytest.approx(h_root, abs=1e-6)


@pytest.mark.parametrize("name", NAMES)
def test_new_wire_has_no_wear(name: str) -> None:
    wire = REGISTERED[name]
    assert float(wire.residual_thickness_mm(0.0)) == pytest.approx(wire.height_mm, abs=1e-12)
    assert float(wire.worn_area_mm2(0.0)) == 0.0
    assert float(wire.worn_fraction(0.0)) == 0.0
    assert float(wire.wear_width_mm(wire.height_mm)) == pytest.approx(0.0, abs=1e-6)
    assert float(wire.wear_width_for_worn_fraction(0.0)) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_full_width_is_the_end_of_the_round_part(name: str) -> None:
    wire = REGISTERED[name]
    radius = wire.width_mm / 2
    assert float(wire.residual_thickness_mm(wire.width_mm)) == pytest.approx(
        wire.height_mm - radius, abs=1e-12
    )
    assert float(wire.worn_area_mm2(wire.width_mm)) == pytest.approx(math.pi * radius**2 / 2)
    assert float(wire.worn_fraction(wire.width_mm)) == pytest.approx(wire.max_worn_fraction)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("excess", [-0.5, 0.5, math.inf])
def test_widths_outside_the_profile_raise(name: str, excess: float) -> None:
    wire = REGISTERED[name]
    value = excess if excess < 0 else wire.width_mm + excess
    for call in (wire.residual_thickness_mm, wire.worn_area_mm2, wire.worn_fraction):
        with pytest.raises(ProfileRangeError) as caught:
            call(value)
        message = str(caught.value)
        assert wire.name in message
        assert f"{value:.3f}" in message
        assert "\n" not in message
    with pytest.raises(ProfileRangeError, match=wire.name):  # one bad value in an array
        wire.residual_thickness_mm([1.0, value, 2.0])


@pytest.mark.parametrize("name", NAMES)
def test_thickness_and_fraction_outside_the_profile_raise(name: str) -> None:
    wire = REGISTERED[name]
    for value in (wire.height_mm + 0.1, wire.min_residual_thickness_mm - 0.1):
        with pytest.raises(ProfileRangeError, match=f"residual thickness {value:.3f} mm"):
            wire.wear_width_mm(value)
    for fraction in (-0.01, wire.max_worn_fraction + 0.01):
        with pytest.raises(ProfileRangeError, match=f"worn fraction {fraction:.3f} is outside"):
            wire.wear_width_for_worn_fraction(fraction)


def test_arrays_and_scalars_alike() -> None:
    wire = REGISTERED["CTA120"]
    widths = np.array([[0.0, 4.0, 8.0], [10.0, 11.0, 12.9]])
    for call in (wire.residual_thickness_mm, wire.worn_area_mm2, wire.worn_fraction):
        result = call(widths)
        assert result.shape == widths.shape
        for index, w in np.ndenumerate(widths):
            scalar = call(float(w))
            assert np.ndim(scalar) == 0
            assert float(scalar) == pytest.approx(result[index], abs=1e-12)
        assert np.allclose(call(widths.tolist()), result, rtol=0, atol=1e-12)
    thickness = wire.residual_thickness_mm(widths)
    assert wire.wear_width_mm(thickness).shape == widths.shape
    fractions = wire.worn_fraction(widths)
    back = wire.wear_width_for_worn_fraction(fractions)
    assert back.shape == widths.shape
    assert np.allclose(back[widths > 1.0], widths[widths > 1.0], rtol=0, atol=1e-9)
    assert np.ndim(wire.wear_width_for_worn_fraction(0.2)) == 0


def test_nan_passes_through() -> None:
    wire = REGISTERED["AC-120"]
    widths = np.array([4.0, np.nan, 11.0])
    for call in (wire.residual_thickness_mm, wire.worn_area_mm2, wire.worn_fraction):
        result = call(widths)
        assert np.isnan(result[1])
        assert np.all(np.isfinite(result[[0, 2]]))
        assert np.isnan(call(math.nan))
    thickness = np.array([12.0, np.nan])
    assert np.isnan(wire.wear_width_mm(thickness)[1])
    assert np.isfinite(wire.wear_width_mm(thickness)[0])
    fractions = np.array([np.nan, 0.2])
    result = wire.wear_width_for_worn_fraction(fractions)
    assert np.isnan(result[0])
    assert float(result[1]) == pytest.approx(11.14, abs=0.01)
