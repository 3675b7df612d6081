"""``scene_seed``: the same line (masts, wires, wear) under runs that differ in motion and noise."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from catenary.errors import UserError
from catenary_linescan.commands import simulate
from catenary_linescan.simulator.rig import SimRig
from catenary_linescan.simulator.scene import Scene, generate_scene
from catenary_linescan.simulator.settings import parse_settings
from catenary_linescan.simulator.simulation import Simulation

LENGTH_M = 20.0


def simulation(rig: SimRig, **settings: Any) -> Simulation:
    return Simulation(parse_settings({"rig": rig, "length_m": LENGTH_M, **settings}))


def same_value(a: object, b: object) -> bool:
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        return type(a) is type(b) and all(
            same_value(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a), np.asarray(b))
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def same_line(a: Scene, b: Scene) -> bool:
    """Masts, wires (geometry and wear), fittings and curve all equal."""
    return all(
        same_value(getattr(a, name), getattr(b, name))
        for name in ("masts", "wires", "fittings", "curve_start_m", "curvature_per_m")
    )


def test_one_scene_seed_two_seeds_same_line_different_runs(small_rig: SimRig) -> None:
    first = simulation(small_rig, seed=1, scene_seed=42)
    second = simulation(small_rig, seed=2, scene_seed=42)
    assert first.scene.seed == second.scene.seed == 42
    assert same_line(first.scene, second.scene)
    # the wear the cameras see, along the whole run
    c = np.linspace(first.settings.start_chainage_m, first.settings.start_chainage_m + 20, 500)
    assert np.array_equal(first.scene.sample(c).wear_width_mm, second.scene.sample(c).wear_width_mm)
    assert np.any(first.scene.sample(c).wear_width_mm > 0.5)
    # and everything the seed drives differs: encoder, speed, body pose
    one, two = first.motion, second.motion
    assert one.encoder_scale_error != two.encoder_scale_error
    assert one.start_chainage_error_m != two.start_chainage_error_m
    t = np.linspace(0.0, min(one.duration_s, two.duration_s), 200)
    assert not np.allclose(one.distance_m(t), two.distance_m(t))
    pose_one, pose_two = one.pose(t), two.pose(t)
    for name in ("roll_rad", "lateral_mm", "bounce_mm"):
        assert not np.allclose(getattr(pose_one, name), getattr(pose_two, name)), name
    assert not np.allclose(first.sky.phase, second.sky.phase)


def test_another_scene_seed_is_another_line(small_rig: SimRig) -> None:
    first = simulation(small_rig, seed=1, scene_seed=42)
    other = simulation(small_rig, seed=1, scene_seed=43)
    assert not same_line(first.scene, other.scene)
    # the scene seed touches the scene only: the motion is the seed's
    assert same_value(
        first.motion.pose(np.linspace(0.0, 1.0, 50)), other.motion.pose(np.linspace(0.0, 1.0, 50))
    )
    assert first.motion.encoder_scale_error == other.motion.encoder_scale_error


def test_without_scene_seed_the_seed_lays_out_the_scene(small_rig: SimRig) -> None:
    plain = simulation(small_rig, seed=5)
    assert plain.settings.scene_seed is None
    assert plain.scene.seed == 5
    assert same_line(plain.scene, generate_scene(plain.settings.scene_params(), 5))
    explicit = simulation(small_rig, seed=5, scene_seed=5)
    assert same_line(plain.scene, explicit.scene)
    assert plain.motion.encoder_scale_error == explicit.motion.encoder_scale_error
    # the ground truth's record of the settings reads as before scene_seed existed
    assert "scene_seed" not in plain.settings.as_dict()
    assert explicit.settings.as_dict()["scene_seed"] == 5
    assert simulation(small_rig, seed=5, scene_seed=None).settings == plain.settings


@pytest.mark.parametrize("value", [-1, 1.5, True, "3"])
def test_bad_scene_seed_is_a_user_error(value: object) -> None:
    with pytest.raises(UserError, match="scene_seed"):
        parse_settings({"scene_seed": value})


def test_simulate_command_takes_a_scene_seed(tmp_path: Path, small_rig_file: Path) -> None:
    rig = small_rig_file
    common = ["--rig", str(rig), "--length-m", "2", "--scan-rate-hz", "200", "--scene-seed", "7"]
    for seed in ("1", "2"):
        out = tmp_path / f"run{seed}.h5"
        result = CliRunner().invoke(simulate, [str(out), *common, "--seed", seed])
        assert result.exit_code == 0, result.output
    masts = [(tmp_path / f"run{seed}.masts.csv").read_bytes() for seed in ("1", "2")]
    assert masts[0] == masts[1]
    records = []
    for seed in ("1", "2"):
        with h5py.File(tmp_path / f"run{seed}.truth.h5", "r") as f:
            records.append(
                (
                    json.loads(f.attrs["settings_json"]),
                    float(f.attrs["encoder_scale_error"]),
                )
            )
    assert records[0][0]["scene_seed"] == records[1][0]["scene_seed"] == 7
    assert [record[0]["seed"] for record in records] == [1, 2]
    assert records[0][1] != records[1][1]
