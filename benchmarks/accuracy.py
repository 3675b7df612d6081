"""Benchmark: accuracy of the line-scan processor against the simulator's ground truth.

Runs the whole measurement chain on simulated sections the project's tests do not use (their
own seeds) and compares it with the ground truth, per case:

- the rig is calibrated the way users calibrate it: the simulator renders the calibration
  tool's captures (the paper's figure 8), ``catenary_linescan.calibrate.calibrate_from_captures``
  measures them (targets assigned with the mounting drawing's nominal camera poses) and
  calibrates every camera and its resolution look-up table; the processor never sees the true
  camera models;
- the processor (features, matching, tracking) turns the run's blocks into wire observations
  in the roof frame; the core then applies the vehicle compensation (``roof_to_track`` with
  the noisy displacement sensors, by default 0.3 mm at 200 Hz, smoothed below 5 Hz without lag
  as ``catenary process`` does: ``catenary.measurement.sensors``), the stagger-angle
  correction (``catenary.measurement.wear``: θ from the measured stagger gradient), the
  along-track screen of the widths (``catenary.measurement.wear``: a width that departs from
  its neighbours for a few scans, at a fitting, is left out) and the wire type's residual
  thickness, as the pipeline does.

Per case it prints, for the running contact wires: the residual thickness error (RMS, 95th
percentile, max), the height and stagger errors in the track frame (RMS, max), the recall of
running contact wire samples, and the false rows and false wires (output wires that are not a
contact wire), with the number of wire numbers each contact wire got (1 = stable). Rows the
processor flags ``selection_uncertain`` are not claimed as a contact wire: they are neither
false nor recalled, and their share of the rows is printed.

Targets (DESIGN.md, the issue): thickness 0.05 mm RMS and 0.10 mm worst; height and stagger
within 2 mm; recall 99.5 %; no false wire; at most 0.5 % of the rows uncertain.

    .venv/bin/python benchmarks/accuracy.py                 # every case (a few minutes)
    .venv/bin/python benchmarks/accuracy.py --quick         # shorter sections
    .venv/bin/python benchmarks/accuracy.py --cases overlap blind-camera
    .venv/bin/python benchmarks/accuracy.py --no-screen     # without the along-track screen
    .venv/bin/python benchmarks/accuracy.py --sensor-noise-mm 0.5 --sensor-rate-hz 100
    .venv/bin/python benchmarks/accuracy.py --vehicle-filter-hz 0   # sensors unsmoothed
    .venv/bin/python benchmarks/accuracy.py --cases limit-filter --lighting night
    .venv/bin/python benchmarks/accuracy.py --no-outlines   # no unworn wire's outline on one side
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from catenary.domain import CameraLines, ScanBlock
from catenary.measurement.sensors import DEFAULT_FILTER_HZ
from catenary.measurement.vehicle import roof_to_track
from catenary.measurement.wear import (
    corrected_wear_width_mm,
    screened_wear_width_by_wire_mm,
    stagger_angle_by_wire_rad,
)
from catenary_linescan.calibrate import calibrate_from_captures, rig_from_reports
from catenary_linescan.processor.stereo import LineScanProcessor, ProcessorConfig
from catenary_linescan.rig import Rig
from catenary_linescan.simulator import (
    DEMO_RIG_PATH,
    SimRig,
    Simulation,
    load_rig,
    parse_settings,
)
from catenary_linescan.simulator.captures import write_captures
from catenary_linescan.simulator.radiometry import CONDITIONS
from catenary_linescan.simulator.scene import generate_scene
from catenary_wiretypes import load_profiles

TRUE_DISTANCE_MM = 20.0
"""An output point within this of a wire's contact point is that wire: wires are 11-15 mm
thick, and one without a worn face (a new wire, or one raised out of running) is located at
its centre, up to a radius above its contact point. Positions are scored separately."""


@dataclass(frozen=True)
class Case:
    """One simulated section: simulation settings and scene parameters that differ."""

    name: str
    settings: dict[str, Any]
    scene: dict[str, Any] = field(default_factory=dict)
    note: str = ""


CASES = [
    Case("night", {"seed": 101, "lighting": "night", "overlap": False}),
    Case("day-filter", {"seed": 102, "lighting": "day-filter", "overlap": False}),
    Case("day-white", {"seed": 103, "lighting": "day-white", "overlap": False}),
    Case("overlap", {"seed": 104, "lighting": "night", "overlap": True, "length_m": 300.0}),
    Case(
        "overlap-white",
        {"seed": 105, "lighting": "day-white", "overlap": True, "length_m": 300.0},
        note="white daylight: messengers dark and visible",
    ),
    Case(
        "wear-12mm",
        {"seed": 106, "overlap": False, "curve_radius_m": 0.0},
        {"wear_base_mm": (9.5, 11.0)},
        note="faces 8-12 mm",
    ),
    Case(
        "height-1300",
        {"seed": 107, "overlap": False, "curve_radius_m": 0.0},
        {"contact_height_above_roof_mm": (1220.0, 1620.0)},
        note="1300-1500 mm above the roof",
    ),
    Case(
        "height-2500",
        {"seed": 108, "overlap": False, "curve_radius_m": 0.0},
        {"contact_height_above_roof_mm": (2220.0, 2620.0)},
        note="2300-2500 mm above the roof",
    ),
    Case(
        "stagger-400",
        {"seed": 109, "overlap": False, "curve_radius_m": 0.0},
        {"stagger_mm": (385.0, 400.0)},
        note="zigzag ±385-400 mm",
    ),
    Case(
        "curve",
        {"seed": 110, "overlap": False, "curve_radius_m": 600.0, "direction": "decreasing"},
        note="R 600 m, decreasing chainage",
    ),
    Case(
        "new-wire",
        {"seed": 112, "overlap": False},
        {"wear_base_mm": (0.0, 0.0)},
        note="faces 0-2 mm: undulation and hot spots only",
    ),
    Case(
        "new-wire-white",
        {"seed": 113, "lighting": "day-white", "overlap": False},
        {"wear_base_mm": (0.0, 0.0)},
        note="the same by white daylight",
    ),
    Case(
        "new-wire-filter",
        {"seed": 114, "lighting": "day-filter", "overlap": False},
        {"wear_base_mm": (0.0, 0.0)},
        note="the same behind the band-pass filter",
    ),
    Case(
        "turnout",
        {"seed": 115, "overlap": False, "turnout_angle_deg": 6.0},
        note="a diverging contact wire crossing the main one at 6° mid-run",
    ),
    Case(
        "system-300",
        {"seed": 116, "overlap": False},
        {"system_height_mm": (300.0, 400.0)},
        note="messengers 300-400 mm above their contact wires at the masts",
    ),
    Case(
        "limit-filter",
        {"seed": 117, "lighting": "day-filter", "overlap": False, "curve_radius_m": 0.0},
        {"wear_base_mm": (11.3, 11.6), "contact_height_above_roof_mm": (2220.0, 2620.0)},
        note="faces 11-12 mm, 2300-2500 mm above the roof, with the filter",
    ),
    Case(
        "limit-white",
        {"seed": 118, "lighting": "day-white", "overlap": False, "curve_radius_m": 0.0},
        {"wear_base_mm": (11.3, 11.6), "contact_height_above_roof_mm": (1220.0, 1620.0)},
        note="faces 11-12 mm, 1300-1500 mm above the roof, white daylight",
    ),
    Case(
        "blind-camera",
        {
            "seed": 111,
            "overlap": True,
            "sun_blind": "cam2",
            "sun_blind_span": (0.1, 0.9),
            "length_m": 300.0,
        },
        note="cam2 saturated over 80 % of the run, overlap included",
    ),
]


def calibrated_rig(workdir: Path, sim_rig: SimRig | None = None, *, seed: int = 7) -> Rig:
    """A simulated rig (default: the demo rig) calibrated from its simulated captures, as
    ``catenary calibrate`` does it; ``workdir`` receives the captures.

    The targets are assigned with the nominal camera poses of the mounting drawing (the
    simulated rig's design values: position, tilt, focal length, principal point at the
    line's middle, no distortion); everything else comes from the captures.
    """
    sim_rig = sim_rig or load_rig(DEMO_RIG_PATH)
    captures, _ = write_captures(workdir / "captures.h5", sim_rig, seed=seed)
    reports = calibrate_from_captures(
        captures, distortion=None, approximate=sim_rig.nominal_models()
    )
    return rig_from_reports(sim_rig.vehicle, reports, source=captures.name)


def simulation(case: Case, quick: bool, changed: dict[str, Any] | None = None) -> Simulation:
    """The case's simulation; ``changed``: simulation settings that differ for every case
    (``sensor_noise_mm``, ``sensor_rate_hz``, ``lighting``)."""
    settings = {"length_m": 150.0, **case.settings, **(changed or {})}
    if quick:
        settings["length_m"] = min(settings["length_m"], 150.0 if settings.get("overlap") else 60.0)
    return build_simulation(settings, case.scene)


def build_simulation(settings: dict[str, Any], scene: dict[str, Any]) -> Simulation:
    """A simulation from ``settings`` (``parse_settings``) whose scene is generated with the
    :class:`SceneParams` fields in ``scene`` changed (heights, wear ... that the settings do
    not reach)."""
    parsed = parse_settings(settings)
    params = replace(parsed.scene_params(), **scene)
    return Simulation(parsed, generate_scene(params, parsed.scene_rng_seed))


@dataclass
class Collected:
    """What a case's run gives: the processor's rows and the truth per scan."""

    scan: list[np.ndarray] = field(default_factory=list)
    wire: list[np.ndarray] = field(default_factory=list)
    x: list[np.ndarray] = field(default_factory=list)
    z: list[np.ndarray] = field(default_factory=list)
    width: list[np.ndarray] = field(default_factory=list)
    cameras: list[np.ndarray] = field(default_factory=list)
    uncertain: list[np.ndarray] = field(default_factory=list)
    truth: dict[str, list[np.ndarray]] = field(default_factory=dict)
    first_scan: int = 0  # the scan of the truth's first row

    def add_rows(self, observations: Any) -> None:
        self.scan.append(observations.scan)
        self.wire.append(observations.wire)
        self.x.append(observations.x_roof_mm)
        self.z.append(observations.z_roof_mm)
        self.width.append(observations.wear_width_mm)
        self.cameras.append(observations.cameras)
        self.uncertain.append(observations.selection_uncertain)

    def add_truth(self, name: str, values: np.ndarray) -> None:
        self.truth.setdefault(name, []).append(values)


_TRUTH_WIRE = (
    "present",
    "running",
    "x_roof_mm",
    "z_roof_mm",
    "stagger_mm",
    "height_mm",
    "wear_width_mm",
    "wear_width_inplane_mm",
    "residual_thickness_mm",
)


def run_case(
    case: Case,
    rig: Rig,
    quick: bool,
    screen: bool = True,
    *,
    changed: dict[str, Any] | None = None,
    filter_hz: float = DEFAULT_FILTER_HZ,
    config: ProcessorConfig | None = None,
) -> dict[str, Any]:
    result = measure(
        simulation(case, quick, changed), rig, screen, filter_hz=filter_hz, config=config
    )
    result.update(case=case.name, note=case.note)
    return result


def measure(
    sim: Simulation,
    rig: Rig,
    screen: bool = True,
    *,
    filter_hz: float = DEFAULT_FILTER_HZ,
    scans: tuple[int, int] | None = None,
    config: ProcessorConfig | None = None,
) -> dict[str, Any]:
    """Process a simulated run with the calibrated ``rig`` (processor settings ``config``,
    None: the defaults) and score it (:func:`evaluate`); adds ``scans``, ``seconds``
    (simulation and processing), ``processing_s`` and the processor's ``table_check``.
    ``scans`` ``(first, stop)``: only the chunks that hold those scans (a stretch of the
    run, as a regression test cuts it). The processor is told the scene's wire type, as
    ``catenary process`` tells it the run's."""
    wire_type = {p.name: p for p in load_profiles()}[sim.scene.wire_type.name]
    processor = LineScanProcessor(rig, config)
    processor.expect_wire_types([wire_type])
    got = Collected()
    bit_depth = {c.name: c.bit_depth for c in sim.rig.cameras}
    started = time.perf_counter()
    processing = 0.0
    first_chunk, stop_chunk = 0, sim.chunk_count
    if scans is not None:
        first_chunk = scans[0] // sim.chunk_scans
        stop_chunk = min(-(-scans[1] // sim.chunk_scans), sim.chunk_count)
    got.first_scan = first_chunk * sim.chunk_scans
    for chunk in map(sim.chunk, range(first_chunk, stop_chunk)):
        block = ScanBlock(
            first_scan=chunk.first_scan,
            position_m=chunk.position_m,
            time_s=chunk.time_s,
            cameras={n: CameraLines(lines, bit_depth[n]) for n, lines in chunk.lines.items()},
            vehicle=chunk.vehicle,
        )
        t0 = time.perf_counter()
        got.add_rows(processor.process(block))
        processing += time.perf_counter() - t0
        truth = chunk.truth
        for name in _TRUTH_WIRE:
            got.add_truth(name, getattr(truth, name))
        got.add_truth("position_m", chunk.position_m)
        # the sensors as catenary process gives them to the chain: smoothed without lag
        vehicle = sim.processed_vehicle_at(chunk.time_s, filter_hz)
        for name in ("left_mm", "right_mm", "lateral_mm"):
            got.add_truth("sensor_" + name, getattr(vehicle, name))
        # the car body's true pose: the processor's own error, the sensors' noise apart
        exact = sim.motion.pose(chunk.time_s).sensors(sim.rig.vehicle.sensor_baseline_mm)
        for name, values in zip(("left_mm", "right_mm", "lateral_mm"), exact, strict=True):
            got.add_truth("pose_" + name, values)
    t0 = time.perf_counter()
    got.add_rows(processor.finish())
    processing += time.perf_counter() - t0
    contact = np.array([w.contact for w in sim.scene.wires])
    result = evaluate(got, contact, wire_type, rig, screen)
    result.update(
        scans=sum(p.shape[0] for p in got.truth["position_m"]),
        seconds=time.perf_counter() - started,
        processing_s=processing,
        table_check=processor.table_check,
    )
    return result


def _stats(errors: np.ndarray) -> tuple[float, float, float]:
    errors = errors[np.isfinite(errors)]
    if errors.shape[0] == 0:
        return math.nan, math.nan, math.nan
    a = np.abs(errors)
    return float(np.sqrt(np.mean(errors**2))), float(np.percentile(a, 95)), float(a.max())


def evaluate(
    got: Collected, contact: np.ndarray, wire_type: Any, rig: Rig, screen: bool = True
) -> dict[str, Any]:
    t = {k: np.concatenate(v) for k, v in got.truth.items()}
    scan = np.concatenate(got.scan) - got.first_scan
    wire = np.concatenate(got.wire)
    x = np.concatenate(got.x)
    z = np.concatenate(got.z)
    width = np.concatenate(got.width)
    # rows the selection could not decide are not claimed: not false, missed for recall
    uncertain = np.concatenate(got.uncertain)
    # which true wire each row is
    dx = t["x_roof_mm"][scan] - x[:, None]
    dz = t["z_roof_mm"][scan] - z[:, None]
    distance = np.where(t["present"][scan], np.hypot(dx, dz), np.inf)
    which = np.argmin(distance, axis=1)
    near = distance[np.arange(scan.shape[0]), which] <= TRUE_DISTANCE_MM
    true_row = near & contact[which] & ~uncertain
    false_rows = int(np.count_nonzero(~true_row & ~uncertain))
    # false wires: output wire numbers most of whose certain rows are not a contact wire
    false_wires = 0
    for number in np.unique(wire[~uncertain]):
        rows = (wire == number) & ~uncertain
        if np.mean(true_row[rows]) < 0.5:
            false_wires += 1
    # wire numbers per true contact wire (1: stable), over its running samples
    numbers = {}
    for j in np.flatnonzero(contact):
        rows = true_row & (which == j) & t["running"][scan, j]
        if np.any(rows):
            numbers[int(j)] = int(np.unique(wire[rows]).shape[0])
    # recall of running contact wire samples
    running = t["running"]
    detected = np.zeros(running.shape, dtype=bool)
    detected[scan[true_row], which[true_row]] = True
    recall = float(np.count_nonzero(detected & running) / max(np.count_nonzero(running), 1))
    # the pipeline: track frame, stagger angle, corrected width, residual thickness
    left, right, lateral = (t["sensor_" + k][scan] for k in ("left_mm", "right_mm", "lateral_mm"))
    stagger, height = roof_to_track(x, z, left, right, lateral, rig.vehicle)
    pose = (t["pose_" + k][scan] for k in ("left_mm", "right_mm", "lateral_mm"))
    own_stagger, own_height = roof_to_track(x, z, *pose, rig.vehicle)
    position = t["position_m"][scan]
    stream = np.where(uncertain, -1 - wire, wire)  # uncertain rows apart, as the chain does
    theta = stagger_angle_by_wire_rad(stream, position, stagger)
    corrected = corrected_wear_width_mm(width, theta)
    w0 = screened_wear_width_by_wire_mm(stream, position, corrected) if screen else corrected
    # NaN width (faces seen but not agreed on, or screened out): no thickness
    thickness = wire_type.residual_thickness_mm(np.clip(w0, 0.0, wire_type.width_mm))
    use = true_row & running[scan, which]
    rows = np.flatnonzero(use)
    j = which[rows]
    s = scan[rows]
    thickness_error = thickness[rows] - t["residual_thickness_mm"][s, j]
    width_error = w0[rows] - t["wear_width_mm"][s, j]
    height_error = height[rows] - t["height_mm"][s, j]
    stagger_error = stagger[rows] - t["stagger_mm"][s, j]
    own_height_error = own_height[rows] - t["height_mm"][s, j]
    own_stagger_error = own_stagger[rows] - t["stagger_mm"][s, j]
    key = scan * 1000 + wire
    duplicates = int(key.shape[0] - np.unique(key).shape[0])
    return {
        "duplicates": duplicates,
        "running": int(np.count_nonzero(running)),
        "recall": recall,
        "false_rows": false_rows,
        "false_wires": false_wires,
        "uncertain_share": float(np.mean(uncertain)) if uncertain.shape[0] else 0.0,
        "numbers": numbers,
        "thickness": _stats(thickness_error),
        "width": _stats(width_error),
        "height": _stats(height_error),
        "stagger": _stats(stagger_error),
        "own_height": _stats(own_height_error),
        "own_stagger": _stats(own_stagger_error),
        "max_wear_mm": float(np.nanmax(t["wear_width_mm"][s, j])) if rows.size else math.nan,
        "no_width": int(np.count_nonzero(~np.isfinite(width[rows]))),
        "screened": int(np.count_nonzero(np.isfinite(corrected[rows]) & ~np.isfinite(w0[rows]))),
    }


def print_table(results: list[dict[str, Any]]) -> None:
    header = (
        f"{'case':<14} {'scans':>6} {'recall%':>8} {'false':>9} {'unc%':>5} {'wire#':>6} "
        f"{'thick rms/p95/max mm':>21} {'width rms':>9} {'height rms/max':>15} "
        f"{'stagger rms/max':>15} {'wear max':>8} {'no w':>5} {'scr':>4} {'s/case':>7}"
    )
    print(header)
    print("-" * len(header))
    for r in results:
        th, wd, hg, st = r["thickness"], r["width"], r["height"], r["stagger"]
        numbers = ",".join(str(v) for v in r["numbers"].values()) or "-"
        print(
            f"{r['case']:<14} {r['scans']:>6d} {100 * r['recall']:>8.3f} "
            f"{r['false_wires']:>3d}w/{r['false_rows']:<4d} {100 * r['uncertain_share']:>5.2f} "
            f"{numbers:>6} "
            f"{th[0]:>6.3f}/{th[1]:>6.3f}/{th[2]:>6.3f}  {wd[0]:>9.3f} "
            f"{hg[0]:>7.2f}/{hg[2]:>6.2f} {st[0]:>7.2f}/{st[2]:>6.2f} "
            f"{r['max_wear_mm']:>8.2f} {r['no_width']:>5d} {r['screened']:>4d} {r['seconds']:>7.1f}"
        )
    for r in results:
        if r["duplicates"]:
            print(f"{r['case']}: {r['duplicates']} rows repeat a (scan, wire) pair")
    print()
    print("false: output wires that are not a contact wire (w) / rows not on a contact wire;")
    print("unc%: rows flagged selection_uncertain (not claimed; missed for recall; target 0.5 %);")
    print("wire#: wire numbers each running contact wire got (1 = stable through the run);")
    print("no w: rows of running wires whose face the cameras did not agree on (no width);")
    print(
        "scr: rows whose width the along-track screen left out "
        "(catenary.measurement.wear, a fitting's)."
    )
    print(
        "Targets: thickness 0.05 RMS / 0.10 max; height, stagger 2 mm; recall 99.5 %; "
        "no false wire."
    )


def add_outlines_option(parser: argparse.ArgumentParser) -> None:
    """The benchmarks' ``--no-outlines``: the processor setting off (:func:`processor_config`)."""
    parser.add_argument(
        "--no-outlines",
        action="store_true",
        help="the processor setting outlines = false (no unworn wire's outline on one side)",
    )


def processor_config(args: argparse.Namespace) -> ProcessorConfig | None:
    """The processor settings the parsed options ask for (None: the defaults)."""
    return ProcessorConfig(outlines=False) if args.no_outlines else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", help="case names (default: all)")
    parser.add_argument("--quick", action="store_true", help="shorter sections")
    parser.add_argument(
        "--no-screen",
        action="store_true",
        help="widths as the processor gives them, without the along-track screen",
    )
    parser.add_argument(
        "--sensor-noise-mm", type=float, help="displacement sensor noise (default: simulator's)"
    )
    parser.add_argument(
        "--sensor-rate-hz", type=float, help="displacement sensor rate (default: simulator's)"
    )
    parser.add_argument(
        "--lighting",
        choices=CONDITIONS,
        help="every case in this light instead of its own (what the light alone does)",
    )
    add_outlines_option(parser)
    parser.add_argument(
        "--vehicle-filter-hz",
        type=float,
        default=DEFAULT_FILTER_HZ,
        help=f"the sensors' zero-phase low-pass, 0: off (default {DEFAULT_FILTER_HZ:g})",
    )
    args = parser.parse_args(argv)
    changed = {
        key: value
        for key, value in (
            ("sensor_noise_mm", args.sensor_noise_mm),
            ("sensor_rate_hz", args.sensor_rate_hz),
            ("lighting", args.lighting),
        )
        if value is not None
    }
    cases = [c for c in CASES if not args.cases or c.name in args.cases]
    unknown = set(args.cases or []) - {c.name for c in CASES}
    if unknown:
        parser.error(f"unknown case(s) {sorted(unknown)}; known: {[c.name for c in CASES]}")
    with tempfile.TemporaryDirectory() as tmp:
        rig = calibrated_rig(Path(tmp))
    worst = max(c.reprojection_rms_px for c in rig.cameras.values())
    print(f"rig calibrated from simulated captures: worst reprojection RMS {worst:.3f} px")
    results = []
    for case in cases:
        result = run_case(
            case,
            rig,
            args.quick,
            not args.no_screen,
            changed=changed,
            filter_hz=args.vehicle_filter_hz,
            config=processor_config(args),
        )
        results.append(result)
        print(
            f"  {case.name}: {result['scans']} scans in {result['seconds']:.0f} s "
            f"(processor {result['processing_s']:.1f} s); model/table "
            + " ".join(f"{k} {v:.4f}" for k, v in result["table_check"].items()),
            file=sys.stderr,
        )
    print_table(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
