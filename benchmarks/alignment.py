"""Benchmark: aligning a run's encoder positions to the mast register, on simulated runs.

Per case, the whole measurement chain runs on a simulated run with a known encoder scale
error and start-chainage error (``encoder_scale_error``, ``start_chainage_error_m``): the rig
calibrated from simulated captures (``accuracy.calibrated_rig``), the line-scan processor
over the run's chunks, the track frame from the noisy displacement sensors
(``catenary.measurement.vehicle.roof_to_track``), the registration points found in the stagger as
the processor releases its rows (``catenary.measurement.chainage.TurningPointFinder``), and their
match to the scene's mast register (``catenary.measurement.chainage.align_to_register``). Against
the truth's chainage
of every scan it prints:

- the aligned chainage's error (RMS and max over every scan), and for contrast the header's
  ``start + sign · position`` (no alignment);
- the masts the run passes, the turning points found and matched, the spurious ones (no mast
  within 5 m) and the found points' error against their mast (true chainage at the point's
  encoder position minus the mast's chainage);
- the fitted scale and start against the true ones.

    .venv/bin/python benchmarks/alignment.py            # every case (a few minutes)
    .venv/bin/python benchmarks/alignment.py --quick    # 400 m runs
    .venv/bin/python benchmarks/alignment.py --cases curve
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from accuracy import calibrated_rig

from catenary.domain import CameraLines, ScanBlock
from catenary.measurement.chainage import TurningPointFinder, align_to_register
from catenary.measurement.vehicle import roof_to_track
from catenary_linescan.processor.stereo import LineScanProcessor
from catenary_linescan.rig import Rig
from catenary_linescan.simulator import Simulation, parse_settings

SPURIOUS_M = 5.0
"""A turning point with no mast within this (true chainage) is spurious."""


@dataclass(frozen=True)
class Case:
    name: str
    settings: dict[str, Any]
    note: str = ""


CASES = [
    Case(
        "straight",
        {
            "seed": 301,
            "length_m": 1500.0,
            "overlap": False,
            "curve_radius_m": 0.0,
            "encoder_scale_error": 0.005,
            "start_chainage_error_m": 6.0,
        },
        note="+0.5 %, +6 m",
    ),
    Case(
        "overlap",
        {
            "seed": 302,
            "length_m": 1200.0,
            "overlap": True,
            "curve_radius_m": 0.0,
            "encoder_scale_error": -0.004,
            "start_chainage_error_m": -8.0,
        },
        note="-0.4 %, -8 m, overlap mid-run",
    ),
    Case(
        "curve",
        {
            "seed": 303,
            "length_m": 1200.0,
            "overlap": False,
            "curve_radius_m": 700.0,
            "encoder_scale_error": 0.003,
            "start_chainage_error_m": 5.0,
        },
        note="+0.3 %, +5 m, R 700 m over the second half",
    ),
    Case(
        "decreasing",
        {
            "seed": 304,
            "length_m": 1200.0,
            "overlap": True,
            "curve_radius_m": 0.0,
            "direction": "decreasing",
            "encoder_scale_error": -0.006,
            "start_chainage_error_m": 3.0,
        },
        note="-0.6 %, +3 m, overlap",
    ),
]


def simulation(case: Case, quick: bool) -> Simulation:
    settings = dict(case.settings)
    if quick:
        settings["length_m"] = min(settings["length_m"], 400.0)
    return Simulation(parse_settings(settings))


def _stats(errors: np.ndarray) -> tuple[float, float]:
    errors = errors[np.isfinite(errors)]
    if errors.shape[0] == 0:
        return math.nan, math.nan
    return float(np.sqrt(np.mean(errors**2))), float(np.max(np.abs(errors)))


def run_case(case: Case, rig: Rig, quick: bool) -> dict[str, Any]:
    sim = simulation(case, quick)
    header = sim.header()
    processor = LineScanProcessor(rig)
    finder = TurningPointFinder()
    bit_depth = {c.name: c.bit_depth for c in sim.rig.cameras}
    n = sim.scans
    position = np.full(n, np.nan)
    chainage = np.full(n, np.nan)
    sensors = np.full((3, n), np.nan)
    rows = 0
    started = time.perf_counter()

    def push(observations: Any) -> None:
        nonlocal rows
        scan = observations.scan
        left, right, lateral = sensors[:, scan]
        stagger, _ = roof_to_track(
            observations.x_roof_mm, observations.z_roof_mm, left, right, lateral, rig.vehicle
        )
        finder.push(observations.wire, position[scan], stagger)
        rows += int(scan.shape[0])

    for chunk in sim.chunks():
        block = ScanBlock(
            first_scan=chunk.first_scan,
            position_m=chunk.position_m,
            time_s=chunk.time_s,
            cameras={k: CameraLines(v, bit_depth[k]) for k, v in chunk.lines.items()},
            vehicle=chunk.vehicle,
        )
        span = slice(chunk.first_scan, chunk.first_scan + chunk.scans)
        position[span] = chunk.position_m
        chainage[span] = chunk.truth.chainage_m
        sensors[:, span] = (chunk.vehicle.left_mm, chunk.vehicle.right_mm, chunk.vehicle.lateral_mm)
        push(processor.process(block))
    push(processor.finish())
    turning = finder.finish()

    masts = np.sort(np.array([m.chainage_m for m in sim.scene.masts]))
    sign = 1.0 if header.direction == "increasing" else -1.0
    alignment = align_to_register(turning, masts, header.start_chainage_m, header.direction)
    aligned = _stats(alignment.chainage_m(position) - chainage)
    unaligned = _stats(header.start_chainage_m + sign * position - chainage)

    low, high = float(np.nanmin(chainage)), float(np.nanmax(chainage))
    passed = int(np.count_nonzero((masts > low) & (masts < high)))
    # each turning point's true chainage (position is non-decreasing: first scan at or after)
    at = np.clip(np.searchsorted(position, turning), 0, n - 1)
    true_c = chainage[at] + sign * (turning - position[at]) / (1.0 + sim.motion.encoder_scale_error)
    to_mast = true_c[:, None] - masts[None, :]
    nearest = to_mast[np.arange(turning.shape[0]), np.argmin(np.abs(to_mast), axis=1)]
    real = np.abs(nearest) <= SPURIOUS_M
    epsilon = sim.motion.encoder_scale_error
    return {
        "case": case.name,
        "note": case.note,
        "length_m": sim.settings.length_m,
        "direction": header.direction,
        "scans": n,
        "rows": rows,
        "masts": passed,
        "found": int(turning.shape[0]),
        "matched": alignment.matched,
        "spurious": int(np.count_nonzero(~real)),
        "tp_error": _stats(nearest[real]),
        "aligned": aligned,
        "unaligned": unaligned,
        "alignment": alignment,
        "scale_error": (alignment.scale * (1.0 + epsilon) - 1.0) if alignment.aligned else math.nan,
        "start_error": alignment.offset_m - sim.motion.start_chainage_m,
        "true": (epsilon, sim.motion.start_chainage_error_m),
        "seconds": time.perf_counter() - started,
    }


def print_table(results: list[dict[str, Any]]) -> None:
    header = (
        f"{'case':<11} {'dir':>4} {'km':>5} {'masts':>5} {'found':>5} {'match':>5} {'spur':>4} "
        f"{'tp rms/max m':>13} {'aligned rms/max m':>17} {'header rms/max m':>16} "
        f"{'scale err':>9} {'start err':>9} {'s':>5}"
    )
    print(header)
    print("-" * len(header))
    for r in results:
        tp, al, un = r["tp_error"], r["aligned"], r["unaligned"]
        print(
            f"{r['case']:<11} {r['direction'][:4]:>4} {r['length_m'] / 1000:>5.2f} "
            f"{r['masts']:>5d} {r['found']:>5d} {r['matched']:>5d} {r['spurious']:>4d} "
            f"{tp[0]:>6.3f}/{tp[1]:<6.3f} {al[0]:>8.3f}/{al[1]:<8.3f} "
            f"{un[0]:>7.2f}/{un[1]:<8.2f} {1e6 * r['scale_error']:>7.0f}e-6 "
            f"{r['start_error']:>8.3f}m {r['seconds']:>5.0f}"
        )
    print()
    for r in results:
        a = r["alignment"]
        eps, start = r["true"]
        state = "aligned" if a.aligned else f"NOT aligned: {a.reason}"
        print(
            f"{r['case']}: {r['note']} (true scale error {100 * eps:+.2f} %, start error "
            f"{start:+.1f} m); {state}; fit residual RMS {a.residual_rms_m:.3f} m, "
            f"max {a.max_residual_m:.3f} m; {r['rows']} rows of {r['scans']} scans"
        )
    print()
    print("masts: masts the run passes; found/match: turning points found, matched to a mast;")
    print(f"spur: turning points with no mast within {SPURIOUS_M:g} m; tp: found points' error")
    print("against their mast; aligned: fitted chainage minus the truth over every scan;")
    print("header: start + sign * position minus the truth; scale err: fitted scale times the")
    print("encoder's (1 + error), minus 1; start err: fitted chainage at the first scan minus")
    print("the true one.")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--cases", nargs="*", help="case names (default: all)")
    parser.add_argument("--quick", action="store_true", help="400 m runs")
    args = parser.parse_args(argv)
    unknown = set(args.cases or []) - {c.name for c in CASES}
    if unknown:
        parser.error(f"unknown case(s) {sorted(unknown)}; known: {[c.name for c in CASES]}")
    cases = [c for c in CASES if not args.cases or c.name in args.cases]
    with tempfile.TemporaryDirectory() as tmp:
        rig = calibrated_rig(Path(tmp))
    results = []
    for case in cases:
        result = run_case(case, rig, args.quick)
        results.append(result)
        print(
            f"  {case.name}: {result['scans']} scans in {result['seconds']:.0f} s",
            file=sys.stderr,
        )
    print_table(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
