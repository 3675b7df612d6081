"""Vehicle compensation (FORMATS.md "Vehicle compensation model") and the vehicle TOML."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from catenary.domain import VehicleGeometry
from catenary.errors import FormatError, UserError
from catenary.measurement.vehicle import (
    load_vehicle_geometry,
    parse_vehicle_geometry,
    roll_rad,
    roof_to_track,
    track_to_roof,
)

GEOMETRY = VehicleGeometry(
    name="demo-rig", roof_height_mm=3900.0, sensor_height_mm=1100.0, sensor_baseline_mm=1800.0
)

# Left sensor 9 mm up, right 9 mm down over the 1800 mm baseline: tan(phi) = 18 / 1800 = 0.01.
SIN_PHI = 0.01 / math.sqrt(1.0001)
COS_PHI = 1.0 / math.sqrt(1.0001)


def test_roll_is_positive_with_the_left_side_up() -> None:
    assert roll_rad(9.0, -9.0, 1800.0) == pytest.approx(math.atan(0.01), abs=1e-15)
    assert roll_rad(9.0, -9.0, 1800.0) == pytest.approx(0.009999666686665238, abs=1e-15)
    assert roll_rad(-9.0, 9.0, 1800.0) == pytest.approx(-math.atan(0.01), abs=1e-15)
    assert roll_rad(20.0, 20.0, 1800.0) == 0.0
    np.testing.assert_allclose(
        roll_rad(np.array([0.0, 900.0]), np.array([0.0, -900.0]), 1800.0),
        [0.0, math.pi / 4],
        atol=1e-15,
    )


def test_nominal_ride_puts_the_roof_origin_at_roof_height() -> None:
    stagger, height = roof_to_track(120.0, 1500.0, 0.0, 0.0, 0.0, GEOMETRY)
    assert stagger == pytest.approx(120.0, abs=1e-9)
    assert height == pytest.approx(5400.0, abs=1e-9)


def test_lateral_offset_shifts_the_stagger() -> None:
    # Body 25 mm to the right: a wire 300 mm left of the roof centre is 275 mm left of track.
    stagger, height = roof_to_track(-300.0, 1600.0, 0.0, 0.0, 25.0, GEOMETRY)
    assert stagger == pytest.approx(-275.0, abs=1e-9)
    assert height == pytest.approx(5500.0, abs=1e-9)


def test_bounce_raises_the_height() -> None:
    # Both sensors 20 mm up: everything on the roof is 20 mm higher, stagger unchanged.
    stagger, height = roof_to_track(-300.0, 1600.0, 20.0, 20.0, 0.0, GEOMETRY)
    assert stagger == pytest.approx(-300.0, abs=1e-9)
    assert height == pytest.approx(5520.0, abs=1e-9)


def test_roll_left_side_up_moves_a_high_wire_to_the_right() -> None:
    # Wire 1500 mm above the roof centre, 4300 mm above B along the tilted up axis:
    # stagger = 4300 sin(phi) = 42.9979 mm, height = 1100 + 4300 cos(phi) = 5399.785 mm.
    stagger, height = roof_to_track(0.0, 1500.0, 9.0, -9.0, 0.0, GEOMETRY)
    assert stagger == pytest.approx(4300.0 * SIN_PHI, abs=1e-9)
    assert stagger == pytest.approx(42.99785016, abs=1e-7)
    assert height == pytest.approx(1100.0 + 4300.0 * COS_PHI, abs=1e-9)
    assert height == pytest.approx(5399.78501612, abs=1e-7)


def test_roll_right_side_up_moves_a_high_wire_to_the_left() -> None:
    stagger, height = roof_to_track(0.0, 1500.0, -9.0, 9.0, 0.0, GEOMETRY)
    assert stagger == pytest.approx(-4300.0 * SIN_PHI, abs=1e-9)
    assert height == pytest.approx(1100.0 + 4300.0 * COS_PHI, abs=1e-9)


def test_roll_lowers_the_right_side_of_the_roof() -> None:
    # A point on the roof 1000 mm right of the centre, left side up: it goes down.
    stagger, height = roof_to_track(1000.0, 0.0, 9.0, -9.0, 0.0, GEOMETRY)
    assert stagger == pytest.approx(2800.0 * SIN_PHI + 1000.0 * COS_PHI, abs=1e-9)
    assert height == pytest.approx(1100.0 + 2800.0 * COS_PHI - 1000.0 * SIN_PHI, abs=1e-9)
    assert height < 3900.0 - 9.0


def test_roll_bounce_and_sway_together() -> None:
    # left 29, right 11: the same roll as above, 20 mm of bounce; 25 mm of sway.
    stagger, height = roof_to_track(1000.0, 1500.0, 29.0, 11.0, 25.0, GEOMETRY)
    assert stagger == pytest.approx(25.0 + 4300.0 * SIN_PHI + 1000.0 * COS_PHI, abs=1e-9)
    assert height == pytest.approx(1120.0 + 4300.0 * COS_PHI - 1000.0 * SIN_PHI, abs=1e-9)


def test_track_to_roof_hand_case() -> None:
    x, z = track_to_roof(-275.0, 5520.0, 20.0, 20.0, 25.0, GEOMETRY)
    assert x == pytest.approx(-300.0, abs=1e-9)
    assert z == pytest.approx(1600.0, abs=1e-9)


def test_round_trip_roof_track_roof() -> None:
    rng = np.random.default_rng(7)
    n = 10_000
    x = rng.uniform(-800.0, 800.0, n)
    z = rng.uniform(800.0, 2500.0, n)
    left = rng.uniform(-60.0, 60.0, n)
    right = rng.uniform(-60.0, 60.0, n)
    lateral = rng.uniform(-120.0, 120.0, n)
    stagger, height = roof_to_track(x, z, left, right, lateral, GEOMETRY)
    x2, z2 = track_to_roof(stagger, height, left, right, lateral, GEOMETRY)
    np.testing.assert_allclose(x2, x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(z2, z, rtol=0, atol=1e-9)
    # and the other way round
    s2, h2 = roof_to_track(*track_to_roof(stagger, height, left, right, lateral, GEOMETRY),
                           left, right, lateral, GEOMETRY)  # fmt: skip
    np.testing.assert_allclose(s2, stagger, rtol=0, atol=1e-9)
    np.testing.assert_allclose(h2, height, rtol=0, atol=1e-9)


def test_the_transform_is_rigid() -> None:
    """Distances between points on the roof are kept in the track frame."""
    xs = np.array([-500.0, 400.0])
    zs = np.array([1200.0, 1900.0])
    stagger, height = roof_to_track(xs, zs, 35.0, -12.0, 8.0, GEOMETRY)
    assert math.hypot(*np.diff(stagger), *np.diff(height)) == pytest.approx(
        math.hypot(900.0, 700.0), abs=1e-9
    )


def test_broadcasting_many_wires_per_scan() -> None:
    rng = np.random.default_rng(1)
    x = rng.uniform(-600, 600, (5, 3))  # 5 scans, 3 wires
    z = 1500.0
    left = rng.uniform(-30, 30, (5, 1))
    right = rng.uniform(-30, 30, (5, 1))
    lateral = rng.uniform(-50, 50, (5, 1))
    stagger, height = roof_to_track(x, z, left, right, lateral, GEOMETRY)
    assert stagger.shape == height.shape == (5, 3)
    assert stagger.dtype == np.float64
    for i in range(5):
        for j in range(3):
            s, h = roof_to_track(x[i, j], z, left[i, 0], right[i, 0], lateral[i, 0], GEOMETRY)
            assert stagger[i, j] == pytest.approx(float(s), abs=1e-9)
            assert height[i, j] == pytest.approx(float(h), abs=1e-9)
    x2, z2 = track_to_roof(stagger, height, left, right, lateral, GEOMETRY)
    assert x2.shape == z2.shape == (5, 3)
    np.testing.assert_allclose(x2, x, atol=1e-9)
    np.testing.assert_allclose(z2, 1500.0, atol=1e-9)


def test_scalars_give_zero_dimensional_arrays() -> None:
    stagger, height = roof_to_track(0.0, 0.0, 0.0, 0.0, 0.0, GEOMETRY)
    assert isinstance(stagger, np.ndarray)
    assert stagger.shape == height.shape == ()
    assert roll_rad([1.0, 2.0], 0.0, 1800.0).shape == (2,)


def test_incompatible_shapes_raise() -> None:
    with pytest.raises(ValueError):
        roof_to_track(np.zeros(3), np.zeros(4), 0.0, 0.0, 0.0, GEOMETRY)


# -- vehicle TOML --------------------------------------------------------------------------

GOOD_TOML = """\
name = "demo-rig"
roof_height_mm = 3900.0      # roof origin above top of rail, nominal ride
sensor_height_mm = 1100      # an integer is a number
sensor_baseline_mm = 1800.0
operator = "extra keys are ignored"
"""


def write(tmp_path: Path, text: str, name: str = "vehicle.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_load_vehicle_geometry(tmp_path: Path) -> None:
    geometry = load_vehicle_geometry(write(tmp_path, GOOD_TOML))
    assert geometry == GEOMETRY
    assert isinstance(geometry.sensor_height_mm, float)


def test_name_defaults_to_the_file_stem(tmp_path: Path) -> None:
    text = "\n".join(line for line in GOOD_TOML.splitlines() if not line.startswith("name"))
    assert load_vehicle_geometry(write(tmp_path, text, "car-4711.toml")).name == "car-4711"


@pytest.mark.parametrize(
    ("replace", "by", "needles"),
    [
        ("sensor_baseline_mm = 1800.0", "", ["missing key sensor_baseline_mm"]),
        ("roof_height_mm = 3900.0", 'roof_height_mm = "3900"', ["roof_height_mm", "'3900'"]),
        ("roof_height_mm = 3900.0", "roof_height_mm = true", ["roof_height_mm", "True"]),
        ("roof_height_mm = 3900.0", "roof_height_mm = [3900.0]", ["roof_height_mm"]),
        ("sensor_height_mm = 1100", "sensor_height_mm = -1100", ["sensor_height_mm", "-1100"]),
        ("sensor_baseline_mm = 1800.0", "sensor_baseline_mm = 0.0", ["sensor_baseline_mm", "0.0"]),
        ("sensor_baseline_mm = 1800.0", "sensor_baseline_mm = nan", ["sensor_baseline_mm", "nan"]),
        ("sensor_baseline_mm = 1800.0", "sensor_baseline_mm = inf", ["sensor_baseline_mm", "inf"]),
        ('name = "demo-rig"', "name = 4", ["name", "4"]),
        (  # the roof below the sensors
            "roof_height_mm = 3900.0",
            "roof_height_mm = 900",
            ["key roof_height_mm = 900 is not above sensor_height_mm = 1100"],
        ),
        ("roof_height_mm = 3900.0", "roof_height_mm = 1100.0", ["roof_height_mm = 1100.0 is not"]),
        (
            'name = "demo-rig"',
            f'name = "{"v" * 201}"',
            ["key name is 201 characters long (at most 200)"],
        ),
        ("sensor_baseline_mm = 1800.0", "sensor_baseline_mm = ", ["not valid TOML"]),
    ],
)
def test_bad_vehicle_toml_names_the_file_and_key(
    tmp_path: Path, replace: str, by: str, needles: list[str]
) -> None:
    path = write(tmp_path, GOOD_TOML.replace(replace, by))
    with pytest.raises(FormatError) as info:
        load_vehicle_geometry(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)


def test_missing_vehicle_toml_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no such file"):
        load_vehicle_geometry(tmp_path / "nope.toml")


def test_parse_vehicle_geometry_names_nested_keys() -> None:
    with pytest.raises(FormatError, match=r"rig\.toml: missing key vehicle\.roof_height_mm"):
        parse_vehicle_geometry({"sensor_height_mm": 1.0}, "rig.toml", prefix="vehicle.")
    below = {"roof_height_mm": 1000.0, "sensor_height_mm": 1100.0, "sensor_baseline_mm": 1800.0}
    with pytest.raises(
        FormatError, match=r"rig\.toml: key vehicle\.roof_height_mm = 1000\.0 is not"
    ):
        parse_vehicle_geometry(below, "rig.toml", prefix="vehicle.")
