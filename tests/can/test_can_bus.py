"""A live bus: python-can's virtual bus (each test its own channel) carrying sensor frames."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from typing import Any

import can
import numpy as np
import pytest
from can.interfaces.virtual import VirtualBus

from catenary.errors import UserError
from catenary_can.decode import DEFAULT_METRES_PER_PULSE, DROPPED, OUT_OF_RANGE, STATUS, STUCK
from catenary_can.reader import CanSensorStream, load_database, open_can

DB = load_database()
DISP = DB.get_message_by_name("DisplacementSensors")
ENC = DB.get_message_by_name("WheelEncoder")
PERIOD_S = 0.005
T0 = 1_700_000_000.0


def sensor_frames(
    n: int,
    *,
    seed: int = 0,
    right: dict[int, float] | None = None,
    lateral: dict[int, float] | None = None,
    left: dict[int, float] | None = None,
    status: dict[int, int] | None = None,
    skip: set[int] | frozenset[int] = frozenset(),
    speed_mps: float = 10.0,
) -> list[can.Message]:
    """Encoder and displacement frames every 5 ms from T0, noisy sensors, overrides by index."""
    rng = np.random.default_rng(seed)
    values = {
        "left_mm": np.round(5.0 + rng.normal(0.0, 0.3, n), 2),
        "right_mm": np.round(-4.0 + rng.normal(0.0, 0.3, n), 2),
        "lateral_mm": np.round(rng.normal(0.0, 2.0, n), 2),
    }
    for name, override in (("left_mm", left), ("right_mm", right), ("lateral_mm", lateral)):
        for i, value in (override or {}).items():
            values[name][i] = value
    messages = []
    for i in range(n):
        t = T0 + i * PERIOD_S
        pulses = round(speed_mps * i * PERIOD_S / DEFAULT_METRES_PER_PULSE)
        enc = ENC.encode({"pulse_count": pulses, "status": 0, "counter": i % 16})
        messages.append(
            can.Message(timestamp=t, arbitration_id=0x100, is_extended_id=False, data=enc)
        )
        if i in skip:
            continue
        signals = {name: float(v[i]) for name, v in values.items()}
        signals |= {"status": (status or {}).get(i, 0), "counter": i % 16}
        data = DISP.encode(signals, strict=False)
        messages.append(
            can.Message(timestamp=t + 0.0005, arbitration_id=0x110, is_extended_id=False, data=data)
        )
    return messages


@pytest.fixture
def channel() -> str:
    return f"catenary-test-{uuid.uuid4().hex}"


@pytest.fixture
def sender(channel: str) -> Iterator[can.BusABC]:
    bus = can.Bus(
        interface="virtual", channel=channel, preserve_timestamps=True, ignore_config=True
    )
    yield bus
    bus.shutdown()


def read_all(stream: CanSensorStream, frames: int, timeout_s: float = 10.0) -> list[Any]:
    """Read until ``frames`` frames arrived, then the rest with ``final``."""
    blocks: list[Any] = []
    deadline = time.monotonic() + timeout_s
    while stream.statistics.frames < frames:
        assert time.monotonic() < deadline, f"only {stream.statistics.frames} of {frames} frames"
        blocks += stream.read()
        time.sleep(0.01)
    blocks += stream.read(final=True)
    return blocks


def test_dropped_stuck_out_of_range_and_status_faults_are_flagged(
    channel: str, sender: can.BusABC
) -> None:
    messages = sensor_frames(
        300,
        skip={40},
        right={i: -3.21 for i in range(100, 220)},  # stuck 0.595 s
        lateral={270: 230.0},
        left={280: 355.35},  # raw 0xFFFF, no measurement
        status={290: 0b0100},
    )
    with open_can({"interface": "virtual", "channel": channel, "chunk_frames": 50}) as stream:
        for msg in messages:
            sender.send(msg)
        blocks = read_all(stream, len(messages))
    time_s = np.concatenate([b.vehicle.time_s for b in blocks])
    fault = np.concatenate([b.vehicle.fault for b in blocks])
    reasons = np.concatenate([b.vehicle_reasons for b in blocks])
    index = np.rint((time_s - 0.0005) / PERIOD_S).astype(int)  # the frame index of each sample
    assert index.tolist() == list(range(300))  # frame 40 is a placeholder at its place
    assert set(index[fault]) == {40, *range(100, 220), 270, 280, 290}
    assert reasons[40] == DROPPED
    assert (reasons[100:220] == STUCK).all()
    assert reasons[270] == OUT_OF_RANGE and reasons[280] == OUT_OF_RANGE
    assert reasons[290] == STATUS
    assert stream.counts.dropped_displacement_frames == 1
    position = np.concatenate([b.encoder.position_m for b in blocks])
    assert position[-1] == pytest.approx(10.0 * 299 * PERIOD_S, abs=DEFAULT_METRES_PER_PULSE)
    assert "1 dropped" in stream.summary() and "stuck 120" in stream.summary()


def test_unknown_ids_and_error_frames_on_the_bus_are_counted(
    channel: str, sender: can.BusABC
) -> None:
    messages = sensor_frames(20)
    extras = [
        can.Message(timestamp=T0 + 0.001, arbitration_id=0x7FF, is_extended_id=False, data=b"x"),
        can.Message(timestamp=T0 + 0.002, arbitration_id=0x110, is_extended_id=True, data=b"y"),
        can.Message(timestamp=T0 + 0.003, is_error_frame=True),
    ]
    with open_can({"interface": "virtual", "channel": channel}) as stream:
        for msg in [*messages[:5], *extras, *messages[5:]]:
            sender.send(msg)
        blocks = read_all(stream, len(messages) + 3)
    stats = stream.statistics
    assert stats.unknown_ids == {"0x7FF": 1, "0x00000110x": 1}
    assert stats.error_frames == 1
    assert sum(b.vehicle.time_s.shape[0] for b in blocks) == 20
    assert not any(b.vehicle.fault.any() for b in blocks)


def test_a_full_queue_loses_frames_that_show_as_dropped(channel: str, sender: can.BusABC) -> None:
    messages = sensor_frames(40)
    with open_can({"interface": "virtual", "channel": channel, "queue_frames": 30}) as stream:
        for msg in messages:
            sender.send(msg)
        deadline = time.monotonic() + 5.0
        while stream._feed._listener.overflow < 50 and time.monotonic() < deadline:  # type: ignore[attr-defined]
            time.sleep(0.01)
        blocks = list(stream.read(final=True))
    assert stream.statistics.overflow_frames == 50
    assert stream.statistics.frames == 30
    time_s = np.concatenate([b.vehicle.time_s for b in blocks])
    assert time_s.shape[0] == 15  # frames 0..14 arrived: nothing to flag yet
    # the next frames that arrive continue the counters: the gap is flagged
    with open_can({"interface": "virtual", "channel": channel}) as stream:
        for msg in messages[:10] + messages[30:]:
            sender.send(msg)
        blocks = read_all(stream, 30)
    fault = np.concatenate([b.vehicle.fault for b in blocks])
    assert np.count_nonzero(fault) == 10 and stream.counts.dropped_displacement_frames == 10


def _notifier_threads(channel: str) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if channel in t.name]


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_watchdog_restarts_a_dead_notifier_and_bus_errors_do_not_stop_it(
    channel: str, sender: can.BusABC, monkeypatch: pytest.MonkeyPatch
) -> None:
    original = VirtualBus._recv_internal
    plan = {"errors": 3, "die": 1}

    def flaky(self: VirtualBus, timeout: float | None) -> Any:
        if self.channel_id == channel:
            if plan["errors"]:
                plan["errors"] -= 1
                raise can.CanOperationError("bus off")
            if plan["die"]:
                plan["die"] -= 1
                raise SystemExit  # not an Exception: the notifier thread dies
        return original(self, timeout)

    with open_can({"interface": "virtual", "channel": channel}) as stream:
        monkeypatch.setattr(VirtualBus, "_recv_internal", flaky)
        deadline = time.monotonic() + 5.0
        while any(t.is_alive() for t in _notifier_threads(channel)):
            assert time.monotonic() < deadline, "the notifier thread did not die"
            time.sleep(0.01)
        messages = sensor_frames(10)
        for msg in messages:
            sender.send(msg)
        blocks = read_all(stream, len(messages))  # the first read restarts the notifier
        assert sum(b.vehicle.time_s.shape[0] for b in blocks) == 10
    stats = stream.statistics
    assert stats.bus_errors == 3
    assert stats.notifier_restarts == 1
    assert "restarted" in (stats.last_error or "")


def test_bus_settings_are_checked_in_one_line() -> None:
    with pytest.raises(UserError, match=r"CAN interface='no-such-interface'.*cannot open"):
        open_can({"interface": "no-such-interface", "channel": "x"})
    with pytest.raises(UserError, match="either 'log'"):
        open_can({"interface": "virtual", "log": "x.blf"})
    with pytest.raises(UserError, match="either 'log'"):
        open_can({})
    with pytest.raises(UserError, match="unknown setting 'bitrat'"):
        open_can({"interface": "virtual", "bitrat": 500000})
    with pytest.raises(UserError, match=r"stuck_time_s = -1: expected a number > 0"):
        open_can({"interface": "virtual", "stuck_time_s": -1})
    with pytest.raises(UserError, match="'channel' is for a live bus"):
        open_can({"log": "x.blf", "channel": "can0"})
