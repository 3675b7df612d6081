"""The line-scan processor end to end on simulated sections, against the ground truth.

The rig is calibrated as users calibrate it: the simulator renders the calibration tool's
captures and ``calibrate_from_captures`` measures them (targets assigned with the mounting
drawing's nominal poses); the processor never sees the true cameras. Its observations go
through the core's chain (the vehicle sensors smoothed as ``catenary process`` smooths them,
``roof_to_track``, ``catenary.measurement.wear``, the wire type's residual thickness) and are
compared with the truth of the running contact wires.

Tolerances are the figures measured (``benchmarks/accuracy.py``) with margin; the targets
are 0.05 mm RMS and 0.10 mm worst for the residual thickness, 2 mm for height and stagger.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from catenary.domain import CameraLines, RunHeader, ScanBlock, VehicleSamples, WireObservations
from catenary.errors import UserError
from catenary.measurement.vehicle import roof_to_track
from catenary.measurement.wear import (
    corrected_wear_width_mm,
    screened_wear_width_by_wire_mm,
    stagger_angle_by_wire_rad,
)
from catenary_linescan.calibrate import calibrate_from_captures, rig_from_reports
from catenary_linescan.processor.matching import Matches
from catenary_linescan.processor.stereo import (
    LineScanProcessor,
    ProcessorConfig,
    _observations,
    contact_from_axis,
    create,
)
from catenary_linescan.processor.tracking import TrackedPoints
from catenary_linescan.rig import Rig, write_rig
from catenary_linescan.simulator import DEMO_RIG_PATH, Simulation, load_rig, parse_settings
from catenary_linescan.simulator.captures import write_captures
from catenary_linescan.simulator.scene import generate_scene
from catenary_wiretypes import load_profiles

SPEED_KMH = 160.0  # 44 mm between scans at 1000 scans/s: fewer scans to render


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Rig:
    """The demo rig calibrated from simulated captures (``catenary calibrate``'s way)."""
    sim_rig = load_rig(DEMO_RIG_PATH)
    path, _ = write_captures(tmp_path_factory.mktemp("captures") / "captures.h5", sim_rig, seed=3)
    reports = calibrate_from_captures(path, distortion=None, approximate=sim_rig.nominal_models())
    return rig_from_reports(sim_rig.vehicle, reports)


@dataclass
class Section:
    """Rendered scans of a simulated run with their ground truth, concatenated."""

    first_scan: int
    position_m: np.ndarray
    time_s: np.ndarray
    lines: dict[str, np.ndarray]
    bit_depth: dict[str, int]
    vehicle: dict[str, np.ndarray]
    truth: dict[str, np.ndarray]
    contact: np.ndarray
    wire_type: str
    offset_px: dict[str, int] = dataclasses.field(default_factory=dict)

    def blocks(self, size: int):
        n = self.position_m.shape[0]
        for start in range(0, n, size):
            part = slice(start, start + size)
            yield ScanBlock(
                first_scan=self.first_scan + start,
                position_m=self.position_m[part],
                time_s=self.time_s[part],
                cameras={
                    k: CameraLines(v[part], self.bit_depth[k], self.offset_px.get(k, 0))
                    for k, v in self.lines.items()
                },
                vehicle=VehicleSamples(**{k: v[part] for k, v in self.vehicle.items()}),
            )


def render(
    settings: dict,
    around: str = "overlap",
    half_length_m: float = 75.0,
    wear_mm: float | None = None,
    scene: dict | None = None,
) -> Section:
    """The scans within ``half_length_m`` of the overlap's middle mast (or the run's middle);
    ``wear_mm``: every contact wire's face held that wide (0: new wires); ``scene``: scene
    parameters that differ."""
    sim = Simulation(parse_settings({"speed_kmh": SPEED_KMH, **settings}))
    if scene:
        params = replace(sim.settings.scene_params(), **scene)
        sim.scene = generate_scene(params, sim.settings.seed)
    if wear_mm is not None:
        sim.scene = sim.scene.with_constant_wear(wear_mm)
    chainage = sim.motion.chainage_m(sim.motion.scan_times(0, sim.scans))
    if around == "overlap":
        centre = sim.scene.masts[sim.scene.overlap_masts[1]].chainage_m
    else:
        centre = chainage[sim.scans // 2]
    inside = np.flatnonzero(np.abs(chainage - centre) <= half_length_m)
    chunks = [
        sim.chunk(i) for i in range(inside[0] // sim.chunk_scans, inside[-1] // sim.chunk_scans + 1)
    ]
    # the sensors as the processing gives them: smoothed (catenary.measurement.sensors)
    vehicle = sim.processed_vehicle_at(np.concatenate([c.time_s for c in chunks]))
    fields = (
        "present",
        "running",
        "x_roof_mm",
        "z_roof_mm",
        "stagger_mm",
        "height_mm",
        "residual_thickness_mm",
        "wear_width_mm",
    )
    return Section(
        first_scan=chunks[0].first_scan,
        position_m=np.concatenate([c.position_m for c in chunks]),
        time_s=np.concatenate([c.time_s for c in chunks]),
        lines={n: np.concatenate([c.lines[n] for c in chunks]) for n in chunks[0].lines},
        bit_depth={c.name: c.bit_depth for c in sim.rig.cameras},
        vehicle={k: getattr(vehicle, k) for k in ("time_s", "left_mm", "right_mm", "lateral_mm")},
        truth={k: np.concatenate([getattr(c.truth, k) for c in chunks]) for k in fields},
        contact=np.array([w.contact for w in sim.scene.wires]),
        wire_type=sim.scene.wire_type.name,
    )


def process(rig: Rig, section: Section, block: int, config: ProcessorConfig | None = None):
    processor = LineScanProcessor(rig, config)
    parts = [processor.process(b) for b in section.blocks(block)] + [processor.finish()]
    obs = WireObservations(
        **{
            f: np.concatenate([getattr(p, f) for p in parts])
            for f in WireObservations.__dataclass_fields__
        }
    )
    # one row per scan and wire, in scan order
    assert np.all(np.diff(obs.scan) >= 0)
    key = obs.scan * 1000 + obs.wire
    assert np.unique(key).shape[0] == key.shape[0]
    return obs


@dataclass
class Score:
    recall: float
    false_rows: int
    false_wires: int
    numbers: dict[int, int]
    thickness: np.ndarray
    height: np.ndarray
    stagger: np.ndarray
    no_width: int


def score(section: Section, obs: WireObservations, rig: Rig, screen: bool = False) -> Score:
    """The processor's rows against the truth; ``screen``: the widths screened along the
    track as the pipeline does (``catenary.measurement.wear``)."""
    t = section.truth
    row = obs.scan - section.first_scan
    distance = np.where(
        t["present"][row],
        np.hypot(
            t["x_roof_mm"][row] - obs.x_roof_mm[:, None],
            t["z_roof_mm"][row] - obs.z_roof_mm[:, None],
        ),
        np.inf,
    )
    which = distance.argmin(axis=1)
    true_row = (distance[np.arange(row.shape[0]), which] < 20.0) & section.contact[which]
    false_wires = sum(1 for w in np.unique(obs.wire) if np.mean(true_row[obs.wire == w]) < 0.5)
    running = t["running"]
    detected = np.zeros(running.shape, bool)
    detected[row[true_row], which[true_row]] = True
    numbers = {}
    for j in np.flatnonzero(section.contact):
        rows = true_row & (which == j) & running[row, j]
        if rows.any():
            numbers[int(j)] = int(np.unique(obs.wire[rows]).shape[0])
    v = section.vehicle
    stagger, height = roof_to_track(
        obs.x_roof_mm,
        obs.z_roof_mm,
        v["left_mm"][row],
        v["right_mm"][row],
        v["lateral_mm"][row],
        rig.vehicle,
    )
    theta = stagger_angle_by_wire_rad(obs.wire, section.position_m[row], stagger)
    wire_type = {p.name: p for p in load_profiles()}[section.wire_type]
    w0 = corrected_wear_width_mm(obs.wear_width_mm, theta)
    if screen:
        w0 = screened_wear_width_by_wire_mm(obs.wire, section.position_m[row], w0)
    thickness = wire_type.residual_thickness_mm(np.clip(w0, 0.0, wire_type.width_mm))
    use = np.flatnonzero(true_row & running[row, which])
    r, j = row[use], which[use]
    return Score(
        recall=float((detected & running).sum() / running.sum()),
        false_rows=int((~true_row).sum()),
        false_wires=false_wires,
        numbers=numbers,
        thickness=thickness[use] - t["residual_thickness_mm"][r, j],
        height=height[use] - t["height_mm"][r, j],
        stagger=stagger[use] - t["stagger_mm"][r, j],
        no_width=int(np.isnan(w0[use]).sum()),
    )


def assert_accurate(s: Score, recall: float = 0.99, no_width: float = 0.002) -> None:
    assert s.false_wires == 0
    assert s.false_rows <= 2  # single points near a wire at most, never a wire
    assert s.recall >= recall
    assert all(count == 1 for count in s.numbers.values()), s.numbers  # stable numbers
    thickness = s.thickness[np.isfinite(s.thickness)]
    assert s.no_width <= no_width * s.thickness.shape[0]
    assert np.sqrt(np.mean(thickness**2)) < 0.03
    assert np.max(np.abs(thickness)) < 0.10
    assert np.max(np.abs(s.height)) < 2.0
    assert np.max(np.abs(s.stagger)) < 2.0


@pytest.fixture(scope="module")
def overlap() -> Section:
    return render({"seed": 31, "overlap": True, "length_m": 300.0})


def test_an_overlap_at_night(rig: Rig, overlap: Section) -> None:
    obs = process(rig, overlap, 1024)
    s = score(overlap, obs, rig)
    assert len(s.numbers) == 2  # both contact wires, each with one number
    assert set(np.unique(obs.wire).tolist()) == {0, 1}
    assert_accurate(s)
    # three cameras or four; two (unverified, continuing a track) in a few scans at most
    assert np.all(obs.cameras >= 2)
    assert np.mean(obs.cameras >= 3) > 0.99


def test_block_size_does_not_change_the_result(rig: Rig, overlap: Section) -> None:
    a = process(rig, overlap, 1024)
    b = process(rig, overlap, 333)
    for field in WireObservations.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


def test_a_camera_blinded_by_the_sun(rig: Rig) -> None:
    section = render(
        {
            "seed": 32,
            "overlap": True,
            "length_m": 300.0,
            "sun_blind": "cam3",
            "sun_blind_span": (0.0, 1.0),
        },
    )
    obs = process(rig, section, 1024)
    s = score(section, obs, rig)
    assert len(s.numbers) == 2
    assert_accurate(s)
    assert np.all(obs.cameras <= 3)  # the other three; two where one of them missed
    assert np.mean(obs.cameras == 3) > 0.9


def test_white_daylight_overlap_invents_no_wire(rig: Rig) -> None:
    """Messengers are dark and sharp against the sky in white daylight: they are matched,
    and removed by height; nothing that is not a contact wire gets a wire number. (Recall is
    not asserted here: it rests on the features' handling of a worn wire's bright face
    inside its dark silhouette; ``benchmarks/accuracy.py`` reports it.)"""
    section = render({"seed": 33, "overlap": True, "length_m": 300.0, "lighting": "day-white"})
    obs = process(rig, section, 1024)
    s = score(section, obs, rig)
    assert s.false_wires == 0
    assert s.false_rows <= 0.01 * obs.rows  # points near a wire but more than 20 mm off
    assert len(s.numbers) == 2
    assert all(count == 1 for count in s.numbers.values())


def test_worn_to_the_limit_past_dropper_clamps(rig: Rig) -> None:
    """Faces of 8-12 mm: at a dropper clamp the wire's dark side between its face and the clamp
    behind it is narrower than the blur, and every camera reads the face narrow (0.13 mm of
    thickness at the worst clamp here); the pipeline's along-track screen leaves those
    scans' widths out, and the rest meets the targets."""
    section = render(
        {"seed": 21, "overlap": False, "curve_radius_m": 0.0, "length_m": 200.0},
        around="middle",
        half_length_m=60.0,
        scene={"wear_base_mm": (9.5, 11.0)},
    )
    obs = process(rig, section, 1024)
    raw = score(section, obs, rig)
    assert np.nanmax(np.abs(raw.thickness)) > 0.10  # the clamp is in the section
    screened = score(section, obs, rig, screen=True)
    assert np.nanmax(section.truth["wear_width_mm"]) > 11.5
    # a scan at every dropper clamp at most (44 mm between scans here, droppers every 5-10 m)
    assert screened.no_width - raw.no_width <= 120.0 / 5.0
    assert_accurate(screened, no_width=0.01)


def test_create_reads_the_rig_and_the_settings(rig: Rig, tmp_path: Path) -> None:
    path = tmp_path / "rig.toml"
    write_rig(path, rig)
    processor = create(
        path,
        {
            "min_track_m": 0.8,
            "messenger_gap_mm": 250,
            "min_cameras": 3,
            "wire_width_mm": [10.0, 15.0],
            "outlines": False,
        },
    )
    assert create(path, {}).stage.features.outlines and not processor.stage.features.outlines
    assert processor.config.tracking.min_track_m == 0.8
    assert processor.config.tracking.messenger_gap_mm == 250.0
    assert processor.config.matching.min_cameras == 3
    assert processor.config.wire_width_mm == (10.0, 15.0)
    assert processor.names == list(rig.cameras)
    with pytest.raises(UserError, match="unknown line-scan processor setting 'speed'"):
        create(path, {"speed": 1})
    with pytest.raises(UserError, match="min_track_m"):
        create(path, {"min_track_m": -1.0})
    with pytest.raises(UserError, match="max_candidates"):
        create(path, {"max_candidates": 2.5})
    with pytest.raises(UserError, match="outlines = 1: expected true or false"):
        create(path, {"outlines": 1})
    with pytest.raises(UserError, match="no such file"):
        create(tmp_path / "missing.toml", {})


def test_the_runs_wire_types_give_the_radius_of_an_unworn_wire(rig: Rig, overlap: Section) -> None:
    profiles = {p.name: p for p in load_profiles()}
    processor = LineScanProcessor(rig)
    assert processor.stage.wire_radius_mm == 0.25 * (10.6 + 14.8)  # the widths looked for
    processor.expect_wire_types([profiles["AC-100"], profiles["AC-150"]])
    radius = 0.25 * (profiles["AC-100"].width_mm + profiles["AC-150"].width_mm)
    assert processor.stage.wire_radius_mm == radius == processor.stage.matching.wire_radius_mm
    assert processor.config.wire_width_mm == (10.6, 14.8)  # the features' window unchanged
    processor.process(next(overlap.blocks(16)))
    with pytest.raises(ValueError, match="before the first block"):
        processor.expect_wire_types([profiles["AC-100"]])


def test_a_block_without_a_rig_camera_is_refused(rig: Rig, overlap: Section) -> None:
    block = next(overlap.blocks(16))
    cameras = dict(block.cameras)
    del cameras["cam2"]
    broken = ScanBlock(block.first_scan, block.position_m, block.time_s, cameras, block.vehicle)
    with pytest.raises(UserError, match="no camera 'cam2'"):
        LineScanProcessor(rig).process(broken)


def header_of(widths: dict[str, int], offsets: dict[str, int] | None = None) -> RunHeader:
    return RunHeader(
        line="L",
        track="1",
        vehicle="v",
        direction="increasing",
        start_chainage_m=0.0,
        started_at="2024-01-01T00:00:00Z",
        scan_rate_hz=1000.0,
        scans=10,
        camera_pixels=widths,
        camera_bit_depth=dict.fromkeys(widths, 8),
        camera_offset_px=offsets or {},
    )


def test_a_run_that_fits_the_rig_is_accepted_silently(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    widths = {name: c.camera.pixels for name, c in rig.cameras.items()}
    LineScanProcessor(rig).check_run(header_of(widths))
    # regions of interest within the sensor, one of them at its very end
    roi = dict.fromkeys(widths, 2048)
    offsets = {"cam1": 0, "cam2": 1000, "cam3": 1, "cam4": 2048}
    LineScanProcessor(rig).check_run(header_of(roi, offsets))
    assert not caplog.records


@pytest.mark.parametrize(
    ("widths", "offsets", "needles"),
    [
        ({"cam1": 2048}, {}, ["camera 'cam1'", "2048", "4096"]),
        ({"cam2": 4097}, {}, ["camera 'cam2'", "4097", "4096"]),
        ({"cam4": 2048}, {"cam4": 2049}, ["camera 'cam4'", "offset_px 2049", "4097", "4096"]),
        ({"cam3": 4096}, {"cam3": 1}, ["camera 'cam3'", "offset_px 1", "4097", "4096"]),
    ],
)
def test_lines_that_do_not_fit_the_sensor_are_refused(
    rig: Rig, widths: dict[str, int], offsets: dict[str, int], needles: list[str]
) -> None:
    full = {name: c.camera.pixels for name, c in rig.cameras.items()}
    assert set(full.values()) == {4096}
    with pytest.raises(UserError) as info:
        LineScanProcessor(rig).check_run(header_of({**full, **widths}, offsets))
    message = str(info.value)
    assert "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)


def test_a_run_without_a_rig_camera_is_refused_before_any_scan(rig: Rig) -> None:
    widths = {name: c.camera.pixels for name, c in rig.cameras.items()}
    del widths["cam2"]
    with pytest.raises(UserError, match="the run has no camera 'cam2'"):
        LineScanProcessor(rig).check_run(header_of(widths))


def test_a_camera_the_rig_lacks_is_named_once_and_ignored(
    rig: Rig, overlap: Section, caplog: pytest.LogCaptureFixture
) -> None:
    widths = {name: c.camera.pixels for name, c in rig.cameras.items()}
    processor = LineScanProcessor(rig)
    with caplog.at_level(logging.WARNING):
        processor.check_run(header_of({**widths, "overview": 1920}))
    assert [r.getMessage() for r in caplog.records] == [
        f"warning: camera 'overview' of the run is not in rig {rig.vehicle.name!r}: ignored"
    ]
    block = next(overlap.blocks(64))
    extra = {**block.cameras, "overview": CameraLines(np.zeros((64, 1920), np.uint8), 8)}
    with_extra = ScanBlock(block.first_scan, block.position_m, block.time_s, extra, block.vehicle)
    a = processor.process(with_extra)
    b = LineScanProcessor(rig).process(block)
    for name in WireObservations.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_a_block_beyond_the_sensor_is_refused(rig: Rig, overlap: Section) -> None:
    block = next(overlap.blocks(16))
    cameras = dict(block.cameras)
    cameras["cam1"] = CameraLines(cameras["cam1"].lines[:, :2048], 8, offset_px=3000)
    broken = ScanBlock(block.first_scan, block.position_m, block.time_s, cameras, block.vehicle)
    expected = r"camera 'cam1': offset_px 3000 \+ 2048 pixels = 5048, beyond the 4096"
    with pytest.raises(UserError, match=expected):
        LineScanProcessor(rig).process(broken)


def test_a_region_of_interest_measures_as_the_whole_line(rig: Rig, overlap: Section) -> None:
    """Every camera's lines cut to the part of its sensor the contact wires cross (150 px
    either side), each at its own ``offset_px``: line pixel ``i`` is camera pixel
    ``offset_px + i``, and the run measures as the whole line does."""
    t = overlap.truth
    wires = t["present"] & overlap.contact
    x, z = t["x_roof_mm"][wires], t["z_roof_mm"][wires]
    lines, offsets = {}, {}
    for name, rig_camera in rig.cameras.items():
        u = rig_camera.camera.project(x, z)
        first = max(0, int(np.floor(u.min())) - 150)
        stop = min(rig_camera.camera.pixels, int(np.ceil(u.max())) + 151)
        offsets[name] = first
        lines[name] = np.ascontiguousarray(overlap.lines[name][:, first:stop])
    assert min(offsets.values()) > 100 and len(set(offsets.values())) == len(offsets)
    assert max(v.shape[1] for v in lines.values()) < 3500
    cropped = replace(overlap, lines=lines, offset_px=offsets)
    full = score(overlap, process(rig, overlap, 1024), rig)
    roi = score(cropped, process(rig, cropped, 1024), rig)
    assert len(roi.numbers) == 2
    assert_accurate(roi)
    assert roi.recall >= full.recall - 0.001
    assert np.sqrt(np.mean(roi.thickness**2)) <= np.sqrt(np.mean(full.thickness**2)) + 0.005


@pytest.mark.parametrize(
    ("lighting", "median_mm", "p90_mm"), [("day-white", 0.3, 0.5), ("night", 1.2, 1.5)]
)
def test_a_new_wire_is_located_at_its_lowest_point(
    rig: Rig, lighting: str, median_mm: float, p90_mm: float
) -> None:
    """A new wire has no worn face: its point is the middle of its silhouettes, lowered to
    the wire's bottom (the radius: half the mean of the widths looked for, 6.35 mm; this
    CTA120 has 6.45). In white daylight the silhouette is the whole wire: height error median
    0.0 mm, 90 % within 0.11 mm. At night the round sides are too dark to see and the
    silhouette is the lit bottom, a chord lowered by its sagitta: median +0.76 mm, 90 % within
    1.07 mm (lowered by the radius, as before: median -1.6, 90 % within 1.9 mm)."""
    section = render(
        {"seed": 41, "lighting": lighting, "overlap": False}, "middle", 20.0, wear_mm=0.0
    )
    s = score(section, process(rig, section, 1024), rig)
    assert s.false_wires == 0
    assert s.recall >= 0.98
    assert np.all(np.abs(s.thickness[np.isfinite(s.thickness)]) < 0.05)  # no face seen
    assert abs(np.median(s.height)) < median_mm
    assert np.percentile(np.abs(s.height), 90) < p90_mm


def test_a_silhouette_middle_is_lowered_by_its_chord_sagitta() -> None:
    m = 6
    matches = Matches(
        scan=np.array([0, 0, 0, 0, 1, 1]),
        slot=np.zeros((m, 3), np.int64),
        x_mm=np.zeros(m),
        z_mm=np.full(m, 1000.0),
        from_face=np.array([False, False, False, False, False, True]),
        cameras=np.full(m, 3),
        reprojection_rms_px=np.zeros(m),
        sigma_x_mm=np.zeros(m),
        sigma_z_mm=np.zeros(m),
        verified=np.ones(m, bool),
        radius_mm=np.full(m, np.nan),
    )
    roll = np.array([0.0, 0.01])
    # the whole wire (or no bright camera), a chord of 8 mm, none, the lit point; tilted;
    # a point on its face stays
    chord = np.array([13.0, 8.0, 0.0, np.nan, 8.0, 8.0])
    out = contact_from_axis(matches, roll, 6.5, chord)
    sagitta = 6.5 - np.sqrt(6.5**2 - 4.0**2)
    np.testing.assert_allclose(1000.0 - out.z_mm[:4], [6.5, sagitta, 0.0, 6.5])
    np.testing.assert_allclose(out.x_mm[:4], 0.0)
    np.testing.assert_allclose(
        [out.x_mm[4], 1000.0 - out.z_mm[4]], sagitta * np.array([np.sin(0.01), np.cos(0.01)])
    )
    assert (out.x_mm[5], out.z_mm[5]) == (0.0, 1000.0)


@pytest.mark.parametrize("flag", [None, [False, True, True]])
def test_the_trackers_selection_uncertain_column_reaches_the_observations(flag) -> None:
    """The tracker marks rows it cannot decide are the contact wire with a column of that
    name; a tracker that gives none leaves every row certain."""
    columns = {
        "cameras": np.array([3, 4, 3]),
        "reprojection_rms_px": np.zeros(3),
    }
    if flag is not None:
        columns["selection_uncertain"] = np.array(flag)
    points = TrackedPoints(
        scan=np.array([4, 5, 5]),
        wire=np.array([0, 0, 1]),
        position_m=np.array([0.1, 0.2, 0.2]),
        x_mm=np.array([-10.0, -9.0, 300.0]),
        z_mm=np.array([1500.0, 1500.0, 2700.0]),
        face_mm=np.array([5.0, 6.0, 7.0]),
        columns=columns,
    )
    obs = _observations(points)
    expected = [False, False, False] if flag is None else flag
    np.testing.assert_array_equal(obs.selection_uncertain, expected)
    np.testing.assert_array_equal(obs.wear_width_mm, [5.0, 6.0, 7.0])
