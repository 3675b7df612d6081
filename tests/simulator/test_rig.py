"""The rig file and the demo rig's geometry (the paper's Table 1 and field of view)."""

from __future__ import annotations

import numpy as np
import pytest

from catenary.errors import FormatError, UserError
from catenary.measurement.vehicle import load_vehicle_geometry
from catenary_linescan.simulator.rig import SimRig, load_rig
from catenary_linescan.simulator.settings import DEMO_RIG_PATH


def test_demo_rig_has_four_4096_pixel_cameras_across_the_roof(demo_rig: SimRig) -> None:
    assert [c.pixels for c in demo_rig.cameras] == [4096] * 4
    xs = [c.x_mm for c in demo_rig.cameras]
    assert xs == sorted(xs) and xs[0] < -500 and xs[-1] > 500
    # tilted toward the centre
    assert all(np.sign(c.tilt_deg) == -np.sign(c.x_mm) for c in demo_rig.cameras)
    # one lens with noticeable distortion: > 5 px at the ends of the line
    shifts = []
    for cam in demo_rig.cameras:
        model = cam.model()
        shifts.append(float(np.max(np.abs(model.distort(np.array([0.0, 4095.0])) - [0, 4095]))))
    assert max(shifts) > 5.0


def test_demo_rig_resolution_is_the_papers_at_1300_mm(demo_rig: SimRig) -> None:
    """Table 1: 0.27-0.33 mm/px over x = -400..400 at 1300 mm above the roof."""
    x = np.arange(-400.0, 401.0, 100.0)
    for cam in demo_rig.cameras:
        res = cam.model().resolution_mm_per_px(x, 1300.0)
        assert res.min() == pytest.approx(0.27, abs=0.02)
        if abs(cam.x_mm) < 500:  # the inner cameras, like the paper's second one
            assert res.max() < 0.36


@pytest.mark.parametrize("height", [1300.0, 1600.0, 2000.0, 2500.0])
def test_every_camera_sees_600_mm_either_side(demo_rig: SimRig, height: float) -> None:
    for cam in demo_rig.cameras:
        visible = cam.model().in_view(np.array([-600.0, 0.0, 600.0]), height)
        assert visible.all(), (cam.name, height)


def test_rig_file_is_also_a_vehicle_file() -> None:
    geometry = load_vehicle_geometry(DEMO_RIG_PATH)
    assert geometry.roof_height_mm == 3900.0


def test_defocus_is_zero_at_the_focus_distance(demo_rig: SimRig) -> None:
    cam = demo_rig.cameras[1]
    blur = cam.defocus_diameter_px(np.array([cam.focus_distance_mm, 1300.0, 2600.0]))
    assert blur[0] == pytest.approx(0.0, abs=1e-9)
    assert 1.0 < blur[1] < 6.0 and 1.0 < blur[2] < 6.0


def test_bad_rig_files_name_the_key(tmp_path) -> None:
    text = DEMO_RIG_PATH.read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("focal_length_mm = 28.0", 'focal_length_mm = "28"', 1))
    with pytest.raises(FormatError, match=r"cameras\[1\]\.focal_length_mm"):
        load_rig(bad)
    bad.write_text(text.replace('kind = "blue_strobe_bandpass"', 'kind = "laser"'))
    with pytest.raises(FormatError, match=r"lighting\.kind"):
        load_rig(bad)
    with pytest.raises(UserError, match="no such rig file"):
        load_rig(tmp_path / "missing.toml")
    with pytest.raises(UserError, match="has no camera 'cam9'"):
        load_rig(DEMO_RIG_PATH).camera("cam9")
