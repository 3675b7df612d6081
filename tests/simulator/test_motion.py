"""Motion, encoder and the displacement sensors against the FORMATS.md vehicle model."""

from __future__ import annotations

import numpy as np
import pytest

from catenary.measurement.vehicle import roll_rad, roof_to_track, track_to_roof
from catenary_linescan.simulator.motion import Motion, MotionParams
from catenary_linescan.simulator.rig import SimRig


def make_motion(rig: SimRig, **params) -> Motion:
    return Motion(
        MotionParams(**params),
        seed=11,
        length_m=400.0,
        start_chainage_m=1000.0,
        geometry=rig.vehicle,
        curve=(1200.0, 1500.0, 1.0 / 800.0),
    )


def test_sensors_reproduce_the_body_pose_through_the_formats_model(demo_rig: SimRig) -> None:
    motion = make_motion(demo_rig, sensor_noise_mm=0.0)
    geometry = demo_rig.vehicle
    t = np.linspace(0.0, motion.duration_s, 2000)
    pose = motion.pose(t)
    left, right, lateral = pose.sensors(geometry.sensor_baseline_mm)
    np.testing.assert_allclose(roll_rad(left, right, geometry.sensor_baseline_mm), pose.roll_rad)
    np.testing.assert_allclose(0.5 * (left + right), pose.bounce_mm, atol=1e-9)
    # a point fixed in the track frame, seen from the rolling, swaying, bouncing body
    x, z = track_to_roof(250.0, 5600.0, left, right, lateral, geometry)
    assert np.ptp(x) > 20.0 and np.ptp(z) > 10.0  # the body really moves
    back = roof_to_track(x, z, left, right, lateral, geometry)
    np.testing.assert_allclose(back[0], 250.0, atol=1e-9)
    np.testing.assert_allclose(back[1], 5600.0, atol=1e-9)
    # the sampled sensors are the same functions on their own clock
    samples = motion.sensor_samples(-2, 400)
    ref = motion.pose(samples.time_s).sensors(geometry.sensor_baseline_mm)
    np.testing.assert_allclose(samples.left_mm, ref[0])
    np.testing.assert_allclose(samples.lateral_mm, ref[2])


def test_body_motion_has_a_realistic_amplitude(demo_rig: SimRig) -> None:
    motion = make_motion(demo_rig)
    t = np.linspace(0.0, motion.duration_s, 20000)
    pose = motion.pose(t)
    roll = np.degrees(pose.roll_rad)
    assert np.ptp(roll) > 0.3 and np.abs(roll).max() < 2.5
    assert np.ptp(pose.lateral_mm) > 10.0 and np.abs(pose.lateral_mm).max() < 80.0
    assert np.ptp(pose.bounce_mm) > 5.0 and np.abs(pose.bounce_mm).max() < 30.0
    # smooth: no jumps between samples 1 ms apart
    assert np.abs(np.diff(pose.lateral_mm)).max() < 1.0


def test_in_curves_the_body_rolls_out_and_its_centre_moves_in(demo_rig: SimRig) -> None:
    motion = make_motion(demo_rig, roll_std_deg=0.0, lateral_std_mm=0.0, bounce_std_mm=0.0)
    t_straight = np.array([1.0])
    t_curve = np.array([motion.duration_s * 0.85])  # chainage ~1340: in the right-hand curve
    straight = motion.pose(t_straight)
    curve = motion.pose(t_curve)
    assert straight.roll_rad[0] == 0.0 and straight.lateral_mm[0] == 0.0
    assert curve.roll_rad[0] < 0.0  # curve bends right: left side goes down (outward)
    versine = 1000.0 * 17.5**2 / (8 * 800.0)
    assert curve.lateral_mm[0] == pytest.approx(versine - 10.0, abs=1e-6)


def test_encoder_scale_error_and_start_error_are_applied(demo_rig: SimRig) -> None:
    motion = make_motion(demo_rig, encoder_scale_error=0.004, start_chainage_error_m=2.5)
    t = motion.scan_times(0, motion.scans)
    distance = motion.distance_m(t)
    position = motion.encoder_m(t)
    assert position[0] == 0.0 and np.all(np.diff(position) >= 0.0)
    assert distance[-1] == pytest.approx(400.0, abs=0.05)
    assert position[-1] / distance[-1] == pytest.approx(1.004, abs=1e-5)
    assert np.abs(position - distance * 1.004).max() <= 1.25e-3  # one pulse
    assert motion.header_start_chainage_m == pytest.approx(1002.5)
    random = make_motion(demo_rig)
    assert 0.0 < abs(random.encoder_scale_error) <= 0.006


def test_speed_varies_a_little_around_the_set_speed(demo_rig: SimRig) -> None:
    motion = make_motion(demo_rig, speed_kmh=90.0)
    speed = motion.speed_m_s(np.linspace(0.0, motion.duration_s, 500)) * 3.6
    assert speed.min() > 0.9 * 90 and speed.max() < 1.1 * 90
    # the distance is the speed's integral
    t = np.linspace(0.0, motion.duration_s, 20001)
    v = motion.speed_m_s(t)
    integral = np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t))
    assert integral == pytest.approx(float(motion.distance_m(t[-1])), rel=1e-6)
