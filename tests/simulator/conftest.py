"""Fixtures for the simulator tests: the demo rig and small copies of it."""

from __future__ import annotations

import dataclasses

import pytest

from catenary_linescan.simulator.rig import SimRig, load_rig
from catenary_linescan.simulator.settings import DEMO_RIG_PATH


@pytest.fixture(scope="session")
def demo_rig() -> SimRig:
    return load_rig(DEMO_RIG_PATH)


@pytest.fixture(scope="session")
def small_rig(demo_rig: SimRig) -> SimRig:
    """The demo rig with 1024-pixel cameras of 4x the pitch: the same fields of view."""
    cameras = tuple(
        dataclasses.replace(
            cam,
            pixels=1024,
            pixel_pitch_um=cam.pixel_pitch_um * 4.0,
            principal_point_px=(1024 - 1) / 2.0,
        )
        for cam in demo_rig.cameras
    )
    return dataclasses.replace(demo_rig, cameras=cameras)
