"""Stereo matching (paper 3.1, figure 4) against the simulator's ground truth.

The candidates are made from the truth of a simulated chunk (where each wire, its silhouette
and its worn face fall in every camera, ``CameraTruth``) with 0.05 px of noise, so that the
matching is tested on its own, on the demo rig's true cameras: four wires of an overlap in
view, a blind camera, missed detections, ghosts, twelve wires, merged silhouettes.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, fields, replace

import numpy as np
import pytest

from catenary_linescan.calibration import ResolutionTable, resolution_table_from_camera
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.processor.features import FACE_RESOLVED_PX, FeatureConfig
from catenary_linescan.processor.matching import (
    Candidates,
    MatchConfig,
    Matches,
    camera_sigmas_px,
    covering_pairs,
    face_widths_mm,
    hypotheses,
    match,
    pad_candidates,
)
from catenary_linescan.processor.matching.evidence import unseen_in_lines
from catenary_linescan.processor.matching.geometry import _gather, _Geometry, _undistort
from catenary_linescan.simulator import DEMO_RIG_PATH, Simulation, load_rig, parse_settings
from catenary_linescan.simulator.simulation import Chunk

NOISE_PX = 0.05
RMS_PX = 0.05  # the calibration's reprojection RMS the tests assume


@dataclass
class Features:
    """A flat feature table (the ``FeatureTable`` protocol)."""

    scan: np.ndarray
    centre_px: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    face_left_px: np.ndarray
    face_right_px: np.ndarray
    contrast: np.ndarray
    polarity: np.ndarray
    outline_side: np.ndarray | None = None  # None: 0 (both edges or neither)

    def __post_init__(self) -> None:
        if self.outline_side is None:
            self.outline_side = np.zeros(self.scan.shape, np.int8)

    def drop(self, rows: np.ndarray) -> Features:
        keep = np.ones(self.scan.shape, bool)
        keep[rows] = False
        return Features(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))

    def add(self, other: Features) -> Features:
        values = [
            np.concatenate([getattr(self, f), getattr(other, f)]) for f in self.__dataclass_fields__
        ]
        order = np.lexsort((values[1], values[0]))
        return Features(*(v[order] for v in values))


def features_from_truth(chunk: Chunk, names: list[str], rng: np.random.Generator):
    """Per camera, the candidates a perfect feature extractor would give, plus noise.

    Contact wires give their face's edges and its midpoint (the contact point's image);
    messengers their silhouette's middle. Wire ``m`` of scan ``s`` is row ``wire_of``.
    """
    truth = chunk.truth
    out, wire_of = [], []
    for name in names:
        cam = truth.cameras[name]
        seen = np.isfinite(cam.left_px) & (cam.left_px > 1.0) & (cam.right_px < 4094.0)
        s, m = np.nonzero(seen)
        face_l = cam.face_left_px[s, m] + rng.normal(0, NOISE_PX, s.shape)
        face_r = cam.face_right_px[s, m] + rng.normal(0, NOISE_PX, s.shape)
        left = cam.left_px[s, m] + rng.normal(0, NOISE_PX, s.shape)
        right = cam.right_px[s, m] + rng.normal(0, NOISE_PX, s.shape)
        has_face = np.isfinite(face_l) & (face_r - face_l > 1.0)
        face_l = np.where(has_face, face_l, np.nan)
        face_r = np.where(has_face, face_r, np.nan)
        centre = np.where(has_face, 0.5 * (face_l + face_r), 0.5 * (left + right))
        order = np.lexsort((centre, s))
        table = Features(
            s[order],
            centre[order],
            left[order],
            right[order],
            face_l[order],
            face_r[order],
            np.full(s.shape, 0.3),
            np.ones(s.shape, np.int8),
        )
        out.append(table)
        wire_of.append(m[order])
    return out, wire_of


def dark_silhouettes(scan: np.ndarray, *centres: np.ndarray) -> Features:
    """Dark silhouettes 20 px wide, no face, at ``centres`` (each ``(n,)``) of ``scan``."""
    u = np.concatenate(centres)
    s = np.concatenate([scan] * len(centres))
    order = np.lexsort((u, s))
    nan = np.full(u.shape, np.nan)
    return Features(
        s[order],
        u[order],
        u[order] - 10,
        u[order] + 10,
        nan,
        nan,
        np.full(u.shape, 0.4),
        -np.ones(u.shape, np.int8),
    )


@pytest.fixture(scope="module")
def rig_cameras() -> tuple[list[str], list[LineScanCamera]]:
    rig = load_rig(DEMO_RIG_PATH)
    return [c.name for c in rig.cameras], [c.model() for c in rig.cameras]


@pytest.fixture(scope="module")
def overlap_chunk() -> Chunk:
    """A chunk of scans at an overlap's middle mast: two contact wires, two messengers."""
    sim = Simulation(parse_settings({"seed": 21, "overlap": True, "length_m": 300.0}))
    middle = sim.scene.masts[sim.scene.overlap_masts[1]].chainage_m
    chainage = sim.motion.chainage_m(sim.motion.scan_times(0, sim.scans))
    scan = int(np.searchsorted(chainage, middle))
    chunk = sim.chunk(scan // sim.chunk_scans)
    assert np.all(chunk.truth.present.sum(axis=1) == 4)
    return chunk


def verified(cameras, candidates, sigma_px, config=None) -> Matches:
    """The points ``match`` verified (``min_cameras`` cameras)."""
    matches = match(cameras, candidates, sigma_px, config)
    return matches.take(matches.verified)


def sigma(n: int = 4, rms: float = RMS_PX) -> np.ndarray:
    return camera_sigmas_px([rms] * n, 0.15)


def truth_of(matches: Matches, chunk: Chunk, names, cameras):
    """Nearest true wire of each match (by its contact point, or a messenger's axis)."""
    truth = chunk.truth
    x = truth.x_roof_mm[matches.scan]
    z = truth.z_roof_mm[matches.scan]
    contact = np.isfinite(truth.wear_width_mm[matches.scan])
    z = np.where(contact, z, z + 7.0)  # a messenger's axis, 7 mm above its underside
    distance = np.hypot(x - matches.x_mm[:, None], z - matches.z_mm[:, None])
    which = np.argmin(distance, axis=1)
    return (
        which,
        distance[np.arange(matches.count), which],
        contact[np.arange(matches.count), which],
    )


def test_four_wires_of_an_overlap_are_all_found(overlap_chunk, rig_cameras) -> None:
    names, cameras = rig_cameras
    features, _ = features_from_truth(overlap_chunk, names, np.random.default_rng(1))
    candidates = pad_candidates(features, overlap_chunk.scans)
    matches = verified(cameras, candidates, sigma())
    which, distance, contact = truth_of(matches, overlap_chunk, names, cameras)
    # one point per wire and scan, nothing else
    assert matches.count == 4 * overlap_chunk.scans
    counts = np.bincount(matches.scan * 4 + which, minlength=4 * overlap_chunk.scans)
    assert np.all(counts == 1)
    # contact points to a fraction of a millimetre; messengers (their axis) to a few mm
    assert np.max(distance[contact]) < 0.3
    assert np.max(distance[~contact]) < 5.0
    assert np.all(matches.from_face[contact])
    assert np.all(matches.cameras == 4)


def test_a_blind_camera_leaves_three(overlap_chunk, rig_cameras) -> None:
    names, cameras = rig_cameras
    for blind in range(4):
        features, _ = features_from_truth(overlap_chunk, names, np.random.default_rng(2))
        features[blind] = features[blind].drop(np.arange(features[blind].scan.shape[0]))
        matches = verified(cameras, pad_candidates(features, overlap_chunk.scans), sigma())
        _which, distance, contact = truth_of(matches, overlap_chunk, names, cameras)
        assert matches.count == 4 * overlap_chunk.scans, f"camera {blind} blind"
        assert np.max(distance[contact]) < 0.5
        assert np.all(matches.slot[:, blind] == -1)
        assert np.all(matches.cameras == 3)


def test_a_missed_wire_in_one_camera(overlap_chunk, rig_cameras) -> None:
    names, cameras = rig_cameras
    rng = np.random.default_rng(3)
    features, wire_of = features_from_truth(overlap_chunk, names, rng)
    # camera 2 misses contact wire B (id 2) in every other scan, camera 0 contact wire A in
    # a random fifth of the scans
    miss = np.flatnonzero((wire_of[2] == 2) & (features[2].scan % 2 == 0))
    features[2] = features[2].drop(miss)
    miss = np.flatnonzero((wire_of[0] == 0) & (rng.random(wire_of[0].shape) < 0.2))
    features[0] = features[0].drop(miss)
    matches = verified(cameras, pad_candidates(features, overlap_chunk.scans), sigma())
    _, distance, contact = truth_of(matches, overlap_chunk, names, cameras)
    assert matches.count == 4 * overlap_chunk.scans
    assert np.max(distance[contact]) < 0.5


def test_a_ghost_shows_only_sky_to_the_camera_that_did_not_confirm_it(
    overlap_chunk, rig_cameras
) -> None:
    """Rays of different wires that three cameras pair meet where there is no wire (a
    ghost): the fourth camera's pixels show sky there (``unseen_in_lines``). A point 300 mm
    beneath a contact wire and 150 mm aside, given to three cameras, is verified by the
    matching, and the rendered lines of the fourth speak against it; a contact wire whose
    candidates the fourth camera lacks is not spoken against: its pixels show the wire."""
    names, cameras = rig_cameras
    features, wire_of = features_from_truth(overlap_chunk, names, np.random.default_rng(7))
    n = overlap_chunk.scans
    truth = overlap_chunk.truth
    x, z = truth.x_roof_mm[:, 0] - 150.0, truth.z_roof_mm[:, 0] - 300.0
    for c in range(3):
        features[c] = features[c].add(dark_silhouettes(np.arange(n), cameras[c].project(x, z)))
    features[3] = features[3].drop(np.flatnonzero(wire_of[3] == 2))  # misses contact wire B
    candidates = pad_candidates(features, n)
    matches = match(cameras, candidates, sigma())
    lines = [overlap_chunk.lines[name] for name in names]
    full = [float(np.iinfo(line.dtype).max) for line in lines]
    against = unseen_in_lines(
        cameras, lines, [0] * 4, full, candidates, matches, 14.8, FeatureConfig()
    )
    at_ghost = np.hypot(matches.x_mm - x[matches.scan], matches.z_mm - z[matches.scan]) < 5.0
    on_wire_b = (
        np.hypot(
            matches.x_mm - truth.x_roof_mm[matches.scan, 2],
            matches.z_mm - truth.z_roof_mm[matches.scan, 2],
        )
        < 1.0
    )
    assert np.count_nonzero(at_ghost) == n and np.all(matches.verified[at_ghost])
    assert np.all(against[at_ghost])
    assert np.count_nonzero(on_wire_b) == n and np.all(matches.slot[on_wire_b, 3] < 0)
    assert not np.any(against[~at_ghost])


def test_two_views_cannot_be_verified(overlap_chunk, rig_cameras) -> None:
    names, cameras = rig_cameras
    features, _ = features_from_truth(overlap_chunk, names, np.random.default_rng(4))
    for blind in (1, 2):
        features[blind] = features[blind].drop(np.arange(features[blind].scan.shape[0]))
    candidates = pad_candidates(features, overlap_chunk.scans)
    assert verified(cameras, candidates, sigma()).count == 0
    # a rig of two cameras (or a setting) takes two views: every pairing is a point then
    loose = verified(cameras, candidates, sigma(), MatchConfig(min_cameras=2))
    assert loose.count >= 4 * overlap_chunk.scans


def test_two_view_points_are_returned_unverified(overlap_chunk, rig_cameras) -> None:
    """A blind camera and a wire missed by another leave two views: the point comes back
    unverified (every pairing of unused detections does), for tracking to take where it
    continues the wire."""
    names, cameras = rig_cameras
    features, wire_of = features_from_truth(overlap_chunk, names, np.random.default_rng(10))
    features[1] = features[1].drop(np.arange(features[1].scan.shape[0]))  # blind
    missed = np.flatnonzero((wire_of[3] == 0) & (features[3].scan % 3 == 0))
    features[3] = features[3].drop(missed)  # contact wire A missed in a third of the scans
    matches = match(cameras, pad_candidates(features, overlap_chunk.scans), sigma())
    which, distance, _contact = truth_of(matches, overlap_chunk, names, cameras)
    good = matches.verified
    assert np.all(distance[good] < 5.0)
    scans_missed = np.arange(0, overlap_chunk.scans, 3)
    a_verified = good & (which == 0)
    assert not np.any(np.isin(matches.scan[a_verified], scans_missed))
    a_two = ~good & (which == 0) & (distance < 0.5)
    np.testing.assert_array_equal(np.unique(matches.scan[a_two]), scans_missed)
    assert np.all(matches.cameras[a_two] == 2)
    # without the option, none
    strict = match(
        cameras, pad_candidates(features, overlap_chunk.scans), sigma(), MatchConfig(two_view=False)
    )
    assert np.all(strict.verified)


def test_spurious_candidates_make_few_points(overlap_chunk, rig_cameras) -> None:
    """Random candidates (glare, fittings seen by one camera), three per camera and scan,
    make a point of two of them and a coincidence in a third camera in about one scan in ten:
    each in one scan only, which tracking drops (``test_tracking``)."""
    names, cameras = rig_cameras
    rng = np.random.default_rng(5)
    features, _ = features_from_truth(overlap_chunk, names, rng)
    n = overlap_chunk.scans
    for c in range(4):
        s = np.repeat(np.arange(n), 3)
        u = rng.uniform(50.0, 4040.0, s.shape)
        nan = np.full(s.shape, np.nan)
        noise = Features(
            s, u, u - 8, u + 8, nan, nan, np.full(s.shape, 0.1), np.ones(s.shape, np.int8)
        )
        features[c] = features[c].add(noise)
    matches = verified(cameras, pad_candidates(features, n), sigma())
    _, distance, _ = truth_of(matches, overlap_chunk, names, cameras)
    real = distance < 5.0
    assert np.count_nonzero(real) == 4 * n  # every wire still found
    ghosts = ~real
    assert np.count_nonzero(ghosts) <= 0.2 * n
    # never twice in a row at one place
    s, x, z = matches.scan[ghosts], matches.x_mm[ghosts], matches.z_mm[ghosts]
    near = np.hypot(x[:, None] - x[None, :], z[:, None] - z[None, :]) < 20.0
    assert not np.any(near & (np.abs(s[:, None] - s[None, :]) == 1))


def projected_features(
    cameras, x: np.ndarray, z: np.ndarray, rng: np.random.Generator, half_px=None, polarity=-1
) -> list[Features]:
    """Each camera's silhouettes, no face, of the wires at ``x``, ``z`` ``(n, w)`` [mm]: their
    middles with ``NOISE_PX`` of noise, ``half_px`` wide each side (None: a 12-mm wire's)."""
    features = []
    for camera in cameras:
        u = camera.project(x, z) + rng.normal(0.0, NOISE_PX, x.shape)
        if half_px is None:
            half = np.abs(0.5 * camera.project(x + 6.0, z) - 0.5 * camera.project(x - 6.0, z))
        else:
            half = np.full(x.shape, float(half_px))
        s, m = np.nonzero(np.isfinite(u))
        order = np.lexsort((u[s, m], s))
        s, uu, hh = s[order], u[s, m][order], half[s, m][order]
        nan = np.full(s.shape, np.nan)
        contrast = np.full(s.shape, 0.3)
        sign = np.full(s.shape, polarity, np.int8)
        features.append(Features(s, uu, uu - hh, uu + hh, nan, nan, contrast, sign))
    return features


def assert_each_wire_once(matches: Matches, x: np.ndarray, z: np.ndarray) -> None:
    """Every point within 0.5 mm of a wire at ``x``, ``z`` ``(n, w)``, each wire of each scan
    once."""
    distance = np.hypot(
        x[matches.scan] - matches.x_mm[:, None], z[matches.scan] - matches.z_mm[:, None]
    )
    assert np.max(distance.min(axis=1)) < 0.5
    which = distance.argmin(axis=1)
    assert np.all(np.bincount(matches.scan * x.shape[1] + which) == 1)


def test_twelve_wires_in_view(rig_cameras) -> None:
    """Turnouts and overlaps: the best systems follow 10-12 wires."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(6)
    n, wires = 200, 12
    x = np.linspace(-550.0, 550.0, wires)[None, :] + rng.normal(0.0, 5.0, (n, wires))
    z = np.where(
        np.arange(wires) % 3 == 0, 1500.0, np.where(np.arange(wires) % 3 == 1, 1900.0, 2400.0)
    )
    z = z[None, :] + rng.normal(0.0, 20.0, (n, wires))
    features = projected_features(cameras, x, z, rng, half_px=12, polarity=1)
    matches = verified(cameras, pad_candidates(features, n), sigma())
    assert matches.count == n * wires
    assert_each_wire_once(matches, x, z)


def test_two_wires_near_a_crossing_are_both_found(rig_cameras) -> None:
    """A turnout's wires at one height 21-40 mm apart (surfaces 6-25 mm apart): each camera
    sees two silhouettes, and both wires are points (two wires closer than the widest wire
    and the blur touch in the images: the tracker flags those, ``CROSSING_MM``)."""
    _names, cameras = rig_cameras
    n = 200
    apart = np.linspace(21.0, 40.0, n)
    x = np.stack([-60.0 - 0.5 * apart, -60.0 + 0.5 * apart], axis=1)
    z = np.full((n, 2), 1600.0)
    features = projected_features(cameras, x, z, np.random.default_rng(8))
    matches = verified(cameras, pad_candidates(features, n), sigma())
    assert matches.count == 2 * n
    assert_each_wire_once(matches, x, z)


def test_two_worn_wires_nearer_a_crossing_are_both_found(rig_cameras) -> None:
    """A turnout's worn wires at one height 14-20 mm apart: each camera sees the two faces
    apart (5 mm wide, 9-15 mm between their middles), and two faces are two wires once their
    axes are the narrowest wire's width apart: level wires lie no closer."""
    _names, cameras = rig_cameras
    n = 200
    apart = np.linspace(14.0, 20.0, n)
    x = np.stack([-60.0 - 0.5 * apart, -60.0 + 0.5 * apart], axis=1)
    z = np.full((n, 2), 1600.0)
    features = []
    for f in projected_features(cameras, x, z, np.random.default_rng(10)):
        half_face = (f.right_px - f.left_px) / 2.0 * 2.5 / 6.0
        face = replace(
            f, face_left_px=f.centre_px - half_face, face_right_px=f.centre_px + half_face
        )
        features.append(face)
    matches = verified(cameras, pad_candidates(features, n), sigma())
    assert matches.count == 2 * n
    assert_each_wire_once(matches, x, z)


def test_what_rests_on_a_wire_is_one_point_with_it(rig_cameras) -> None:
    """A crossing's pipe clamped above the wire, 20 mm higher and 5 mm across: one wire seen
    twice for the matching (the tracker tells a wire from what rests on it)."""
    _names, cameras = rig_cameras
    n = 200
    x = np.stack([np.full(n, -60.0), np.full(n, -55.0)], axis=1)
    z = np.stack([np.full(n, 1600.0), np.full(n, 1620.0)], axis=1)
    features = projected_features(cameras, x, z, np.random.default_rng(9))
    matches = verified(cameras, pad_candidates(features, n), sigma())
    assert np.all(np.bincount(matches.scan, minlength=n) == 1)


def test_a_wire_in_line_with_its_messenger(rig_cameras) -> None:
    """In one camera a contact wire and its messenger are one silhouette (white daylight):
    its centre is neither's. Two other cameras see each; the merged silhouette supports both."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(7)
    n = 100
    x_wire = np.full(n, 120.0)
    z_wire = np.full(n, 1700.0)
    # the messenger 1200 mm up, exactly on camera 2's ray through the wire
    centre = cameras[2].centre_mm
    direction = np.array([x_wire[0] - centre[0], z_wire[0] - centre[1]])
    direction /= np.hypot(*direction)
    x_mess = np.full(n, x_wire[0] + direction[0] * 1200.0 / direction[1])
    z_mess = np.full(n, 2900.0)
    features = []
    for c, camera in enumerate(cameras):
        u_w = camera.project(x_wire, z_wire) + rng.normal(0, NOISE_PX, n)
        u_m = camera.project(x_mess, z_mess) + rng.normal(0, NOISE_PX, n)
        s = np.arange(n)
        nan = np.full(n, np.nan)
        one = np.ones(n, np.int8)
        if c == 2:  # one merged, darker silhouette, 30 px, its centre off both
            table = Features(s, u_w + 6.0, u_w - 15.0, u_w + 15.0, nan, nan, np.full(n, 0.5), -one)
        elif c == 3:  # this camera misses the wire
            table = Features(s, u_m, u_m - 8, u_m + 8, nan, nan, np.full(n, 0.4), -one)
        else:
            table = dark_silhouettes(s, u_w, u_m)
        features.append(table)
    matches = verified(cameras, pad_candidates(features, n), sigma())
    near_wire = np.hypot(matches.x_mm - x_wire[0], matches.z_mm - z_wire[0]) < 1.0
    near_mess = np.hypot(matches.x_mm - x_mess[0], matches.z_mm - z_mess[0]) < 3.0
    assert np.count_nonzero(near_wire) == n  # two cameras and the merged silhouette
    assert np.count_nonzero(near_mess) == n
    assert matches.count == 2 * n
    assert np.all(matches.slot[near_wire][:, 2] == -1)  # its centre was not used
    # without the merged silhouette's support the wire has two views only
    strict = verified(
        cameras, pad_candidates(features, n), sigma(), MatchConfig(support_merged=False)
    )
    assert not np.any(np.hypot(strict.x_mm - x_wire[0], strict.z_mm - z_wire[0]) < 1.0)


def test_a_wire_nearly_in_line_with_its_messenger_keeps_its_other_cameras(rig_cameras) -> None:
    """In camera 2 a contact wire and its messenger fall under 1 px apart: one detection, whose
    centre confirms both points. The point that takes it leaves the other three cameras,
    enough for the other point: both are found, each located by the cameras that see it
    alone."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(13)
    n = 50
    x_wire, z_wire = np.full(n, -60.0), np.full(n, 1650.0)
    centre = cameras[2].centre_mm
    direction = np.array([x_wire[0] - centre[0], z_wire[0] - centre[1]])
    direction /= np.hypot(*direction)
    x_mess = np.full(n, x_wire[0] + direction[0] * 1100.0 / direction[1] + 0.4)
    z_mess = np.full(n, 2750.0)
    features = []
    s = np.arange(n)
    for c, camera in enumerate(cameras):
        u_w = camera.project(x_wire, z_wire) + rng.normal(0, NOISE_PX, n)
        u_m = camera.project(x_mess, z_mess) + rng.normal(0, NOISE_PX, n)
        if c == 2:
            assert np.all(np.abs(u_w - u_m) < 0.9)
            u = 0.5 * (u_w + u_m)
            nan = np.full(n, np.nan)
            table = Features(s, u, u - 12, u + 12, nan, nan, np.full(n, 0.5), -np.ones(n, np.int8))
        else:
            table = dark_silhouettes(s, u_w, u_m)
        features.append(table)
    matches = verified(cameras, pad_candidates(features, n), sigma())
    near_wire = np.hypot(matches.x_mm - x_wire[0], matches.z_mm - z_wire[0]) < 1.0
    near_mess = np.hypot(matches.x_mm - x_mess[0], matches.z_mm - z_mess[0]) < 3.0
    assert np.count_nonzero(near_wire) == n and np.count_nonzero(near_mess) == n
    assert matches.count == 2 * n
    # camera 2's silhouette, wider than the wire's in the others, locates neither
    assert np.all(matches.slot[:, 2] == -1) and np.all(matches.cameras >= 3)


def test_two_cameras_pair_what_agrees(rig_cameras) -> None:
    """A rig of two cameras sees a worn contact wire (a face, 11 mm wide) and its messenger
    (no face, 14 mm) 1100 mm above: the four pairings of their images all intersect. The
    wire and the messenger are the ones whose silhouettes agree in width and whose faces
    match, not the ghosts that pair one camera's wire with the other's messenger."""
    _names, all_cameras = rig_cameras
    cameras = [all_cameras[0], all_cameras[3]]
    rng = np.random.default_rng(17)
    n = 40
    wires = [(-40.0, 1600.0, 11.0, 7.0), (-42.0, 2700.0, 14.0, None)]  # x, z, width, face
    features = []
    s = np.arange(n)
    for camera in cameras:
        columns: list[list[np.ndarray]] = [[] for _ in range(6)]
        for x, z, width, face in wires:
            xs, zs = np.full(n, x), np.full(n, z)
            u = camera.project(xs, zs) + rng.normal(0, NOISE_PX, n)
            _, du_dx, du_dz = _Geometry.of(camera).project(xs, zs)
            half = 0.5 * width * np.hypot(du_dx, du_dz)
            face_half = np.full(n, np.nan) if face is None else 0.5 * face * np.abs(du_dx)
            for column, value in zip(
                columns, (s, u, u - half, u + half, u - face_half, u + face_half), strict=True
            ):
                column.append(value)
        ss, u, lo, hi, fl, fr = (np.concatenate(c) for c in columns)
        order = np.lexsort((u, ss))
        features.append(
            Features(
                ss[order],
                u[order],
                lo[order],
                hi[order],
                fl[order],
                fr[order],
                np.full(2 * n, 0.4),
                np.ones(2 * n, np.int8),
            )
        )
    matches = verified(cameras, pad_candidates(features, n), sigma(2))
    assert matches.count == 2 * n
    on_wire = np.hypot(matches.x_mm - (-40.0), matches.z_mm - 1600.0) < 1.0
    # the messenger is located by its silhouettes' middles: its axis
    on_messenger = np.hypot(matches.x_mm - (-42.0), matches.z_mm - 2700.0) < 8.0
    assert np.count_nonzero(on_wire) == n and np.count_nonzero(on_messenger) == n


@pytest.mark.parametrize("polarity", [-1, 0])
def test_a_clamp_on_a_new_wire_gives_no_position(rig_cameras, polarity: int) -> None:
    """White daylight, a new wire (no face): at a dropper clamp every camera sees the clamp's
    dark silhouette, 22 mm wide and centred 5 mm above the wire's axis, and the silhouettes
    agree on the clamp's middle. It is no wire's: those scans get no position, not a point
    5 mm off (which they get when any width is taken for a wire's). So also behind the
    filter (``polarity`` 0: an outline of dark sides and a lit bottom, features setting
    ``outlines``), where a candidate wider than any wire is objects in line."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(11)
    n = 60
    clamp = np.arange(n) % 20 == 7
    x = np.full(n, 80.0)
    z_axis = np.full(n, 1705.0)
    z_seen = np.where(clamp, z_axis + 5.0, z_axis)
    width_mm = np.where(clamp, 22.0, 10.8)
    features = []
    for camera in cameras:
        u = camera.project(x, z_seen) + rng.normal(0, NOISE_PX, n)
        _, du_dx, du_dz = _Geometry.of(camera).project(x, z_seen)
        half = 0.5 * width_mm * np.hypot(du_dx, du_dz)
        nan = np.full(n, np.nan)
        features.append(
            Features(
                np.arange(n),
                u,
                u - half,
                u + half,
                nan,
                nan,
                np.full(n, 0.5),
                np.full(n, polarity, np.int8),
            )
        )
    matches = verified(cameras, pad_candidates(features, n), sigma())
    located = np.isfinite(matches.x_mm)
    assert set(matches.scan[located]) == set(np.flatnonzero(~clamp))
    on_wire = np.hypot(matches.x_mm[located] - 80.0, matches.z_mm[located] - 1705.0)
    assert np.max(on_wire) < 0.5
    assert np.all(matches.cameras[located] == 4)
    anything = verified(
        cameras, pad_candidates(features, n), sigma(), MatchConfig(max_wire_width_mm=30.0)
    )
    off = np.hypot(anything.x_mm - 80.0, anything.z_mm - 1705.0)[clamp[anything.scan]]
    assert off.shape[0] == np.count_nonzero(clamp) and np.all(off > 4.0)


def test_two_points_share_a_camera_s_detection(rig_cameras) -> None:
    """Two objects in line in one camera give it one detection; the point the four cameras
    confirm lends it to the one that has only that camera and two more."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(8)
    n = 100
    centre = cameras[1].centre_mm
    a = np.array([-80.0, 1600.0])
    direction = (a - centre) / np.hypot(*(a - centre))
    b = a + direction * 900.0  # in line with a for camera 1
    features = []
    for c, camera in enumerate(cameras):
        u = [
            camera.project(np.full(n, p[0]), np.full(n, p[1])) + rng.normal(0, NOISE_PX, n)
            for p in (a, b)
        ]
        if c == 1:
            u = [u[0]]  # one detection for both
        if c == 3:
            u = [u[0]]  # camera 3 misses b
        s = np.tile(np.arange(n), len(u))
        uu = np.concatenate(u)
        order = np.lexsort((uu, s))
        s, uu = s[order], uu[order]
        nan = np.full(s.shape, np.nan)
        features.append(
            Features(
                s, uu, uu - 10, uu + 10, nan, nan, np.full(s.shape, 0.3), np.ones(s.shape, np.int8)
            )
        )
    matches = verified(cameras, pad_candidates(features, n), sigma())
    at_a = np.hypot(matches.x_mm - a[0], matches.z_mm - a[1]) < 1.0
    at_b = np.hypot(matches.x_mm - b[0], matches.z_mm - b[1]) < 1.0
    assert np.count_nonzero(at_a) == n
    assert np.count_nonzero(at_b) == n
    # each detection used once: camera 1's went to one of them
    assert np.all((matches.slot[at_a, 1] >= 0) != (matches.slot[at_b, 1] >= 0))


def test_the_window_follows_the_calibration(rig_cameras) -> None:
    _names, cameras = rig_cameras
    n = 50
    x, z = np.full(n, 50.0), np.full(n, 2000.0)
    features = []
    for c, camera in enumerate(cameras):
        u = camera.project(x, z) + (1.5 if c == 3 else 0.0)  # camera 3 off by 1.5 px
        s = np.arange(n)
        nan = np.full(n, np.nan)
        features.append(
            Features(s, u, u - 10, u + 10, nan, nan, np.full(n, 0.3), np.ones(n, np.int8))
        )
    candidates = pad_candidates(features, n)
    tight = verified(cameras, candidates, sigma(rms=0.05))
    loose = verified(cameras, candidates, sigma(rms=0.6))
    assert np.all(tight.cameras == 3) and np.all(tight.slot[:, 3] == -1)
    assert np.all(loose.cameras == 4)


def tables_of(cameras: list[LineScanCamera]) -> list[ResolutionTable]:
    """Each camera's look-up table over the demo rig's field."""
    x, z = np.arange(-600.0, 601.0, 100.0), np.arange(1300.0, 2501.0, 100.0)
    return [resolution_table_from_camera(c, x, z) for c in cameras]


def clear_of_silhouette(candidates: Candidates, matches: Matches) -> np.ndarray:
    """Per match and camera ``(m, C)``: a face whose edges both lie FACE_RESOLVED_PX or more
    inside the silhouette."""
    left, right, face_left, face_right = _gather(
        matches.scan,
        matches.slot,
        candidates.left_px,
        candidates.right_px,
        candidates.face_left_px,
        candidates.face_right_px,
    )
    return np.fmin(face_left - left, right - face_right) >= FACE_RESOLVED_PX


def test_face_widths_from_the_camera_model(overlap_chunk, rig_cameras) -> None:
    names, cameras = rig_cameras
    features, _ = features_from_truth(overlap_chunk, names, np.random.default_rng(9))
    candidates = pad_candidates(features, overlap_chunk.scans)
    matches = verified(cameras, candidates, sigma())
    tables = tables_of(cameras)
    roll = np.radians(overlap_chunk.truth.roll_deg)
    widths = face_widths_mm(cameras, tables, candidates, matches, roll)
    which, _distance, contact = truth_of(matches, overlap_chunk, names, cameras)
    true_w = overlap_chunk.truth.wear_width_inplane_mm[matches.scan, which]
    worn = contact & (true_w > 1.0)
    error = widths.width_mm[worn] - true_w[worn]
    # 0.05 px on each edge is 0.03 mm per camera at 0.4 mm/px, 0.014 mm over four
    assert abs(np.mean(error)) < 0.005
    assert np.sqrt(np.mean(error**2)) < 0.02
    assert np.max(np.abs(error)) < 0.06
    assert np.all(widths.cameras[worn] == 4)
    # the look-up table of the same model agrees to its interpolation (about 1 %)
    ratio = widths.table_ratio[worn]
    assert np.nanmax(np.abs(ratio - 1.0)) < 0.01
    # messengers have no face: width 0 (none seen), not NaN
    assert np.all(widths.width_mm[~contact] == 0.0)
    # a "face" wider than a contact wire can be is a fitting's: not a width
    capped = face_widths_mm(cameras, tables, candidates, matches, roll, max_width_mm=3.0)
    assert np.all(np.isnan(capped.width_mm[worn & (true_w > 3.5)]))


@pytest.mark.parametrize("polarity", [-1, 1])
def test_a_dark_silhouette_s_face_edge_merged_with_its_silhouette_gives_way(
    overlap_chunk, rig_cameras, polarity: int
) -> None:
    """A dark silhouette's face edge closer to its silhouette than FACE_RESOLVED_PX is one
    blurred step with it, outward by more than the wire's side between them: camera 0's
    right face edge, 0.3 px outward (about 0.12 mm of width) with its silhouette 0.4 px
    beyond, is left out where two resolved cameras agree, though within the tolerance of
    the median. A bright face on a darker sky (night, the filter) is off by far less there,
    and its camera stays in the mean."""
    names, cameras = rig_cameras
    features, _ = features_from_truth(overlap_chunk, names, np.random.default_rng(9))
    features = [replace(f, polarity=np.full(f.scan.shape, polarity, np.int8)) for f in features]
    merged = features[0].face_right_px + 0.3
    features[0] = replace(features[0], face_right_px=merged, right_px=merged + 0.4)
    candidates = pad_candidates(features, overlap_chunk.scans)
    matches = verified(cameras, candidates, sigma())
    roll = np.radians(overlap_chunk.truth.roll_deg)
    widths = face_widths_mm(cameras, tables_of(cameras), candidates, matches, roll)
    which, _distance, contact = truth_of(matches, overlap_chunk, names, cameras)
    true_w = overlap_chunk.truth.wear_width_inplane_mm[matches.scan, which]
    others = np.count_nonzero(clear_of_silhouette(candidates, matches)[:, 1:], axis=1) >= 2
    worn = contact & (true_w > 1.0) & (matches.slot[:, 0] >= 0) & others
    assert np.count_nonzero(worn) > 100
    wide = widths.per_camera_mm[worn, 0] - true_w[worn]
    assert 0.08 < np.median(wide) < 0.25  # within the tolerance of the others
    error = widths.width_mm[worn] - true_w[worn]
    if polarity < 0:
        # camera 0 in the mean would make it about 0.03 mm; two or three cameras' noise
        assert abs(np.mean(error)) < 0.005 and np.max(np.abs(error)) < 0.08
        assert np.all(widths.cameras[worn] <= 3)
    else:
        assert 0.02 < np.mean(error) < 0.04
        assert np.all(widths.cameras[worn] == 4)


def test_pad_candidates_caps_by_contrast_and_orders_by_position() -> None:
    s = np.array([0, 0, 0, 1, 2, 2])
    u = np.array([30.0, 10.0, 20.0, 5.0, 7.0, 3.0])
    contrast = np.array([0.5, 0.1, 0.9, 0.2, 0.3, 0.4])
    nan = np.full(6, np.nan)
    table = Features(s, u, u - 1, u + 1, nan, nan, contrast, np.ones(6, np.int8))
    padded = pad_candidates([table, table], 4, max_candidates=2)
    assert padded.shape == (4, 2, 2)
    np.testing.assert_array_equal(padded.centre_px[0, 0], [20.0, 30.0])  # 10 (weakest) out
    np.testing.assert_array_equal(padded.centre_px[2, 1], [3.0, 7.0])
    assert np.isnan(padded.centre_px[1, 0, 1]) and np.all(np.isnan(padded.centre_px[3]))
    np.testing.assert_array_equal(padded.detection[0, 0], [2, 0])


def test_covering_pairs() -> None:
    centres = [np.array([x, 100.0]) for x in (-700.0, -250.0, 250.0, 700.0)]
    pairs = covering_pairs(centres, 3)
    assert pairs == [(0, 3), (1, 2)]  # the widest baseline first; every triple holds one
    assert covering_pairs(centres, 2) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert len(covering_pairs(centres[:3], 3)) == 1


def test_enumeration_is_the_same_by_pair_and_grouped(
    overlap_chunk, rig_cameras, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both sides of ``_ENUMERATE_GROUP_ROWS`` (every camera pair at once, or one pair at a
    time) give the same hypotheses, bit for bit, in the same order: on wires, ghosts and
    candidates of either polarity, for every pair and the covering pairs, two and three
    cameras needed."""
    names, cameras = rig_cameras
    rng = np.random.default_rng(8)
    features, _ = features_from_truth(overlap_chunk, names, rng)
    n = overlap_chunk.scans
    for c in range(4):
        s = np.repeat(np.arange(n), 2)
        u = rng.uniform(50.0, 4040.0, s.shape)
        nan = np.full(s.shape, np.nan)
        polarity = rng.integers(-1, 2, s.shape).astype(np.int8)
        ghosts = Features(s, u, u - 8, u + 8, nan, nan, np.full(s.shape, 0.1), polarity)
        features[c] = features[c].add(ghosts)
    candidates = pad_candidates(features, n)
    ideal = [
        np.stack([_undistort(cam, v[:, c, :]) for c, cam in enumerate(cameras)], axis=1)
        for v in (candidates.centre_px, candidates.left_px, candidates.right_px)
    ]
    geometry = [_Geometry.of(camera) for camera in cameras]
    every_pair = list(itertools.combinations(range(4), 2))
    covering = covering_pairs([g.centre for g in geometry], 3)
    for pairs, needed in ((every_pair, 2), (every_pair, 3), (covering, 3)):
        results = []
        for rows in (0, 10**9):  # one pair at a time; every pair at once
            monkeypatch.setattr(hypotheses, "_ENUMERATE_GROUP_ROWS", rows)
            results.append(
                hypotheses._enumerate(
                    geometry,
                    ideal[0],
                    (ideal[1], ideal[2]),
                    candidates.polarity,
                    candidates.outline_side,
                    sigma(),
                    MatchConfig(),
                    4.0 * 4096,
                    needed,
                    pairs,
                )
            )
        by_pair, grouped = results
        assert by_pair.scan.shape[0] > 4 * n
        for field in fields(by_pair):
            a, b = getattr(by_pair, field.name), getattr(grouped, field.name)
            assert a.dtype == b.dtype, field.name
            np.testing.assert_array_equal(a, b, err_msg=field.name, strict=True)


def test_a_wire_whose_outline_shows_on_one_side_is_located_at_its_axis(rig_cameras) -> None:
    """An unworn wire by day behind the band-pass filter, lit from one side: each camera
    sees one of its dark sides against the sky (an edge of its outline) and, on the other
    side, its lit part ending 30 % of the wire inside the outline. The middles of such
    silhouettes are millimetres off the axis, each camera's its own way (the point used to be
    found in a few scans only, centimetres high); from the outline's edge, a radius inward at
    the point, every camera's image is the axis. The radius the matching assumes (6.35 mm)
    is not this wire's (6.9 mm): the edges on both sides measure it, and the matching is
    done again with it."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(19)
    n = 60
    radius = 6.9
    x_axis = np.linspace(-300.0, 300.0, n)
    z_axis = np.linspace(1450.0, 2300.0, n)
    s = np.arange(n)
    features = []
    for c, camera in enumerate(cameras):
        u = camera.project(x_axis, z_axis)
        _, gx, gz = _Geometry.of(camera).project(x_axis, z_axis)
        half = radius * np.hypot(gx, gz)
        left = u - half + rng.normal(0, NOISE_PX, n)
        right = u + half + rng.normal(0, NOISE_PX, n)
        side = -1 if c < 2 else 1  # the left dark side shows to cameras 0 and 1
        if side < 0:
            right = right - 0.6 * half
        else:
            left = left + 0.6 * half
        nan = np.full(n, np.nan)
        features.append(
            Features(
                s,
                0.5 * (left + right),
                left,
                right,
                nan,
                nan,
                np.full(n, 0.3),
                np.zeros(n, np.int8),
                np.full(n, side, np.int8),
            )
        )
    matches = verified(cameras, pad_candidates(features, n), sigma(), MatchConfig())
    assert MatchConfig().wire_radius_mm == 6.35
    assert matches.count == n
    np.testing.assert_array_equal(matches.scan, s)
    assert not np.any(matches.from_face)
    assert np.all(matches.cameras == 4)
    np.testing.assert_allclose(matches.radius_mm, radius, atol=0.05)
    distance = np.hypot(matches.x_mm - x_axis, matches.z_mm - z_axis)
    assert np.max(distance) < 0.2


def test_each_point_s_radius_is_measured_from_its_dark_silhouettes(rig_cameras) -> None:
    """By white daylight a new wire's dark silhouettes are its whole outline: their width
    across the rays is its diameter, which the point carries (its middle, the axis, is
    lowered by it to the wire's bottom), not the radius assumed (6.35 mm, 1.05 mm off the
    thinnest and widest wires). A messenger above has its own; a wire seen bright (its lit
    bottom, at night) or with a face located by it measures none."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(23)
    n = 40
    s = np.arange(n)
    x = np.stack([np.linspace(-200.0, 200.0, n), np.linspace(-100.0, 300.0, n)], axis=1)
    z = np.stack([np.full(n, 1600.0), np.full(n, 2700.0)], axis=1)
    radius = np.array([5.3, 7.0])  # an AC-80 contact wire, a messenger of 14 mm
    polarity = np.where(s < n // 2, -1, 1).astype(np.int8)  # dark, then lit (night)
    features = []
    for camera in cameras:
        u = camera.project(x, z)
        _, gx, gz = _Geometry.of(camera).project(x, z)
        half = radius * np.hypot(gx, gz)
        left = (u - half + rng.normal(0, NOISE_PX, u.shape)).ravel()
        right = (u + half + rng.normal(0, NOISE_PX, u.shape)).ravel()
        nan = np.full(2 * n, np.nan)
        features.append(
            Features(
                np.repeat(s, 2),
                0.5 * (left + right),
                left,
                right,
                nan,
                nan,
                np.full(2 * n, 0.3),
                np.repeat(polarity, 2),
            )
        )
    matches = verified(cameras, pad_candidates(features, n), sigma(), MatchConfig())
    assert matches.count == 2 * n
    wire = (matches.z_mm > 2000.0).astype(int)
    dark = matches.scan < n // 2
    np.testing.assert_allclose(matches.radius_mm[dark], radius[wire[dark]], atol=0.05)
    assert np.all(np.isnan(matches.radius_mm[~dark]))


def test_a_wire_whose_face_some_cameras_miss_is_matched_by_its_middles(rig_cameras) -> None:
    """A face about as narrow as the blur (a new wire's, 2 mm) is found by two cameras and
    missed by the other two: their centres are the face's (the wire's bottom) and the
    silhouettes' middles (its axis, a radius above), which no pair of cameras can match
    with the others'. Sought by the middles too, the point is found in every scan, located
    by the two faces at the wire's bottom."""
    _names, cameras = rig_cameras
    rng = np.random.default_rng(29)
    n = 50
    s = np.arange(n)
    radius = 6.45
    x = np.linspace(-250.0, 250.0, n)
    z_axis = np.linspace(1600.0, 2000.0, n)
    features = []
    for c, camera in enumerate(cameras):
        u = camera.project(x, z_axis) + rng.normal(0, NOISE_PX, n)
        _, gx, gz = _Geometry.of(camera).project(x, z_axis)
        half = radius * np.hypot(gx, gz)
        bottom = camera.project(x, z_axis - radius) + rng.normal(0, NOISE_PX, n)
        seen = c < 2
        face_left = np.where(seen, bottom - 1.0, np.nan)
        face_right = np.where(seen, bottom + 1.0, np.nan)
        centre = bottom if seen else u
        features.append(
            Features(
                s,
                centre,
                u - half,
                u + half,
                face_left,
                face_right,
                np.full(n, 0.4),
                -np.ones(n, np.int8),
            )
        )
    matches = verified(cameras, pad_candidates(features, n), sigma())
    np.testing.assert_array_equal(matches.scan, s)
    assert np.all(matches.from_face)
    # two cameras' faces alone locate it: their noise through a narrower baseline
    assert np.max(np.hypot(matches.x_mm - x, matches.z_mm - (z_axis - radius))) < 0.5
