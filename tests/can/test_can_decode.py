"""Fault detection over decoded sensor samples (catenary_can.decode): pure, block by block."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from catenary_can.decode import (
    DROPPED,
    JUMP,
    OUT_OF_RANGE,
    REPEATED,
    STATUS,
    STUCK,
    DisplacementFrames,
    EncoderFrames,
    RunState,
    SensorTracker,
    TrackedBlock,
    TrackerConfig,
    expand_missing,
    missing_frames,
    out_of_range,
    speed_at,
    stuck_verdicts,
    unwrap_counts,
)

PERIOD_S = 0.005
LIMITS = {"left_mm": (-250.0, 250.0), "right_mm": (-250.0, 250.0), "lateral_mm": (-200.0, 200.0)}
MPP = 0.001  # metres per pulse in these tests


def config(**overrides: float) -> TrackerConfig:
    return TrackerConfig(limits_mm=LIMITS, metres_per_pulse=MPP, **overrides)  # type: ignore[arg-type]


# -- pure helpers ---------------------------------------------------------------------------


def test_missing_frames_by_counter_and_by_time() -> None:
    counter = np.array([0, 1, 3, 4, 4, 5, 6], dtype=np.int64)
    time_s = np.array([0, 1, 3, 4, 5, 6, 7], dtype=float) * PERIOD_S
    missing, repeated = missing_frames(counter, time_s, period_s=PERIOD_S)
    assert missing.tolist() == [0, 0, 1, 0, 0, 0, 0]
    assert repeated.tolist() == [False, False, False, False, True, False, False]

    # 16 frames lost wrap the counter back to the expected value: only time shows them
    counter = np.array([5, 6, 7], dtype=np.int64)
    time_s = np.array([0.0, PERIOD_S, 18 * PERIOD_S])
    missing, _ = missing_frames(counter, time_s, period_s=PERIOD_S)
    assert missing.tolist() == [0, 0, 16]


def test_missing_frames_continue_from_the_previous_block() -> None:
    counter = np.array([15, 0, 1], dtype=np.int64)  # the counter wraps 15 -> 0
    time_s = np.array([3, 4, 5], dtype=float) * PERIOD_S
    missing, _ = missing_frames(counter, time_s, period_s=PERIOD_S, previous=(13, 2 * PERIOD_S))
    assert missing.tolist() == [1, 0, 0]  # counter 14 lost between the blocks
    missing, _ = missing_frames(counter, time_s, period_s=PERIOD_S)
    assert missing.tolist() == [0, 0, 0]  # nothing known before the first frame


def test_expand_missing_places_placeholders_evenly() -> None:
    time_s = np.array([0.0, 0.03])
    times, received, owner = expand_missing(time_s, np.array([0, 2]), None)
    assert times == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert received.tolist() == [True, False, False, True]
    assert owner.tolist() == [0, 1, 1, 1]
    times, received, _ = expand_missing(np.array([0.02]), np.array([1]), 0.0)
    assert times == pytest.approx([0.01, 0.02])
    assert received.tolist() == [False, True]


def test_out_of_range_includes_limits_and_rejects_nan() -> None:
    values = np.array([-250.0, 250.0, 250.01, -300.0, np.nan])
    assert out_of_range(values, -250.0, 250.0).tolist() == [False, False, True, True, True]


def test_stuck_verdicts_need_the_duration_and_motion() -> None:
    t = np.arange(10) * 0.1
    values = np.array([1.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 3.0, 4.0, 5.0])
    moving = np.ones(10, dtype=bool)
    stuck, decided, carried, _ = stuck_verdicts(t, values, moving, 0.5)
    assert stuck.tolist() == [False] + [True] * 6 + [False] * 3
    assert decided[:-1].all() and not decided[-1]  # the last value could still go on
    assert carried == RunState(5.0, 0.9, False)
    # the same at standstill is no fault
    stuck, decided, carried, _ = stuck_verdicts(t, values, np.zeros(10, dtype=bool), 0.5)
    assert not stuck.any() and decided.all() and carried is None
    # 0.4 s unchanged is not enough
    stuck, *_ = stuck_verdicts(t, values, moving, 0.6)
    assert not stuck.any()


def test_stuck_verdicts_continue_a_carried_run() -> None:
    t = np.array([1.0, 1.1, 1.2])
    values = np.array([7.0, 7.0, 8.0])
    moving = np.ones(3, dtype=bool)
    stuck, decided, _, verdict = stuck_verdicts(t, values, moving, 0.5, RunState(7.0, 0.6, False))
    assert stuck.tolist() == [True, True, False]  # 0.6 .. 1.1: 0.5 s
    assert verdict is True and decided[:2].all()
    _, _, _, verdict = stuck_verdicts(t, values, moving, 0.5, RunState(6.0, 0.6, False))
    assert verdict is False  # the carried run ended before this block


def test_unwrap_counts_across_the_wrap_and_in_reverse() -> None:
    counts = np.array([2**32 - 2, 1, 3, 0], dtype=np.int64)
    assert unwrap_counts(counts, 2**32 - 5).tolist() == [3, 3, 2, -3]
    assert unwrap_counts(counts, None).tolist() == [0, 3, 2, -3]


def test_speed_at_holds_the_interval_and_goes_stale() -> None:
    enc_t = np.array([0.0, 0.01, 0.02])
    enc_v = np.array([np.nan, 5.0, 7.0])
    speed = speed_at(np.array([0.005, 0.015, 0.025, 1.0]), enc_t, enc_v, stale_s=0.1)
    assert speed[:3] == pytest.approx([5.0, 7.0, 7.0])
    assert np.isnan(speed[3])
    assert np.isnan(speed_at(np.array([0.0]), np.zeros(0), np.zeros(0), stale_s=1.0)).all()


# -- the tracker ----------------------------------------------------------------------------


def synthetic(n: int = 400, seed: int = 0) -> tuple[DisplacementFrames, EncoderFrames, set[int]]:
    """Frames at 200 Hz, 10 m/s, with faults; the indices of the frames that must be flagged."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * PERIOD_S
    left = np.round(5.0 + rng.normal(0.0, 0.3, n), 2)
    right = np.round(-4.0 + rng.normal(0.0, 0.3, n), 2)
    lateral = np.round(rng.normal(0.0, 2.0, n), 2)
    status = np.zeros(n, dtype=np.int64)
    counter = np.arange(n, dtype=np.int64) % 16
    right[100:220] = -3.21  # stuck 0.595 s
    right[250:260] = 1.11  # 45 ms unchanged: no fault
    lateral[270] = 230.0  # out of range
    left[280] = 355.35  # raw 0xFFFF: no measurement
    status[290] = 0b0001  # left sensor invalid
    status[300] = 0b1000  # module fault
    flagged = {*range(100, 220), 270, 280, 290, 300}
    keep = np.ones(n, dtype=bool)
    keep[40] = False  # dropped
    displacement = DisplacementFrames(
        t[keep], left[keep], right[keep], lateral[keep], status[keep], counter[keep]
    )
    pulses = np.round(10.0 * t / MPP).astype(np.int64)  # 10 m/s
    encoder = EncoderFrames(
        t - 0.001, pulses, np.zeros(n, dtype=np.int64), np.arange(n, dtype=np.int64) % 16
    )
    return displacement, encoder, flagged


def cut(frames: DisplacementFrames, start: int, stop: int) -> DisplacementFrames:
    return DisplacementFrames(
        frames.time_s[start:stop],
        frames.left_mm[start:stop],
        frames.right_mm[start:stop],
        frames.lateral_mm[start:stop],
        frames.status[start:stop],
        frames.counter[start:stop],
    )


def cut_encoder(frames: EncoderFrames, start: int, stop: int) -> EncoderFrames:
    return EncoderFrames(
        frames.time_s[start:stop],
        frames.pulse_count[start:stop],
        frames.status[start:stop],
        frames.counter[start:stop],
    )


def run_blocks(
    displacement: DisplacementFrames, encoder: EncoderFrames, edges: list[float]
) -> list[TrackedBlock]:
    """Push the frames cut at the given times, as a reader would (both kinds up to a time)."""
    tracker = SensorTracker(config())
    blocks = []
    bounds = [-np.inf, *edges, np.inf]
    for low, high in itertools.pairwise(bounds):
        d = np.flatnonzero((displacement.time_s > low) & (displacement.time_s <= high))
        e = np.flatnonzero((encoder.time_s > low) & (encoder.time_s <= high))
        d_part = cut(displacement, d[0], d[-1] + 1) if d.size else DisplacementFrames()
        e_part = cut_encoder(encoder, e[0], e[-1] + 1) if e.size else EncoderFrames()
        blocks.append(tracker.push(d_part, e_part, final=high == np.inf))
    return blocks


def joined(blocks: list[TrackedBlock]) -> dict[str, np.ndarray]:
    return {
        "time_s": np.concatenate([b.vehicle.time_s for b in blocks]),
        "left_mm": np.concatenate([b.vehicle.left_mm for b in blocks]),
        "fault": np.concatenate([b.vehicle.fault for b in blocks]),
        "reasons": np.concatenate([b.vehicle_reasons for b in blocks]),
        "position_m": np.concatenate([b.encoder.position_m for b in blocks]),
        "encoder_fault": np.concatenate([b.encoder.fault for b in blocks]),
    }


def test_tracker_flags_exactly_the_faulty_samples() -> None:
    displacement, encoder, flagged = synthetic()
    out = joined(run_blocks(displacement, encoder, []))
    t = out["time_s"]
    assert t.shape == (400,)  # 399 received + 1 placeholder
    assert t == pytest.approx(np.arange(400) * PERIOD_S, abs=1e-12)
    assert set(np.flatnonzero(out["fault"])) == flagged | {40}
    reasons = out["reasons"]
    assert reasons[40] == DROPPED and np.isnan(out["left_mm"][40])
    assert (reasons[100:220] == STUCK).all()
    assert reasons[270] == OUT_OF_RANGE and reasons[280] == OUT_OF_RANGE
    assert reasons[290] == STATUS and reasons[300] == STATUS
    assert out["position_m"][-1] == pytest.approx(10.0 * 399 * PERIOD_S, abs=MPP)
    assert not out["encoder_fault"].any()


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(min_value=0.0, max_value=2.0), max_size=12))
def test_tracker_output_does_not_depend_on_the_blocks(edges: list[float]) -> None:
    displacement, encoder, _ = synthetic()
    whole = joined(run_blocks(displacement, encoder, []))
    parts = joined(run_blocks(displacement, encoder, sorted(edges)))
    for key, value in whole.items():
        np.testing.assert_array_equal(parts[key], value, err_msg=key)


def test_tracker_holds_back_an_open_run_until_it_ends() -> None:
    displacement, encoder, _ = synthetic()
    tracker = SensorTracker(config())
    first = tracker.push(cut(displacement, 0, 150), cut_encoder(encoder, 0, 150))
    # samples 100.. (right sensor unchanged since) are held: they may turn out stuck
    assert first.vehicle.time_s.shape[0] == 100  # 0..99, the placeholder for 40 among them
    assert not first.vehicle.fault[:40].any()
    rest = tracker.push(cut(displacement, 150, 399), cut_encoder(encoder, 150, 400), final=True)
    assert rest.vehicle.fault[:120].all()  # samples 100..219, now known to be stuck


def test_a_repeated_counter_is_flagged_and_stands_for_a_lost_frame() -> None:
    n = 20
    t = np.arange(n) * PERIOD_S
    counter = np.arange(n, dtype=np.int64) % 16
    counter[10] = counter[9]  # the module sent its previous frame again instead of frame 10
    values = np.round(np.random.default_rng(1).normal(0.0, 1.0, n), 2)
    displacement = DisplacementFrames(t, values, values, values, np.zeros(n, np.int64), counter)
    block = SensorTracker(config()).push(displacement, None, final=True)
    reasons = block.vehicle_reasons
    assert reasons.shape == (21,)
    assert reasons[10] == REPEATED
    assert reasons[11] == DROPPED  # frame 10 never came: a placeholder before frame 11
    assert block.vehicle.time_s[11] == pytest.approx(10.5 * PERIOD_S)
    assert np.count_nonzero(reasons) == 2


def test_standstill_is_not_a_stuck_sensor() -> None:
    n = 300
    t = np.arange(n) * PERIOD_S
    still = np.full(n, 2.5)
    displacement = DisplacementFrames(
        t, still, still, still, np.zeros(n, np.int64), np.arange(n, dtype=np.int64) % 16
    )
    encoder = EncoderFrames(
        t, np.full(n, 1234, np.int64), np.zeros(n, np.int64), np.arange(n, dtype=np.int64) % 16
    )
    block = SensorTracker(config()).push(displacement, encoder, final=True)
    assert not block.vehicle.fault.any()
    # without the encoder the vehicle counts as moving: the same values are a stuck sensor
    block = SensorTracker(config()).push(displacement, None, final=True)
    assert block.vehicle.fault.all()


def test_encoder_faults_and_positions_across_dropped_frames() -> None:
    n = 50
    t = np.arange(n) * PERIOD_S
    pulses = (np.arange(n, dtype=np.int64) * 20 + 2**32 - 300) % 2**32  # wraps, 4 m/s
    counter = np.arange(n, dtype=np.int64) % 16
    status = np.zeros(n, dtype=np.int64)
    status[30] = 1
    pulses[40:] += 10_000  # a jump: 10 m in 5 ms
    keep = np.ones(n, dtype=bool)
    keep[10:13] = False
    frames = EncoderFrames(t[keep], pulses[keep] % 2**32, status[keep], counter[keep])
    block = SensorTracker(config()).push(None, frames, final=True)
    reasons = dict(
        zip(
            np.round(block.encoder.time_s / PERIOD_S).astype(int),
            block.encoder_reasons,
            strict=True,
        )
    )
    assert reasons[13] == DROPPED and reasons[30] == STATUS and reasons[40] == JUMP
    assert sum(1 for r in reasons.values() if r) == 3
    # the count is cumulative: no distance lost over the dropped frames
    position = dict(
        zip(
            np.round(block.encoder.time_s / PERIOD_S).astype(int),
            block.encoder.position_m,
            strict=True,
        )
    )
    assert position[13] == pytest.approx(13 * 20 * MPP)
