"""Generated rigs (simulator/rigs.py): layout, field of view, resolution and calibration."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from catenary_linescan.calibrate import calibrate_from_captures, rig_from_reports
from catenary_linescan.simulator.captures import write_captures
from catenary_linescan.simulator.rig import parse_rig
from catenary_linescan.simulator.rigs import generate_rig
from catenary_linescan.simulator.sensor import expose

SHAPES = [(2, 2048, 8), (3, 4096, 10), (4, 8192, 12), (6, 16384, 16)]


@pytest.mark.parametrize(("cameras", "pixels", "bit_depth"), SHAPES)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_camera_sees_the_measuring_field(
    seed: int, cameras: int, pixels: int, bit_depth: int
) -> None:
    rig = generate_rig(
        seed, cameras=cameras, pixels=pixels, bit_depth=bit_depth, roof_height_mm=4200.0
    )
    assert len(rig.cameras) == cameras
    assert rig.vehicle.roof_height_mm == 4200.0
    assert {(c.pixels, c.bit_depth) for c in rig.cameras} == {(pixels, bit_depth)}
    xs = [c.x_mm for c in rig.cameras]
    assert xs == sorted(xs) and xs[0] < -400 and xs[-1] > 400
    assert all(np.sign(c.tilt_deg) == -np.sign(c.x_mm) for c in rig.cameras)
    x = np.linspace(-600.0, 600.0, 13)
    for cam in rig.cameras:
        model = cam.model()
        for height in (1300.0, 1900.0, 2500.0):
            assert model.in_view(x, height).all(), (cam.name, height)
        # the field fills most of the line: not a wide lens wasting pixels
        u = model.project(np.array([-600.0, 600.0]), 1300.0)
        assert abs(u[1] - u[0]) > 0.6 * pixels


def test_resolution_follows_the_pixel_count() -> None:
    """Finest resolution at 1300 mm above the roof: about 0.3 mm/px for 4096 px (the paper's
    rig), proportionally finer for longer lines."""
    finest = {}
    for pixels in (2048, 4096, 8192, 16384):
        rig = generate_rig(4, cameras=4, pixels=pixels, bit_depth=8)
        x = np.linspace(-400.0, 400.0, 9)
        finest[pixels] = min(
            float(c.model().resolution_mm_per_px(x, 1300.0).min()) for c in rig.cameras
        )
    assert 0.2 < finest[4096] < 0.4
    for pixels in (2048, 8192, 16384):
        assert finest[pixels] == pytest.approx(finest[4096] * 4096 / pixels, rel=0.25)


def test_the_seed_decides_and_the_text_reproduces_the_rig() -> None:
    a = generate_rig(9, cameras=5, pixels=4096, bit_depth=12)
    assert generate_rig(9, cameras=5, pixels=4096, bit_depth=12) == a
    assert generate_rig(10, cameras=5, pixels=4096, bit_depth=12) != a
    again = parse_rig(tomllib.loads(a.text), "again", text=a.text)
    assert again == a


@pytest.mark.parametrize("pixels", [2048, 8192])  # f/4 and f/16
def test_gain_fills_the_bit_depth(pixels: int) -> None:
    """The lines look alike at any aperture: the full well's worth of light at f/8 fills the
    range (through the gain or the exposure time)."""
    for bits in (8, 12, 16):
        cam = generate_rig(3, cameras=2, pixels=pixels, bit_depth=bits).cameras[0]
        at_f8 = cam.gain_dn_per_e * cam.full_well_e * (8.0 / cam.f_number) ** 2 * cam.exposure
        assert at_f8 == pytest.approx(2**bits - 1)


@pytest.mark.parametrize("pixels", [2048, 8192])
def test_the_sensor_saturates_at_the_top_of_the_range(pixels: int) -> None:
    """A full well reads the range's top, never a grey level below it (at a wide aperture the
    exposure is shortened, not the gain lowered): a clipped pixel is recognisable."""
    for bits in (8, 10, 16):
        cam = generate_rig(3, cameras=2, pixels=pixels, bit_depth=bits).cameras[0]
        assert int(expose(np.full((1, 4), 1e9), cam, None).max()) == 2**bits - 1


@pytest.mark.parametrize("bad", [{"cameras": 1}, {"cameras": 7}, {"pixels": 3000}])
def test_out_of_range_shapes_are_refused(bad: dict[str, int]) -> None:
    shape = {"cameras": 3, "pixels": 4096, "bit_depth": 8, **bad}
    with pytest.raises(ValueError):
        generate_rig(0, **shape)


@pytest.mark.parametrize(("cameras", "pixels", "bit_depth"), [(2, 2048, 8), (3, 8192, 12)])
def test_a_generated_rig_calibrates_from_its_captures(
    tmp_path: Path, cameras: int, pixels: int, bit_depth: int
) -> None:
    """Targets assigned with the nominal poses (no distortion, principal point mid-line):
    every camera calibrates, the model within a pixel of the truth over the field."""
    sim_rig = generate_rig(11, cameras=cameras, pixels=pixels, bit_depth=bit_depth)
    captures, _ = write_captures(tmp_path / "captures.h5", sim_rig, seed=7)
    reports = calibrate_from_captures(
        captures, distortion=None, approximate=sim_rig.nominal_models()
    )
    rig = rig_from_reports(sim_rig.vehicle, reports, source=captures.name)
    x = np.linspace(-600.0, 600.0, 25)
    for cam in sim_rig.cameras:
        got = rig.cameras[cam.name].camera
        for height in (1300.0, 1900.0, 2500.0):
            error = np.abs(got.project(x, height) - cam.model().project(x, height))
            assert error.max() < 1.0, (cam.name, height, error.max())
