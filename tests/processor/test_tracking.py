"""Wire selection along the run: continuity, messengers by height, stable wire numbers.

The streams are the matching's output in form: per scan, roof-frame points of contact wires,
messengers, droppers, clamps and noise, with the physical figures of the simulator's scene
(``catenary_linescan.simulator.scene``): zigzag stagger, messengers 400 mm and more above,
droppers every 5-10 m cut in one scan, clamps a few scans long.
"""

from __future__ import annotations

import numpy as np
import pytest

from catenary_linescan.processor.tracking import (
    CROSSING_MM,
    MIN_TRACK_M,
    RESTING_ACROSS_MM,
    RESTING_MM,
    UNCERTAIN_COLUMN,
    TrackedPoints,
    TrackingConfig,
    WireTracker,
    link_fragments,
)

SPACING_M = 1.0 / 60.0  # 60 km/h at 1000 scans/s


def zigzag(position_m: np.ndarray, amplitude_mm: float = 300.0, span_m: float = 50.0):
    phase = (position_m % (2.0 * span_m)) / span_m
    return np.where(
        phase < 1.0,
        -amplitude_mm + 2.0 * amplitude_mm * phase,
        amplitude_mm - 2.0 * amplitude_mm * (phase - 1.0),
    )


class Stream:
    """Points with a truth label: 0, 1 contact wires, 10, 11 messengers, 20+ clutter."""

    def __init__(self, scans: int, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.position = np.arange(scans) * SPACING_M
        self.parts: list[tuple[np.ndarray, ...]] = []

    def wire(
        self,
        label: int,
        x: np.ndarray,
        z: np.ndarray,
        present: np.ndarray,
        miss=0.01,
        noise_mm=(0.2, 0.4),
    ):
        s = np.flatnonzero(present & (self.rng.random(present.shape) >= miss))
        noise_x = self.rng.normal(0.0, noise_mm[0], s.shape)
        noise_z = self.rng.normal(0.0, noise_mm[1], s.shape)
        self.parts.append((s, x[s] + noise_x, z[s] + noise_z, np.full(s.shape, label)))

    def points(self, label: int, s: np.ndarray, x: np.ndarray, z: np.ndarray) -> None:
        self.parts.append((s, x, z, np.full(s.shape, label)))

    def arrays(self):
        s, x, z, t = (np.concatenate(v) for v in zip(*self.parts, strict=True))
        order = np.argsort(s, kind="stable")
        return s[order], x[order], z[order], t[order]


def run(
    stream: Stream,
    block: int,
    config: TrackingConfig | None = None,
    *,
    uncertain_rows: bool = False,
    faces: dict[int, float] | None = None,
):
    """Track the stream in blocks of ``block`` scans: scan, wire, truth label and x of the
    rows out, the most points held, and which rows are ``selection_uncertain`` (any fails
    the test unless ``uncertain_rows``). The points of the labels in ``faces`` were
    located by a worn face the cameras agreed on, as wide as given there [mm]."""
    s, x, z, t = stream.arrays()
    tracker = WireTracker(config)
    out: list[TrackedPoints] = []
    n = stream.position.shape[0]
    held = 0
    for first in range(0, n, block):
        rows = (s >= first) & (s < first + block)
        last = min(first + block, n) - 1
        out.append(
            tracker.push(
                s[rows],
                stream.position[s[rows]],
                x[rows],
                z[rows],
                {"truth": t[rows]},
                face_mm=np.vectorize(lambda label: (faces or {}).get(label, 0.0))(t[rows]),
                last_scan=last,
                last_position_m=float(stream.position[last]),
            )
        )
        held = max(held, tracker.held_points)
    out.append(tracker.finish())
    assert tracker.held_points == 0
    scan = np.concatenate([o.scan for o in out])
    wire = np.concatenate([o.wire for o in out])
    truth = np.concatenate([o.columns["truth"] for o in out])
    x_out = np.concatenate([o.x_mm for o in out])
    uncertain = np.concatenate([o.columns[UNCERTAIN_COLUMN] for o in out])
    if not uncertain_rows:
        assert not np.any(uncertain), "rows the selection could not decide"
    return scan, wire, truth, x_out, held, uncertain


def overlap_stream(seed: int = 0) -> tuple[Stream, np.ndarray, np.ndarray, np.ndarray]:
    """A 400 m run: wire A all along, wire B over 120-300 m, coming down from 350 mm above A
    and going back up (an overlap), crossing A in plan; messengers, droppers and clamps.
    Returns the stream and the scans where B runs clear of A, where it is raised, and where
    it crosses A at its height."""
    stream = Stream(24_000, seed)
    p = stream.position
    xa = zigzag(p)
    za = np.full(p.shape, 1800.0)
    in_b = (p > 120.0) & (p < 300.0)
    # B runs 200 mm from A at the middle and swings across it (a crossing in plan) where it
    # is raised out of contact: heights differ there by 150 mm and more
    xb = xa + 200.0 * np.cos((p - 210.0) / 90.0 * np.pi / 2.0 * 2.0)
    zb = 1800.0 + np.clip((np.abs(p - 210.0) - 40.0) * 7.0, 0.0, 400.0)
    stream.wire(0, xa, za, np.ones(p.shape, bool))
    stream.wire(1, xb, zb, in_b)
    stream.wire(10, xa + 5.0, za + 1300.0, np.ones(p.shape, bool), miss=0.3)
    stream.wire(11, xb + 5.0, zb + 1250.0, in_b, miss=0.3)
    rng = stream.rng
    droppers = np.searchsorted(p, np.arange(3.0, p[-1], 7.3))
    stream.points(
        20, droppers, xa[droppers], za[droppers] + rng.uniform(15.0, 1250.0, droppers.size)
    )
    clamps = (droppers[:, None] + np.arange(2)).ravel()  # a dropper clamp's face, 6 mm up
    stream.points(21, clamps, xa[clamps], za[clamps] + 6.0)
    arms = (np.searchsorted(p, np.arange(50.0, p[-1], 50.0))[:, None] + np.arange(3)).ravel()
    stream.points(22, arms, xa[arms] + 300.0, za[arms] + 80.0)  # steady arm, 3 scans
    noise = rng.integers(0, p.shape[0], 400)
    stream.points(30, noise, rng.uniform(-600, 600, 400), rng.uniform(1300, 3500, 400))
    # B where it runs (below the messenger gap above A, and not raised over it in plan) and
    # where it does not, with the points' noise aside
    gap = TrackingConfig().messenger_gap_mm
    lift = zb - 1800.0
    across = np.abs(xb - xa)
    running = (lift < gap - 3.0) & ((across > RESTING_ACROSS_MM + 3.0) | (lift < RESTING_MM - 3.0))
    raised = (lift > gap + 3.0) | ((across < RESTING_ACROSS_MM - 3.0) & (lift > RESTING_MM + 3.0))
    # where B crosses A in plan at A's height, both rows are uncertain (one image of both)
    crossing = in_b & (across < CROSSING_MM + 3.0) & (lift < RESTING_MM + 3.0)
    return stream, in_b & running & ~crossing, in_b & raised, crossing


@pytest.mark.parametrize("block", [1024, 333])
def test_overlap_stable_numbers_no_false_wire(block: int) -> None:
    stream, b_contact, b_raised, crossing = overlap_stream()
    scan, wire, truth, _, held, uncertain = run(stream, block, uncertain_rows=True)
    # only contact wire points come out; uncertain only where B crosses A
    assert set(np.unique(truth).tolist()) == {0, 1}
    assert np.any(uncertain) and np.all(crossing[scan[uncertain]])
    # one wire number per contact wire, through the crossing and the blocks
    assert np.unique(wire[truth == 0]).tolist() == [0]
    assert np.unique(wire[truth == 1]).tolist() == [1]
    # wire A everywhere it was detected
    s, _, _, t = stream.arrays()
    assert np.count_nonzero(truth == 0) == np.count_nonzero(t == 0)
    # wire B wherever it is within the messenger gap of A
    b_out = np.zeros(stream.position.shape, bool)
    b_out[scan[truth == 1]] = True
    b_in = np.zeros(stream.position.shape, bool)
    b_in[s[t == 1]] = True
    assert np.count_nonzero(b_out & b_contact) >= 0.999 * np.count_nonzero(b_in & b_contact)
    assert not np.any(b_out & b_raised)  # raised out of running: not reported
    # what the tracker holds back stays bounded: under 3 m of points
    assert held < 3 * 3.0 / SPACING_M


def test_results_do_not_depend_on_the_block_size() -> None:
    stream, _, _, _ = overlap_stream(seed=4)
    a = run(stream, 4096, uncertain_rows=True)
    b = run(stream, 97, uncertain_rows=True)
    for left, right in zip(a[:4] + a[5:], b[:4] + b[5:], strict=True):
        np.testing.assert_array_equal(left, right)


def test_droppers_clamps_and_arms_are_rejected() -> None:
    stream = Stream(6000, seed=1)
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 2000.0)
    stream.wire(0, x, z, np.ones(p.shape, bool), miss=0.0)
    rng = stream.rng
    # a dropper seen in 1 scan, as a column of points up to the messenger
    for c in np.arange(2.0, 95.0, 6.1):
        s = int(np.searchsorted(p, c))
        stream.points(20, np.full(5, s), np.full(5, x[s]), z[s] + np.linspace(20, 1200, 5))
    # registration: clamp (3 scans, 7 mm up) replacing the wire's point, arm and tube beside
    for c in (25.0, 75.0):
        s = int(np.searchsorted(p, c)) + np.arange(3)
        stream.points(21, s, x[s] + rng.normal(0, 0.2, 3), z[s] + 7.0)
        stream.points(22, s, x[s] + 400.0, z[s] + 60.0)
        stream.points(23, s, x[s] + 900.0, z[s] + 320.0)
    _, wire, truth, _, _, _ = run(stream, 1000)
    assert set(np.unique(truth).tolist()) == {0}
    assert np.unique(wire).tolist() == [0]


def test_a_clamp_in_place_of_the_wire_is_set_apart() -> None:
    # the wire is missed for 3 scans where a clamp's face 6 mm up is seen instead: the
    # excursion leaves the track, which goes on with the wire
    stream = Stream(3000, seed=2)
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 2000.0)
    present = np.ones(p.shape, bool)
    present[1500:1503] = False
    stream.wire(0, x, z, present, miss=0.0)
    s = np.arange(1500, 1503)
    stream.points(21, s, x[s], z[s] + 6.0)
    _scan, wire, truth, _, _, _ = run(stream, 1024)
    assert set(np.unique(truth).tolist()) == {0}
    assert np.unique(wire).tolist() == [0]
    assert np.count_nonzero(truth == 0) == 3000 - 3


@pytest.mark.parametrize(("block", "scans"), [(1024, 3000), (333, 3000), (1024, 1513)])
def test_a_fitting_s_points_scattered_off_the_wire_are_dropped(block: int, scans: int) -> None:
    # the wire missed for 3 scans where a clamp's silhouette gives points 6 mm across,
    # 36 mm up, then 7 mm across the other way, each out of the others' link gate: none is
    # the wire, and the wire goes on as one track, also where the run ends 10 scans later
    # (a piece of track too short to be confirmed)
    stream = Stream(scans, seed=3)
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 2000.0)
    present = np.ones(p.shape, bool)
    present[1500:1503] = False
    stream.wire(0, x, z, present, miss=0.0)
    for i, (dx, dz) in enumerate([(6.0, 3.0), (2.0, 36.0), (-7.0, 1.6)]):
        s = np.array([1500 + i])
        stream.points(21, s, x[s] + dx, z[s] + dz)
    _scan, wire, truth, _, _, _ = run(stream, block)
    assert set(np.unique(truth).tolist()) == {0}
    assert np.unique(wire).tolist() == [0]
    assert np.count_nonzero(truth == 0) == scans - 3


def test_messengers_are_removed_by_height() -> None:
    stream = Stream(6000, seed=3)
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 1500.0)
    stream.wire(0, x, z, np.ones(p.shape, bool), miss=0.05)
    # the messenger: 420 mm above at its lowest (mid-span), more at the supports
    sag = 420.0 + 600.0 * np.abs(((p % 50.0) - 25.0) / 25.0)
    stream.wire(10, x + 3.0, z + sag, np.ones(p.shape, bool), miss=0.0)
    _, wire, truth, _, _, _ = run(stream, 1024)
    assert set(np.unique(truth).tolist()) == {0}
    assert np.unique(wire).tolist() == [0]


def test_a_low_system_s_messenger_is_removed() -> None:
    # system height 300 mm at the supports, 250 mm mid-span: the lowest systems built
    stream = Stream(6000, seed=8)
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 1500.0)
    stream.wire(0, x, z, np.ones(p.shape, bool))
    gap = 250.0 + 50.0 * np.abs(((p % 50.0) - 25.0) / 25.0)
    stream.wire(10, x, z + gap, np.ones(p.shape, bool), miss=0.0)
    _, wire, truth, _, _, _ = run(stream, 1024)
    assert set(np.unique(truth).tolist()) == {0}
    assert np.unique(wire).tolist() == [0]


@pytest.mark.parametrize("block", [1024, 250])
def test_a_contact_wire_seen_in_one_scan_of_four_is_kept_beneath_its_messenger(
    block: int,
) -> None:
    # a worn wire by white daylight: its face as bright as the sky, the wire found in few
    # scans, while the dark messenger 1,200 mm above shows in every one
    stream = Stream(9000, seed=9)
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 1450.0)
    stream.wire(0, x, z, np.ones(p.shape, bool), miss=0.75)
    stream.wire(10, x + 4.0, z + 1200.0, np.ones(p.shape, bool), miss=0.0)
    _, wire, truth, _, _, _ = run(stream, block)
    assert set(np.unique(truth).tolist()) == {0}
    _, _, _, t = stream.arrays()
    assert np.count_nonzero(truth == 0) >= 0.99 * np.count_nonzero(t == 0)
    assert np.unique(wire).tolist() == [0]


def test_a_wire_above_points_that_make_no_track_is_uncertain() -> None:
    # the contact wire's points scatter (tens of mm from scan to scan: they chain into no
    # track), the messenger above is a clean track: which wire runs there cannot be told,
    # and the messenger must not come out as the contact wire
    stream = Stream(6000, seed=10)
    rng = stream.rng
    p = stream.position
    x = zigzag(p)
    z = np.full(p.shape, 1450.0)
    s = np.flatnonzero(rng.random(p.shape) < 0.3)
    stream.points(0, s, x[s] + rng.uniform(-60, 60, s.shape), z[s] + rng.uniform(-60, 60, s.shape))
    stream.wire(10, x, z + 1200.0, np.ones(p.shape, bool), miss=0.0)
    _, _, truth, _, _, uncertain = run(stream, 1024, uncertain_rows=True)
    s, _, _, t = stream.arrays()
    assert not np.any((truth == 10) & ~uncertain)  # no messenger row claims a contact wire
    assert np.count_nonzero(truth == 10) > 0.9 * np.count_nonzero(t == 10)


def test_a_crossing_keeps_both_wires_and_drops_the_pipe_on_them() -> None:
    # a turnout's wire crosses the main one at 4°, riding 12 mm over it at the crossing; a
    # 1.6 m cross-over pipe lies on the main wire 37 mm above its contact point (the stream
    # has both wires' points apart at the crossing: the cameras would merge them)
    stream = Stream(9000, seed=13)
    p = stream.position
    main = np.full(p.shape, -50.0)
    branch = -50.0 + (p - 75.0) * np.tan(np.radians(4.0)) * 1000.0
    seen = np.abs(branch) < 600.0
    stream.wire(0, main, np.full(p.shape, 1600.0), np.ones(p.shape, bool))
    ride = 12.0 * np.clip(1.0 - np.abs(branch - main) / 15.0, 0.0, 1.0)
    stream.wire(1, branch, 1600.0 + ride + np.maximum(p - 80.0, 0.0) * 20.0, seen)
    pipe = np.flatnonzero(np.abs(p - 75.0) < 0.8)
    stream.points(20, pipe, main[pipe] + 8.0, np.full(pipe.shape, 1637.0))
    scan, wire, truth, _, _, uncertain = run(stream, 1024, uncertain_rows=True)
    assert set(np.unique(truth).tolist()) == {0, 1}
    # where the wires are within CROSSING_MM across the cameras see one image of both:
    # those rows are uncertain, and only those
    across = np.abs(branch - main)[scan]
    assert np.all(across[uncertain] < CROSSING_MM + 1.0)
    assert np.all(uncertain[across < CROSSING_MM - 1.0])
    s, _, _, t = stream.arrays()
    for label in (0, 1):  # each wire wherever it runs within the messenger gap
        assert np.count_nonzero(truth == label) >= 0.99 * np.count_nonzero(
            (t == label) & (stream.position[s] < 80.0 + 190.0 / 20.0)
        )
        assert np.unique(wire[truth == label]).shape == (1,)


def crossing_stream(seed: int, image_mm: tuple[float, float]) -> tuple[Stream, np.ndarray]:
    """A turnout's wire (label 1) crossing the main one (0) at 3° at its height, points by
    faces (0.1 mm of scatter): where the branch lies ``image_mm`` across the main wire (from,
    to) the matching gives one point per scan on both, their middle (2); the main wire's
    before, the branch's after. Returns the stream and, per scan, whether the wires lie
    within ``CROSSING_MM`` of each other."""
    stream = Stream(9000, seed=seed)
    p = stream.position
    main = np.full(p.shape, -80.0)
    branch = -80.0 + (p - 75.0) * np.tan(np.radians(3.0)) * 1000.0
    across = branch - main
    height = np.full(p.shape, 1700.0)
    close = np.abs(across) < CROSSING_MM
    seen = np.abs(branch) < 600.0
    image = (across >= image_mm[0]) & (across < image_mm[1])
    face = (0.1, 0.1)
    stream.wire(0, main, height, ~close | (across < image_mm[0]), noise_mm=face)
    stream.wire(1, branch, height, seen & (~close | (across >= image_mm[1])), noise_mm=face)
    stream.wire(2, 0.5 * (main + branch), height, image, miss=0.0, noise_mm=face)
    return stream, close


@pytest.mark.parametrize("block", [1024, 333])
def test_a_crossing_s_point_on_one_wire_s_line_is_that_wire_s(block: int) -> None:
    # (sweep scene 6) within CROSSING_MM one point per scan, located by the face the cameras
    # agreed on: the main wire's, an image of both 6-8.7 mm from the main wire (three scans),
    # then the branch's
    stream, close = crossing_stream(17, (6.0, 8.7))
    faces = {0: 5.0, 1: 3.0, 2: 5.0}  # the image of both: one of the faces, or wider
    scan, _, truth, _, _, uncertain = run(stream, block, uncertain_rows=True, faces=faces)
    assert np.all(uncertain[truth == 2])  # the image of both wires
    # each wire's own points: certain, but a few where the track turns from one wire to the
    # other (a side's line then runs through both)
    own = close[scan] & (truth < 2)
    assert np.count_nonzero(own) > 30
    assert np.count_nonzero(uncertain & own) <= 4
    assert not np.any(uncertain & ~close[scan])


def test_the_image_of_both_faces_where_crossing_wires_touch_is_uncertain() -> None:
    # within 1.3 mm of each other (three scans) the image of both wires is on the line of
    # the points on either side, and its face is both faces (7 mm: the wires' own are 5 and
    # 3 mm)
    stream, close = crossing_stream(19, (-1.3, 1.3))
    faces = {0: 5.0, 1: 3.0, 2: 7.0}
    scan, _, truth, _, _, uncertain = run(stream, 1024, uncertain_rows=True, faces=faces)
    assert np.count_nonzero(truth == 2) >= 2
    assert np.all(uncertain[truth == 2])
    own = close[scan] & (truth < 2)
    assert np.count_nonzero(uncertain & own) <= 0.1 * np.count_nonzero(own)


def test_a_wire_is_kept_once_the_wire_it_rode_over_has_ended() -> None:
    # a wire 33 mm over another (more than RESTING_MM: the lower one is the running wire)
    # until the lower one's track ends: from there on the upper one is kept at once, not a
    # metre later (the lower track held beyond its end as if it were still beneath it)
    stream = Stream(3000, seed=17)
    p = stream.position
    x = zigzag(p)
    stream.wire(0, x, np.full(p.shape, 2000.0), np.ones(p.shape, bool), miss=0.0)
    lower = (p >= 10.0) & (p < 25.0)
    stream.wire(1, x + 1.0, np.full(p.shape, 2000.0 - RESTING_MM - 3.0), lower, miss=0.0)
    scan, _, truth, _, _, _ = run(stream, 1024)
    ended = int(np.flatnonzero(lower)[-1])
    upper = scan[truth == 0]
    assert np.all((upper <= np.flatnonzero(lower)[0]) | (upper > ended))  # rests on it there
    assert np.count_nonzero(upper > ended) == p.shape[0] - 1 - ended


def test_a_messenger_alone_where_its_contact_wire_was_lost_is_uncertain() -> None:
    # the contact wire not matched over 20 m (glare), its messenger seen all along
    stream = Stream(12000, seed=14)
    p = stream.position
    x = zigzag(p)
    seen = (p < 60.0) | (p > 80.0)
    stream.wire(0, x, np.full(p.shape, 1500.0), seen)
    stream.wire(10, x, np.full(p.shape, 2700.0), np.ones(p.shape, bool), miss=0.0)
    scan, _, truth, _, _, uncertain = run(stream, 1024, uncertain_rows=True)
    assert not np.any((truth == 10) & ~uncertain)
    lost = (stream.position[scan] > 61.5) & (stream.position[scan] < 78.5)
    assert np.all(uncertain[lost & (truth == 10)])
    assert np.count_nonzero(lost & (truth == 10)) > 0.9 * 17.0 / SPACING_M
    assert not np.any(uncertain[truth == 0])


@pytest.mark.parametrize("messengers", [1, 2])
def test_a_messenger_first_seen_where_its_contact_wire_was_lost_is_uncertain(
    messengers: int,
) -> None:
    # the contact wire seen over 60 m, then not matched over 12 m (a camera blinded and
    # glare); its messenger (an overlap's two) 1,200 mm above seen only there
    stream = Stream(6000, seed=16)
    p = stream.position
    x = zigzag(p)
    seen = (p < 60.0) | (p > 72.0)
    stream.wire(0, x, np.full(p.shape, 1700.0), seen)
    lost = (p > 61.0) & (p < 71.0)
    for k in range(messengers):
        stream.wire(10 + k, x + 150.0 * k, np.full(p.shape, 2900.0), lost, miss=0.0)
    _, _, truth, _, _, uncertain = run(stream, 1024, uncertain_rows=True)
    assert np.count_nonzero(truth >= 10) > 0.9 * messengers * 10.0 / SPACING_M
    assert np.all(uncertain[truth >= 10])
    assert not np.any(uncertain[truth == 0])


def test_a_wire_higher_than_contact_wires_run_is_a_messenger() -> None:
    # the contact wire unseen over the first 40 m (a camera glared, another looking along
    # both wires); its messenger 3,600 mm above the roof, seen all along
    stream = Stream(6000, seed=15)
    p = stream.position
    x = zigzag(p)
    stream.wire(0, x, np.full(p.shape, 2100.0), p > 40.0)
    stream.wire(10, x + 7.0, np.full(p.shape, 3600.0), np.ones(p.shape, bool), miss=0.0)
    _, _, truth, _, _, _ = run(stream, 1024)
    assert set(np.unique(truth).tolist()) == {0}
    assert TrackingConfig().max_height_mm < 3600.0


def test_a_lost_wire_keeps_its_number() -> None:
    # wire A is not matched over 5 m (a blinded camera and a missed detection): longer than
    # the gap a track bridges, shorter than re-identification; wire B stays in view
    stream = Stream(12000, seed=5)
    p = stream.position
    xa = zigzag(p)
    present = np.ones(p.shape, bool)
    present[(p > 60.0) & (p < 65.0)] = False
    stream.wire(0, xa, np.full(p.shape, 1700.0), present)
    stream.wire(1, xa + 250.0, np.full(p.shape, 1750.0), np.ones(p.shape, bool))
    _, wire, truth, _, _, _ = run(stream, 1024)
    assert np.unique(wire[truth == 0]).tolist() == [0]
    assert np.unique(wire[truth == 1]).tolist() == [1]


def test_short_tracks_and_sparse_noise_are_not_wires() -> None:
    stream = Stream(5000, seed=6)
    rng = stream.rng
    p = stream.position
    # a true object seen for 0.3 m: below MIN_TRACK_M
    s = np.arange(1000, 1000 + int(0.3 / SPACING_M))
    stream.points(20, s, np.full(s.shape, 100.0), np.full(s.shape, 1800.0))
    # noise points chaining within the gap gate every 0.5 m: too sparse for a wire
    s = np.arange(2000, 2000 + int(3.0 / SPACING_M), int(0.5 / SPACING_M))
    stream.points(30, s, 200.0 + rng.normal(0, 2, s.shape), 1900.0 + rng.normal(0, 2, s.shape))
    stream.wire(0, zigzag(p), np.full(p.shape, 1500.0), np.ones(p.shape, bool))
    _, _wire, truth, _, _, _ = run(stream, 1024)
    assert set(np.unique(truth).tolist()) == {0}
    assert MIN_TRACK_M >= 0.3


def test_link_fragments_chains_mutual_nearest_neighbours() -> None:
    # two wires 10 mm apart and a point jumping 8 mm: it breaks its chain
    scan = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    position = scan * SPACING_M
    x = np.array([0.0, 10.0, 0.2, 10.1, 0.3, 18.2, 0.4, 10.3])
    z = np.full(8, 1500.0)
    root = link_fragments(scan, position, x, z, 3.0, 150.0, 40.0)
    np.testing.assert_array_equal(root, [0, 1, 0, 1, 0, 5, 0, 7])
    assert link_fragments(scan[:0], position[:0], x[:0], z[:0], 3.0, 150.0, 40.0).shape == (0,)


def test_columns_must_keep_their_keys() -> None:
    tracker = WireTracker()
    tracker.push(
        np.array([0]), np.array([0.0]), np.array([0.0]), np.array([1500.0]), {"a": np.ones(1)}
    )
    with pytest.raises(ValueError, match="columns"):
        tracker.push(np.array([1]), np.array([0.1]), np.array([0.0]), np.array([1500.0]), {})
    with pytest.raises(ValueError, match="after scan"):
        tracker.push(
            np.array([0]), np.array([0.0]), np.array([0.0]), np.array([1500.0]), {"a": np.ones(1)}
        )
