"""The projective line-scan camera: decomposition, projection, back-projection, distortion."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from catenary_linescan.camera import LineScanCamera, camera_from_pose

PIXELS = 4096
FOCAL_PX = 5000.0  # 35 mm lens, 7 µm pixels
CAMERA_X_MM = (-700.0, -250.0, 250.0, 700.0)


def demo_rig() -> list[LineScanCamera]:
    """Four cameras on the roof, each tilted to centre x ±600 mm at 1300-2500 mm."""
    corners_x = np.array([-600.0, 600.0, -600.0, 600.0])
    corners_z = np.array([1300.0, 1300.0, 2500.0, 2500.0])
    cameras = []
    for index, x in enumerate(CAMERA_X_MM):
        angles = np.degrees(np.arctan2(corners_x - x, corners_z))
        tilt = 0.5 * (angles.min() + angles.max())
        cameras.append(camera_from_pose(f"cam{index}", PIXELS, x, 0.0, tilt, FOCAL_PX, 2047.5))
    return cameras


poses = st.fixed_dictionaries(
    {
        "centre_x_mm": st.floats(-800.0, 800.0),
        "centre_z_mm": st.floats(-100.0, 200.0),
        "tilt_deg": st.floats(-35.0, 35.0),
        "focal_px": st.floats(3000.0, 12000.0),
        "u0_px": st.floats(1800.0, 2300.0),
        "k1": st.floats(-0.08, 0.05),
    }
)


@settings(max_examples=60, deadline=None)
@given(pose=poses, scale=st.floats(-50.0, 50.0).filter(lambda s: abs(s) > 1e-3))
def test_decomposition_recovers_the_pose_at_any_scale(pose: dict[str, float], scale: float):
    camera = camera_from_pose("cam", PIXELS, **pose)
    scaled = LineScanCamera("cam", PIXELS, camera.matrix * scale, camera.k1)
    for candidate in (camera, scaled):
        assert candidate.focal_px == pytest.approx(pose["focal_px"], rel=1e-9)
        assert candidate.principal_point_px == pytest.approx(pose["u0_px"], abs=1e-6)
        assert candidate.tilt_deg == pytest.approx(pose["tilt_deg"], abs=1e-9)
        np.testing.assert_allclose(
            candidate.centre_mm, [pose["centre_x_mm"], pose["centre_z_mm"]], atol=1e-6
        )
    normalised = scaled.normalised()
    assert np.linalg.norm(normalised.matrix[1]) == pytest.approx(1.0, abs=1e-12)
    assert normalised.matrix[1, 2] > 0.0 or (
        normalised.matrix[1, 2] == 0.0 and normalised.matrix[1, 1] > 0.0
    )
    np.testing.assert_allclose(normalised.matrix, camera.normalised().matrix, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(pose=poses, u=st.lists(st.floats(0.0, PIXELS - 1.0), min_size=1, max_size=20))
def test_ray_projects_back_to_its_pixel(pose: dict[str, float], u: list[float]):
    camera = camera_from_pose("cam", PIXELS, **pose)
    u_px = np.array(u)
    origin, direction = camera.ray(u_px)
    assert origin.shape == direction.shape == (len(u), 2)
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0, atol=1e-12)
    for distance_mm in (1300.0, 2500.0):
        point = origin + distance_mm * direction
        assert np.all(camera.depth_mm(point[:, 0], point[:, 1]) > 0.0)
        np.testing.assert_allclose(camera.project(point[:, 0], point[:, 1]), u_px, atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(pose=poses, x=st.floats(-600.0, 600.0), z=st.floats(1300.0, 2500.0))
def test_point_lies_on_the_ray_of_its_projection(pose: dict[str, float], x: float, z: float):
    camera = camera_from_pose("cam", PIXELS, **pose)
    u_px = camera.project(x, z)
    # a point the camera sees: outside the sensor a strong barrel lens's model folds over
    # (hypothesis found x -109, z 1300 mm at u -2331 px, where the inverse is ill-conditioned)
    assume(0.0 <= u_px <= PIXELS - 1.0)
    origin, direction = camera.ray(u_px)
    offset = np.array([x, z]) - origin
    along = offset @ direction
    across = offset[0] * direction[1] - offset[1] * direction[0]
    assert along > 0.0
    assert abs(across) < 1e-6  # mm


def test_distortion_round_trip_over_a_60_degree_lens():
    focal = (PIXELS / 2) / math.tan(math.radians(30.0))
    camera = camera_from_pose("wide", PIXELS, 0.0, 0.0, 0.0, focal, 2047.5, k1=-0.05)
    u = np.linspace(-50.0, PIXELS + 50.0, 2001)
    np.testing.assert_allclose(camera.distort(camera.undistort(u)), u, atol=1e-6)
    np.testing.assert_allclose(camera.undistort(camera.distort(u)), u, atol=1e-6)
    # a -0.05 barrel term pulls the edge of the field in by tens of pixels
    edge_shift = camera.distort(np.array([0.0]))[0] - 0.0
    assert 20.0 < edge_shift < 60.0
    assert np.isnan(camera.undistort(np.array([np.nan]))[0])


def test_no_distortion_is_identity():
    camera = demo_rig()[0]
    u = np.linspace(0.0, PIXELS - 1.0, 11)
    np.testing.assert_array_equal(camera.distort(u), u)
    np.testing.assert_array_equal(camera.undistort(u), u)


def test_projection_follows_equation_8_and_broadcasts():
    camera = demo_rig()[1]
    m = camera.matrix
    x = np.linspace(-400.0, 400.0, 5)
    z = np.linspace(1300.0, 2500.0, 3)[:, np.newaxis]
    expected = (m[0, 0] * x + m[0, 1] * z + m[0, 2]) / (m[1, 0] * x + m[1, 1] * z + m[1, 2])
    u = camera.project(x, z)
    assert u.shape == (3, 5)
    np.testing.assert_allclose(u, expected, rtol=0, atol=1e-9)
    assert isinstance(camera.project(0.0, 2000.0), np.ndarray)


def test_resolution_straight_above_an_upright_camera_is_height_over_focal():
    camera = camera_from_pose("up", PIXELS, 0.0, 0.0, 0.0, FOCAL_PX, 2047.5)
    for z in (1300.0, 2000.0, 2500.0):
        assert camera.resolution_mm_per_px(0.0, z) == pytest.approx(z / FOCAL_PX, rel=1e-12)


@pytest.mark.parametrize("k1", [0.0, -0.05])
def test_resolution_and_jacobian_match_finite_differences(k1: float):
    camera = camera_from_pose("cam", PIXELS, -700.0, 0.0, 23.6, 3547.0, 2040.0, k1=k1)
    x = np.linspace(-400.0, 400.0, 9)
    z = np.linspace(1300.0, 2500.0, 7)[:, np.newaxis]
    half = 3.0  # a 6 mm flat face, as on the calibration targets
    width_px = np.abs(camera.project(x + half, z) - camera.project(x - half, z))
    np.testing.assert_allclose(camera.resolution_mm_per_px(x, z), 2 * half / width_px, rtol=1e-4)
    _, du_dx, du_dz = camera.project_jacobian(x, z)
    step = 1e-3
    np.testing.assert_allclose(
        du_dx, (camera.project(x + step, z) - camera.project(x - step, z)) / (2 * step), rtol=1e-6
    )
    np.testing.assert_allclose(
        du_dz, (camera.project(x, z + step) - camera.project(x, z - step)) / (2 * step), rtol=1e-6
    )


def test_demo_rig_sees_the_measurement_range():
    x = np.linspace(-400.0, 400.0, 81)
    z = np.linspace(1300.0, 2500.0, 61)[:, np.newaxis]
    for camera in demo_rig():
        assert np.all(camera.in_view(x, z)), camera.name
        resolution = camera.resolution_mm_per_px(x, z)
        # the paper's Table 1 (0.27-0.33 mm/px at 1300 mm) and twice that at 2500 mm
        assert resolution.min() > 0.2 and resolution.max() < 0.7
    below = demo_rig()[0]
    assert below.depth_mm(0.0, -1000.0) < 0.0
    assert not below.in_view(0.0, -1000.0)


def test_camera_is_immutable_and_validated():
    camera = demo_rig()[0]
    with pytest.raises(ValueError):
        camera.matrix[0, 0] = 1.0
    assert camera == LineScanCamera(camera.name, camera.pixels, camera.matrix.copy())
    assert hash(camera) == hash(LineScanCamera(camera.name, camera.pixels, camera.matrix.copy()))
    assert camera != LineScanCamera("other", camera.pixels, camera.matrix)
    with pytest.raises(ValueError, match="shape"):
        LineScanCamera("bad", PIXELS, np.eye(3))
    with pytest.raises(ValueError, match="non-finite"):
        LineScanCamera("bad", PIXELS, np.full((2, 3), np.nan))
    with pytest.raises(ValueError, match="singular"):
        LineScanCamera("bad", PIXELS, [[1.0, 2.0, 3.0], [2.0, 4.0, 1.0]])
    with pytest.raises(ValueError, match="pixels"):
        LineScanCamera("bad", 0, camera.matrix)


def test_to_dict_is_the_normalised_camera():
    camera = demo_rig()[2]
    values = camera.to_dict()
    assert values["name"] == camera.name and values["pixels"] == PIXELS
    rebuilt = LineScanCamera(values["name"], values["pixels"], values["matrix"], values["k1"])
    assert rebuilt == camera.normalised()
