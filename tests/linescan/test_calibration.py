"""Camera calibration from (x, z, u) points and the resolution look-up table."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catenary.errors import UserError
from catenary_linescan.calibration import (
    ResolutionTable,
    build_resolution_table,
    calibrate_camera,
    direct_linear_transform,
    resolution_table_from_camera,
)
from catenary_linescan.camera import LineScanCamera, camera_from_pose
from catenary_linescan.triangulation import triangulate

PIXELS = 4096
FOCAL_PX = 5000.0
WIDE_FOCAL_PX = (PIXELS / 2) / math.tan(math.radians(30.0))  # a 60° lens
CAMERA_X_MM = (-700.0, -250.0, 250.0, 700.0)
NOISE_PX = 0.1
TARGETS_X_MM = np.arange(-600.0, 601.0, 100.0)
HEIGHTS_MM = np.arange(1300.0, 2501.0, 100.0)


def demo_rig(focal_px: float = FOCAL_PX, k1: float = 0.0) -> list[LineScanCamera]:
    """Four cameras on the roof, each tilted to centre x ±600 mm at 1300-2500 mm."""
    corners_x = np.array([-600.0, 600.0, -600.0, 600.0])
    corners_z = np.array([1300.0, 1300.0, 2500.0, 2500.0])
    cameras = []
    for index, x in enumerate(CAMERA_X_MM):
        angles = np.degrees(np.arctan2(corners_x - x, corners_z))
        tilt = 0.5 * (angles.min() + angles.max())
        u0 = 2047.5 + 15.0 * (index - 1.5)
        cameras.append(camera_from_pose(f"cam{index}", PIXELS, x, 0.0, tilt, focal_px, u0, k1))
    return cameras


def visible_points(camera: LineScanCamera, n: int, rng: np.random.Generator):
    """``n`` points of the measurement range (x ±600 mm, z 1300-2500 mm) the camera sees."""
    x = rng.uniform(-600.0, 600.0, 4 * n)
    z = rng.uniform(1300.0, 2500.0, 4 * n)
    seen = camera.in_view(x, z)
    return x[seen][:n], z[seen][:n]


def noisy_observations(camera: LineScanCamera, x, z, rng: np.random.Generator, outliers=0.05):
    """Image coordinates with 0.1 px noise and a fraction of gross errors (3-80 px)."""
    u = camera.project(x, z) + rng.normal(0.0, NOISE_PX, x.shape)
    gross = rng.random(x.shape) < outliers
    u[gross] += rng.choice([-1.0, 1.0], gross.sum()) * rng.uniform(3.0, 80.0, gross.sum())
    return u, gross


def test_calibration_with_noise_and_outliers_recovers_the_rig():
    rng = np.random.default_rng(11)
    truth = demo_rig()
    calibrated = []
    for camera in truth:
        x, z = visible_points(camera, 150, rng)
        u, gross = noisy_observations(camera, x, z, rng)
        result = calibrate_camera(camera.name, PIXELS, x, z, u)
        assert gross.sum() >= 3
        assert not np.any(result.inliers & gross), "a gross outlier was kept"
        assert result.points_rejected >= gross.sum()
        assert result.points_used + result.points_rejected == x.shape[0]
        assert result.rms_px == pytest.approx(NOISE_PX, rel=0.3)
        assert result.max_px < 5 * NOISE_PX
        assert result.camera.k1 == 0.0
        # the model, judged on clean points it was not fitted to
        x_check, z_check = visible_points(camera, 500, rng)
        error = result.camera.project(x_check, z_check) - camera.project(x_check, z_check)
        assert np.sqrt(np.mean(error**2)) < 0.3
        calibrated.append(result.camera)
    x, z = rng.uniform(-400.0, 400.0, 2000), rng.uniform(1300.0, 2500.0, 2000)
    u = np.stack([camera.project(x, z) for camera in truth], axis=1)
    result = triangulate(calibrated, u)
    assert np.max(np.abs(result.x_mm - x)) < 1.0
    assert np.max(np.abs(result.z_mm - z)) < 1.0


def test_distortion_is_recovered_when_present():
    rng = np.random.default_rng(12)
    for camera in demo_rig(WIDE_FOCAL_PX, k1=-0.05)[:2]:
        x, z = visible_points(camera, 150, rng)
        u, _ = noisy_observations(camera, x, z, rng)
        result = calibrate_camera(camera.name, PIXELS, x, z, u)
        assert result.camera.k1 == pytest.approx(-0.05, abs=0.002)
        assert result.rms_px == pytest.approx(NOISE_PX, rel=0.3)
        x_check, z_check = visible_points(camera, 500, rng)
        error = result.camera.project(x_check, z_check) - camera.project(x_check, z_check)
        assert np.sqrt(np.mean(error**2)) < 0.3
        # without the radial term the same data are fitted tens of times worse
        plain = calibrate_camera(
            camera.name, PIXELS, x, z, u, distortion=False, outlier_px=50, max_rms_px=100
        )
        assert plain.camera.k1 == 0.0
        assert plain.rms_px > 10 * result.rms_px


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_distortion_is_not_invented_when_absent(seed: int):
    rng = np.random.default_rng(seed)
    for camera in demo_rig(WIDE_FOCAL_PX):
        x, z = visible_points(camera, 150, rng)
        u, _ = noisy_observations(camera, x, z, rng)
        assert calibrate_camera(camera.name, PIXELS, x, z, u).camera.k1 == 0.0
        forced = calibrate_camera(camera.name, PIXELS, x, z, u, distortion=True)
        assert abs(forced.camera.k1) < 0.002


def test_distortion_is_not_estimated_from_too_few_points():
    rng = np.random.default_rng(13)
    camera = demo_rig(WIDE_FOCAL_PX, k1=-0.05)[0]
    x, z = visible_points(camera, 8, rng)
    u = camera.project(x, z)
    assert calibrate_camera("cam0", PIXELS, x, z, u).camera.k1 == 0.0
    assert calibrate_camera("cam0", PIXELS, x, z, u, distortion=True).camera.k1 == pytest.approx(
        -0.05, abs=1e-6
    )


def test_six_points_suffice_without_distortion():
    camera = demo_rig()[1]
    x = np.array([-300.0, 0.0, 300.0, -200.0, 100.0, 350.0])
    z = np.array([1300.0, 1300.0, 1300.0, 2500.0, 2500.0, 1900.0])
    result = calibrate_camera("cam1", PIXELS, x, z, camera.project(x, z))
    assert result.points_used == 6 and result.camera.k1 == 0.0
    np.testing.assert_allclose(result.camera.matrix, camera.normalised().matrix, atol=1e-6)
    with pytest.raises(UserError, match="at least 7"):
        calibrate_camera("cam1", PIXELS, x, z, camera.project(x, z), distortion=True)


def test_calibrated_matrix_is_normalised_and_equivalent():
    rng = np.random.default_rng(14)
    camera = demo_rig()[3]
    x, z = visible_points(camera, 40, rng)
    result = calibrate_camera(camera.name, PIXELS, x, z, camera.project(x, z))
    matrix = result.camera.matrix
    assert np.linalg.norm(matrix[1]) == pytest.approx(1.0, abs=1e-12)
    assert matrix[1, 2] > 0.0
    np.testing.assert_allclose(matrix, camera.normalised().matrix, rtol=1e-6, atol=1e-9)
    assert result.rms_px < 1e-6
    dlt, conditioning = direct_linear_transform(x, z, camera.project(x, z))
    assert conditioning > 1e-6
    np.testing.assert_allclose(
        LineScanCamera("dlt", PIXELS, dlt).normalised().matrix, matrix, rtol=1e-6, atol=1e-9
    )


def test_unconstrained_cameras_raise_a_one_line_user_error():
    camera = demo_rig()[0]
    x = np.linspace(-300.0, 300.0, 10)
    z = np.linspace(1300.0, 2500.0, 10)
    cases = {
        "at least 6": (x[:5], z[:5]),
        "one height": (x, np.full(10, 1800.0)),
        "one line": (x, 1800.0 + 0.5 * x),
    }
    for expected, (xs, zs) in cases.items():
        with pytest.raises(UserError, match=expected) as raised:
            calibrate_camera("left-outer", PIXELS, xs, zs, camera.project(xs, zs))
        message = str(raised.value)
        assert "'left-outer'" in message and "\n" not in message
    bad = camera.project(x, z)
    bad[3] = np.nan
    with pytest.raises(UserError, match="non-finite"):
        calibrate_camera("left-outer", PIXELS, x, z, bad)
    with pytest.raises(UserError, match="shapes"):
        calibrate_camera("left-outer", PIXELS, x, z[:-1], camera.project(x, z))


def test_too_many_outliers_raise():
    rng = np.random.default_rng(15)
    camera = demo_rig()[0]
    x, z = visible_points(camera, 12, rng)
    u = camera.project(x, z) + rng.uniform(-300.0, 300.0, x.shape)
    with pytest.raises(UserError, match=r"'cam0'.*RMS"):
        calibrate_camera("cam0", PIXELS, x, z, u)
    x, z = visible_points(camera, 40, rng)
    u = camera.project(x, z)
    u[:30] += rng.uniform(20.0, 300.0, 30)
    with pytest.raises(UserError, match="'cam0'"):
        calibrate_camera("cam0", PIXELS, x, z, u)


# -- the resolution table ----------------------------------------------------------------------


def face_widths_px(camera: LineScanCamera, flat_width_mm: float = 6.0) -> np.ndarray:
    """Widths [px] of the targets' flat faces, ``(H, T)``, NaN where a face is out of view."""
    x = TARGETS_X_MM[np.newaxis, :]
    z = HEIGHTS_MM[:, np.newaxis]
    half = flat_width_mm / 2
    width = np.abs(camera.project(x + half, z) - camera.project(x - half, z))
    seen = camera.in_view(x - half, z) & camera.in_view(x + half, z)
    return np.where(seen, width, np.nan)


@pytest.mark.parametrize(("focal_px", "k1"), [(FOCAL_PX, 0.0), (WIDE_FOCAL_PX, -0.05)])
def test_interpolated_table_matches_the_analytic_resolution(focal_px: float, k1: float):
    x = np.linspace(-600.0, 600.0, 121)
    z = np.linspace(1300.0, 2500.0, 121)[:, np.newaxis]
    for camera in demo_rig(focal_px, k1):
        table = build_resolution_table(TARGETS_X_MM, HEIGHTS_MM, face_widths_px(camera), 6.0)
        seen = camera.in_view(x, z)
        analytic = camera.resolution_mm_per_px(x, z)
        interpolated = np.abs(table.at(x, z) / analytic - 1.0)
        assert np.max(interpolated[seen]) < 0.005
        # the paper's cell-constant table is an order of magnitude coarser
        cell = np.abs(table.at_cell(x, z) / analytic - 1.0)
        assert np.max(cell[seen]) > 5 * np.max(interpolated[seen])


def test_unseen_targets_are_filled_along_x_and_marked():
    camera = demo_rig()[1]
    widths = face_widths_px(camera)
    assert np.isnan(widths).any(), "the inner camera misses some corner targets"
    widths[4, 6] = np.nan  # one missed in the middle of a row
    table = build_resolution_table(TARGETS_X_MM, HEIGHTS_MM, widths, 6.0, camera="cam1")
    np.testing.assert_array_equal(table.filled, np.isnan(widths))
    exact = camera.resolution_mm_per_px(TARGETS_X_MM, HEIGHTS_MM[:, np.newaxis])
    np.testing.assert_allclose(table.mm_per_px, exact, rtol=0.005)


def test_table_grids_are_sorted_and_rows_must_be_seen():
    camera = demo_rig()[0]
    widths = face_widths_px(camera)
    shuffled_x = np.random.default_rng(16).permutation(TARGETS_X_MM.shape[0])
    table = build_resolution_table(
        TARGETS_X_MM[shuffled_x], HEIGHTS_MM[::-1], widths[::-1][:, shuffled_x], 6.0
    )
    np.testing.assert_array_equal(table.x_mm, TARGETS_X_MM)
    np.testing.assert_array_equal(table.z_mm, HEIGHTS_MM)
    np.testing.assert_allclose(table.mm_per_px, 6.0 / widths)
    widths[2] = np.nan
    with pytest.raises(UserError, match=r"'cam0'.*1500 mm"):
        build_resolution_table(TARGETS_X_MM, HEIGHTS_MM, widths, 6.0, camera="cam0")
    with pytest.raises(UserError, match="shape"):
        build_resolution_table(TARGETS_X_MM, HEIGHTS_MM, widths[:, :-1], 6.0, camera="cam0")


@settings(max_examples=40, deadline=None)
@given(
    coefficients=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4),
    x=st.floats(-700.0, 700.0),
    z=st.floats(1200.0, 2600.0),
)
def test_bilinear_interpolation_is_exact_for_bilinear_functions(
    coefficients: list[float], x: float, z: float
):
    a, b, c, d = coefficients

    def field(x, z):
        return 1.0 + a * x / 600 + b * (z - 1900) / 600 + c * d * x * (z - 1900) / 360000

    grid_x = np.array([-600.0, -350.0, 0.0, 100.0, 600.0])
    grid_z = np.array([1300.0, 1700.0, 2500.0])
    values = field(grid_x[np.newaxis, :], grid_z[:, np.newaxis])
    table = ResolutionTable(grid_x, grid_z, values, np.zeros(values.shape, dtype=bool))
    assert table.at(x, z) == pytest.approx(field(x, z), abs=1e-9)  # extrapolates linearly too
    ix = np.argmin(np.abs(grid_x - x))
    iz = np.argmin(np.abs(grid_z - z))
    assert table.at_cell(x, z) == values[iz, ix]


def test_table_from_the_camera_model():
    camera = demo_rig()[2]
    table = resolution_table_from_camera(camera, TARGETS_X_MM, HEIGHTS_MM)
    assert table.mm_per_px.shape == (HEIGHTS_MM.shape[0], TARGETS_X_MM.shape[0])
    np.testing.assert_allclose(
        table.at(TARGETS_X_MM, HEIGHTS_MM[:, np.newaxis]),
        camera.resolution_mm_per_px(TARGETS_X_MM, HEIGHTS_MM[:, np.newaxis]),
    )
    assert not table.filled.any()
