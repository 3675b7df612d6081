"""A recorded run whose vehicle sensors failed for a stretch still processes, flagged."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from catenary.measurement.runfile import open_run
from catenary_linescan.calibrate import calibrate_from_captures, rig_from_reports
from catenary_linescan.processor.stereo import LineScanProcessor
from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig
from catenary_linescan.simulator.run import record_run


def test_a_run_with_a_sensor_fault_processes_with_the_stretch_flagged(tmp_path: Path) -> None:
    run_path = tmp_path / "run.h5"
    record_run(run_path, {"length_m": 30.0, "seed": 5, "overlap": False})
    with h5py.File(run_path, "r+") as f:  # the sensors fail from 0.4 s to 0.6 s
        t = f["vehicle/time_s"][:]
        left = f["vehicle/left_mm"][:]
        left[(t >= 0.4) & (t <= 0.6)] = np.nan
        f["vehicle/left_mm"][:] = left
    reports = calibrate_from_captures(
        DEMO_RIG_PATH.with_name("demo-captures.h5"), distortion=None, approximate=None
    )
    rig = rig_from_reports(load_rig(DEMO_RIG_PATH).vehicle, reports)
    processor = LineScanProcessor(rig)
    scans, times, faults, observed = [], [], [], []
    with open_run(run_path) as run:
        for block in run.blocks(512):
            scans.append(block.first_scan + np.arange(block.scans))
            times.append(block.time_s)
            faults.append(block.vehicle.fault)
            observed.append(processor.process(block).scan)
    observed.append(processor.finish().scan)
    scan, fault, seen = np.concatenate(scans), np.concatenate(faults), np.concatenate(observed)
    time_s = np.concatenate(times)
    in_fault = (time_s > 0.4) & (time_s < 0.6)
    assert fault[in_fault].all()
    assert not fault[(time_s < 0.39) | (time_s > 0.61)].any()
    # the contact wire is still measured through the stretch, every scan of it
    assert np.isin(scan[in_fault], seen).mean() > 0.99
