"""What the resolution look-up table costs in wear width: cell-constant vs interpolated.

Calibrates the demo rig from the shipped demo captures (as ``catenary calibrate`` does) and
compares, against the simulator's true cameras over the measurement range (x ±400 mm,
heights 1300-2500 mm above the roof), the resolution given by

- the paper's table, measured node by node from the targets' face widths, looked up
  cell-constant (the paper) and interpolated bilinearly;
- the table from the calibrated camera model, interpolated bilinearly (what processing uses).

A relative error in resolution is the same relative error in wear width: the figures are
also given in mm for a 10 mm face.

    .venv/bin/python benchmarks/resolution_table.py
"""

from __future__ import annotations

import h5py
import numpy as np

from catenary_linescan.calibrate import calibrate_from_captures
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.simulator.settings import DEMO_RIG_PATH

CAPTURES = DEMO_RIG_PATH.with_name("demo-captures.h5")
TRUTH = DEMO_RIG_PATH.with_name("demo-captures.truth.h5")
FACE_MM = 10.0


def main() -> None:
    reports = calibrate_from_captures(CAPTURES, distortion=None, approximate=None)
    x, z = np.meshgrid(np.linspace(-400.0, 400.0, 161), np.linspace(1300.0, 2500.0, 121))
    print(f"{'camera':<7} {'lookup':<34} {'mean %':>8} {'max |%|':>8} {'max mm @10 mm':>14}")
    with h5py.File(TRUTH, "r") as truth:
        for report in reports:
            name = report.calibration.camera.name
            g = truth["cameras"][name]
            true = LineScanCamera(name, int(g.attrs["pixels"]), g.attrs["matrix"], g.attrs["k1"])
            reference = true.resolution_mm_per_px(x, z)
            assert report.measured is not None
            for label, values in (
                ("measured table, cell-constant", report.measured.at_cell(x, z)),
                ("measured table, interpolated", report.measured.at(x, z)),
                ("model table, interpolated", report.table.at(x, z)),
            ):
                error = values / reference - 1.0
                print(
                    f"{name:<7} {label:<34} {100 * error.mean():8.3f} "
                    f"{100 * np.abs(error).max():8.3f} {FACE_MM * np.abs(error).max():14.3f}"
                )


if __name__ == "__main__":
    main()
