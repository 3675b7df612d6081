"""Frames to scans (``catenary_camera.assembly``): placed by time and frame id, never shifted."""

from __future__ import annotations

import math

import numpy as np
import pytest

from catenary_camera.assembly import RESYNC_FRAMES, ScanAssembler

N = 8  # lines per frame
W = 6
RATE = 1000.0
T0 = 1_700_000_000.0


MARK = 1000  # a line holds its scan index + MARK (0: no line)


def frame(first_scan: int) -> np.ndarray:
    """A frame whose lines hold their scan index + MARK (``[N, W]`` uint16)."""
    index = np.arange(first_scan, first_scan + N) + MARK
    return np.repeat(index.astype(np.uint16)[:, None], W, axis=1)


def assembler(**kwargs: object) -> ScanAssembler:
    cameras = {"a": (W, np.dtype(np.uint16)), "b": (W, np.dtype(np.uint16))}
    return ScanAssembler(cameras, N, RATE, T0, **kwargs)  # type: ignore[arg-type]


def check_in_place(lines: np.ndarray, valid: np.ndarray, first: int = 0) -> None:
    index = np.arange(first, first + lines.shape[0]) + MARK
    assert (lines[valid] == index[valid, None]).all()
    assert (lines[~valid] == 0).all()


def test_consecutive_frames_of_two_cameras_make_scans_in_step() -> None:
    asm = assembler()
    for k in range(4):  # b started later: other frame ids, and 3 ms behind a's clock
        asm.add("a", 100 + k, T0 + k * N / RATE, frame(k * N))
        asm.add("b", 7 + k, T0 + (k * N + 0.3) / RATE, frame(k * N))
    assert asm.reached("a") == asm.reached("b") == 4 * N
    scans = asm.take(4 * N)
    for name in "ab":
        assert scans.valid[name].all()
        check_in_place(scans.lines[name], scans.valid[name])
    np.testing.assert_allclose(scans.time_s, np.arange(4 * N) / RATE)
    assert asm.counts("a").delivered == 4 * N and asm.counts("a").lost == 0


def test_a_lost_frame_leaves_exactly_its_lines_invalid() -> None:
    asm = assembler()
    for k in (0, 1, 3, 4):  # frame id 2 never came
        asm.add("a", 1 + k, T0 + k * N / RATE, frame(k * N))
    asm.add("a", 6, None, None)  # frame 5 came incomplete: no lines, no trusted stamp
    scans = asm.take(6 * N)
    expected = np.ones(6 * N, dtype=bool)
    expected[2 * N : 3 * N] = False
    expected[5 * N :] = False
    np.testing.assert_array_equal(scans.valid["a"], expected)
    check_in_place(scans.lines["a"], scans.valid["a"])
    assert asm.counts("a").incomplete_frames == 1 and asm.counts("a").missing_frames == 1
    assert asm.counts("b").lost == 6 * N  # b delivered nothing


def test_frame_ids_wrap_from_65535_to_1() -> None:
    asm = assembler()
    for k, fid in enumerate((65534, 65535, 1, 2)):
        asm.add("a", fid, T0 + k * N / RATE, frame(k * N))
    scans = asm.take(4 * N)
    assert scans.valid["a"].all()
    check_in_place(scans.lines["a"], scans.valid["a"])


def test_frames_whose_times_all_disagree_with_their_ids_are_placed_by_time() -> None:
    asm = assembler()
    asm.add("a", 1, T0, frame(0))
    # from id 2 on, every frame comes 2 frames later than its id says (a line clock far off)
    for k in range(1, RESYNC_FRAMES + 1):
        asm.add("a", 1 + k, T0 + (k + 2) * N / RATE, frame((k + 2) * N))
    assert asm.counts("a").resyncs == 1
    asm.add(
        "a", RESYNC_FRAMES + 2, T0 + (RESYNC_FRAMES + 3) * N / RATE, frame((RESYNC_FRAMES + 3) * N)
    )
    scans = asm.take(asm.reached("a"))
    # every frame where its time says, those before the resync too: nothing shifted
    check_in_place(scans.lines["a"], scans.valid["a"])
    expected = np.ones(scans.scans, dtype=bool)
    expected[N : 3 * N] = False  # the two periods the camera's ids do not count
    np.testing.assert_array_equal(scans.valid["a"], expected)


def test_a_second_skip_before_the_first_is_confirmed_is_placed_by_its_own_times() -> None:
    asm = assembler()
    # the camera skips a period after its 3rd frame and two more after its 10th, its ids
    # counting on (Aravis's fake camera): both within RESYNC_FRAMES frames, stamps exact
    for k in range(3 * RESYNC_FRAMES):
        scan = (k + (0 if k < 3 else 1 if k < 10 else 3)) * N
        asm.add("a", 1 + k, T0 + scan / RATE, frame(scan))
    scans = asm.take(asm.reached("a"))
    check_in_place(scans.lines["a"], scans.valid["a"])
    expected = np.ones((3 * RESYNC_FRAMES + 3) * N, dtype=bool)
    expected[3 * N : 4 * N] = expected[11 * N : 13 * N] = False
    np.testing.assert_array_equal(scans.valid["a"], expected)
    assert asm.counts("a").resyncs == 2


def test_frames_held_as_late_are_not_handed_out_before_they_are_placed() -> None:
    asm = assembler()
    for k in range(3):
        asm.add("a", 1 + k, T0 + k * N / RATE, frame(k * N))
    # from id 4 on each frame is stamped a period later than its id says (a skipped period,
    # or late stamps: only the frames after them can tell)
    for k in range(3, 10):
        asm.add("a", 1 + k, T0 + (k + 1) * N / RATE, frame(k * N))
    assert asm.reached("a") == 3 * N  # what follows waits for the resync or a frame on time
    check_in_place(asm.take(3 * N).lines["a"], np.ones(3 * N, dtype=bool))
    asm.add("a", 11, T0 + 10 * N / RATE, frame(10 * N))  # on time after all: late stamps
    assert asm.reached("a") == 11 * N and asm.counts("a").resyncs == 0
    rest = asm.take(11 * N)
    assert rest.valid["a"].all()
    check_in_place(rest.lines["a"], rest.valid["a"], first=3 * N)


def test_one_late_stamp_moves_nothing_but_an_early_one_does() -> None:
    asm = assembler()
    for k in range(4):  # frame 2 stamped 3 frames late
        asm.add("a", 1 + k, T0 + (k + (3 if k == 2 else 0)) * N / RATE, frame(k * N))
    scans = asm.take(4 * N)
    assert scans.valid["a"].all() and asm.counts("a").resyncs == 0
    check_in_place(scans.lines["a"], scans.valid["a"])
    asm.add("a", 5, T0 + 2 * N / RATE, frame(2 * N))  # stamped before its predecessor's lines
    assert asm.counts("a").resyncs == 1


def test_host_stamped_frames_arriving_late_stay_where_their_ids_put_them() -> None:
    asm = assembler()
    asm.add("a", 1, T0, frame(0), host_stamped=True)
    # a busy host: every later frame arrives two frames late, for twice RESYNC_FRAMES frames
    for k in range(1, 2 * RESYNC_FRAMES):
        asm.add("a", 1 + k, T0 + (k + 2) * N / RATE, frame(k * N), host_stamped=True)
    assert asm.reached("a") == 2 * RESYNC_FRAMES * N and asm.counts("a").resyncs == 0
    scans = asm.take(asm.reached("a"))
    assert scans.valid["a"].all()
    check_in_place(scans.lines["a"], scans.valid["a"])
    # one that arrives before its lines could have been taken: the first was placed late
    k = 2 * RESYNC_FRAMES
    asm.add("a", 1 + k, T0 + (k - 2) * N / RATE, frame((k - 2) * N), host_stamped=True)
    assert asm.counts("a").resyncs == 1


def test_lines_before_the_run_or_already_handed_out_are_dropped() -> None:
    asm = assembler()
    asm.add("a", 1, T0 - 3 / RATE, frame(-3))  # started 3 lines before scan 0
    first = asm.take(2)
    assert first.valid["a"].all() and (first.lines["a"][:, 0] == [MARK, MARK + 1]).all()
    asm.add("b", 1, T0, frame(0))  # b's lines 0-1 are late: scans 0-1 are gone
    rest = asm.take(N - 3)
    check_in_place(rest.lines["b"], rest.valid["b"], first=2)
    assert rest.valid["b"].all() and asm.counts("b").late_lines == 2


def test_repeated_frame_ids_add_nothing() -> None:
    asm = assembler()
    asm.add("a", 5, T0, frame(0))
    asm.add("a", 5, T0, frame(0) + 1)
    scans = asm.take(N)
    check_in_place(scans.lines["a"], scans.valid["a"])


def test_an_incomplete_frame_whose_id_goes_back_is_left_out() -> None:
    asm = assembler()
    for k in range(3):
        asm.add("a", 100 + k, T0 + k * N / RATE, frame(k * N))
    asm.add("a", 7, None, None)  # a lost leader: a stale id, no time to place it by
    asm.add("a", 103, T0 + 3 * N / RATE, frame(3 * N))
    scans = asm.take(4 * N)
    assert scans.valid["a"].all() and asm.counts("a").resyncs == 0
    check_in_place(scans.lines["a"], scans.valid["a"])


def test_a_reconnected_camera_is_placed_by_time_again() -> None:
    asm = assembler()
    asm.add("a", 40, T0, frame(0))
    asm.restart("a")
    asm.add("a", 40, T0 + 5 * N / RATE, frame(5 * N))  # the camera restarted its ids
    scans = asm.take(6 * N)
    assert scans.valid["a"][:N].all() and not scans.valid["a"][N : 5 * N].any()
    check_in_place(scans.lines["a"], scans.valid["a"])


def test_encoder_first_frames_are_placed_in_frames_of_the_speed_not_of_the_nominal_rate() -> None:
    """At a third of the nominal speed a frame takes 24 ms, not 8: a camera whose first
    frame is two frames before another's (the run's scan 0) starts two frames before it (the
    nominal rate put it six), and its next frames go on from there, not from scan 0."""
    asm = assembler(encoder=True)
    period = 3 * N / RATE
    asm.add("a", 1, T0 - 2 * period, frame(-2 * N), period_s=period)
    asm.add("b", 5, T0, frame(0), period_s=period)
    for k in range(1, 5):
        asm.add("a", 1 + k, T0 + (k - 2) * period, frame((k - 2) * N))
        asm.add("b", 5 + k, T0 + k * period, frame(k * N))
    scans = asm.take(3 * N)
    for name in "ab":
        assert scans.valid[name].all(), name
        check_in_place(scans.lines[name], scans.valid[name])


def test_encoder_a_camera_back_is_placed_by_the_other_cameras_frames() -> None:
    """At a quarter of the nominal speed a camera that dropped off comes back (new frame
    ids) 3 ms after the other camera's frame of the same lines: it goes where that frame
    went, not where the time since the start would put it at the nominal rate (40 frames
    on, not 10)."""
    asm = assembler(encoder=True)
    period = 4 * N / RATE
    for k in range(4):
        asm.add("a", 100 + k, T0 + k * period, frame(k * N), period_s=period)
        asm.add("b", 7 + k, T0 + k * period, frame(k * N), period_s=period)
    asm.restart("a")
    for k in range(4, 12):
        asm.add("b", 7 + k, T0 + k * period, frame(k * N))
        if k >= 10:
            asm.add("a", k - 9, T0 + k * period + 0.003, frame(k * N), period_s=period)
    scans = asm.take(12 * N)
    check_in_place(scans.lines["a"], scans.valid["a"])
    assert scans.valid["a"][: 4 * N].all() and scans.valid["a"][10 * N :].all()
    assert not scans.valid["a"][4 * N : 10 * N].any()


@pytest.mark.parametrize("period_s", [math.nan, 1e-5, None])
def test_encoder_an_implausible_period_gives_way_to_the_nominal_rate(
    period_s: float | None,
) -> None:
    """A period that is no number, or one of a train at over four times its nominal speed
    (a host's bunched stamps), places a camera back by the nominal rate, as with none."""
    asm = assembler(encoder=True)
    period = N / RATE
    for k in range(4):
        asm.add("a", 100 + k, T0 + k * period, frame(k * N))
        asm.add("b", 7 + k, T0 + k * period, frame(k * N))
    asm.restart("a")
    asm.add("b", 11, T0 + 4 * period, frame(4 * N))
    asm.add("a", 1, T0 + 4 * period + 0.001, frame(4 * N), period_s=period_s)
    scans = asm.take(5 * N)
    assert scans.valid["a"].all()
    check_in_place(scans.lines["a"], scans.valid["a"])


def test_a_first_frame_before_scan_0_carries_the_next_on_from_where_it_ends() -> None:
    """Free-running: a camera whose first frame ends a line before the run's scan 0 (the
    other camera's first) goes on from there, not from scan 0 (a line off for the whole run:
    within ``resync_lines``, never moved back)."""
    asm = assembler()
    asm.add("b", 7, T0, frame(0))
    asm.add("a", 100, T0 - (N + 1) / RATE, frame(-N - 1))
    for k in range(1, 5):
        asm.add("b", 7 + k, T0 + k * N / RATE, frame(k * N))
        asm.add("a", 100 + k, T0 + ((k - 1) * N - 1) / RATE, frame((k - 1) * N - 1))
    scans = asm.take(3 * N)
    for name in "ab":
        assert scans.valid[name].all(), name
        check_in_place(scans.lines[name], scans.valid[name])


def test_encoder_lines_align_first_frames_to_whole_frames_and_interpolate_times() -> None:
    asm = assembler(encoder=True)
    # the train slows down: frames of N lines take 8, then 16 ms; b's first frame is 2 ms late
    asm.add("a", 1, T0, frame(0))
    asm.add("b", 9, T0 + 0.002, frame(0))
    asm.add("a", 2, T0 + 0.008, frame(N))
    asm.add("b", 10, T0 + 0.010, frame(N))
    asm.add("a", 3, T0 + 0.024, frame(2 * N))
    asm.add("b", 11, T0 + 0.024, frame(2 * N))
    scans = asm.take(2 * N + 1)
    for name in "ab":
        assert scans.valid[name].all()
        check_in_place(scans.lines[name], scans.valid[name])
    assert np.all(np.diff(scans.time_s) >= 0)
    assert scans.time_s[2 * N] == pytest.approx(0.024, abs=1e-6)  # UNIX float64: 0.2 µs
    assert scans.time_s[N + N // 2] == pytest.approx(0.0165, abs=1.5e-3)  # half-way, 2nd frame
