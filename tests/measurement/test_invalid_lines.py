"""Lines a camera did not deliver (``/cameras/{name}/valid`` false): the processor takes that
camera as not seeing those scans, in this process and in worker processes alike.

A small simulated run is changed in a copy: over a stretch one camera's lines are replaced by
lines of other scans (wires where there are none: what a shifted or corrupted buffer would
show) and marked invalid. Processed, it must give exactly what the run gives with that camera
blinded over the stretch (lines of zeros, valid: no candidate at all); unmarked, the same
lines must not (else the comparison could not fail).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from contextlib import closing
from pathlib import Path

import h5py
import numpy as np
import pytest

from catenary.domain import WireObservations
from catenary.measurement.parallel import staged_blocks
from catenary.measurement.runfile import open_run
from catenary_linescan.processor.features import extract_features
from catenary_linescan.processor.stereo import create

from ..conftest import SmallRun

STRETCH = slice(300, 700)
CAMERA = "cam2"
BLOCK_SCANS = 256


def variant(
    small_run: SmallRun, folder: Path, name: str, change: Callable[[h5py.File], None]
) -> Path:
    path = folder / f"{name}.h5"
    shutil.copyfile(small_run.run, path)
    with h5py.File(path, "a") as f:
        change(f)
    return path


def invalid(*cameras: str, content: str) -> Callable[[h5py.File], None]:
    """``cameras``' lines over the stretch: ``"zeros"`` or ``"shifted"`` (those of scans 60
    to 460 further on), marked invalid unless ``content`` ends in ``"unmarked"``."""

    def change(f: h5py.File) -> None:
        for camera in cameras:
            lines = f[f"cameras/{camera}/lines"]
            if content == "zeros":
                lines[STRETCH] = 0
            else:
                lines[STRETCH] = lines[STRETCH.start + 460 : STRETCH.stop + 460]
            if not content.endswith("unmarked"):
                valid = np.ones(lines.shape[0], dtype=bool)
                valid[STRETCH] = False
                f[f"cameras/{camera}/valid"] = valid

    return change


def blinded(f: h5py.File) -> None:
    f[f"cameras/{CAMERA}/lines"][STRETCH] = 0


def process(small_run: SmallRun, path: Path, workers: int = 0) -> WireObservations:
    """The processor over the run, in this process (``workers`` 0) or staged in workers."""
    processor = create(small_run.rig, {})
    parts = []
    with open_run(path) as run:
        processor.check_run(run.header)
        if workers:
            pool = staged_blocks(
                path, processor.stage, run.blocks(BLOCK_SCANS, lines=False), workers
            )
            with closing(pool):
                for block, staged in pool:
                    parts.append(processor.process_staged(block, staged.result()))
        else:
            parts = [processor.process(block) for block in run.blocks(BLOCK_SCANS)]
    parts.append(processor.finish())
    return WireObservations(
        **{
            name: np.concatenate([getattr(part, name) for part in parts])
            for name in WireObservations.__dataclass_fields__
        }
    )


def assert_same(a: WireObservations, b: WireObservations) -> None:
    for name in WireObservations.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_an_invalid_stretch_is_that_camera_blinded(small_run: SmallRun, tmp_path: Path) -> None:
    with open_run(small_run.run) as run:
        assert CAMERA in run.header.camera_pixels and run.header.scans > STRETCH.stop + 460
        zeros = np.zeros((8, run.header.camera_pixels[CAMERA]), dtype=np.uint8)
    assert len(extract_features(zeros, 8)) == 0  # a blinded camera: no candidate

    reference = process(small_run, variant(small_run, tmp_path, "blinded", blinded))
    seen = (reference.scan >= STRETCH.start) & (reference.scan < STRETCH.stop)
    assert seen.sum() > 300  # the other three cameras still see the wires there
    assert np.all(reference.cameras[seen] <= 3)

    shifted = variant(small_run, tmp_path, "shifted", invalid(CAMERA, content="shifted"))
    assert_same(process(small_run, shifted), reference)
    zeroed = variant(small_run, tmp_path, "zeroed", invalid(CAMERA, content="zeros"))
    assert_same(process(small_run, zeroed), reference)
    assert_same(process(small_run, shifted, workers=1), reference)  # workers read the flags

    unmarked = variant(small_run, tmp_path, "unmarked", invalid(CAMERA, content="shifted-unmarked"))
    with pytest.raises(AssertionError):
        assert_same(process(small_run, unmarked), reference)


def test_fewer_than_two_valid_cameras_give_nothing(small_run: SmallRun, tmp_path: Path) -> None:
    with open_run(small_run.run) as run:
        others = [name for name in run.header.camera_pixels if name != CAMERA]
    assert len(others) == 3
    path = variant(small_run, tmp_path, "three", invalid(*others, content="shifted"))
    observations = process(small_run, path)
    inside = (observations.scan >= STRETCH.start) & (observations.scan < STRETCH.stop)
    assert observations.rows > 300 and not inside.any()
