"""Log files written by python-can itself (``can.Logger``) read back through the ``can`` source."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from catenary.errors import UserError
from catenary.plugins import PluginRegistry
from catenary_can.decode import DEFAULT_METRES_PER_PULSE
from catenary_can.reader import CanSensorStream, load_database, open_can, open_log

DB = load_database()
DISP = DB.get_message_by_name("DisplacementSensors")
ENC = DB.get_message_by_name("WheelEncoder")
PERIOD_S = 0.005
T0 = 1_700_000_000.0


def sensor_frames(
    n: int, *, skip: frozenset[int] = frozenset(), stuck: range = range(0)
) -> list[can.Message]:
    """Encoder and displacement frames every 5 ms from T0 at 10 m/s, noisy sensors."""
    rng = np.random.default_rng(7)
    messages = []
    for i in range(n):
        t = T0 + i * PERIOD_S
        pulses = round(10.0 * i * PERIOD_S / DEFAULT_METRES_PER_PULSE)
        enc = ENC.encode({"pulse_count": pulses, "status": 0, "counter": i % 16})
        messages.append(
            can.Message(timestamp=t, arbitration_id=0x100, is_extended_id=False, data=enc)
        )
        if i in skip:
            continue
        signals = {
            "left_mm": round(5.0 + rng.normal(0.0, 0.3), 2),
            "right_mm": -3.21 if i in stuck else round(-4.0 + rng.normal(0.0, 0.3), 2),
            "lateral_mm": round(rng.normal(0.0, 2.0), 2),
            "status": 0,
            "counter": i % 16,
        }
        messages.append(
            can.Message(
                timestamp=t + 0.0005,
                arbitration_id=0x110,
                is_extended_id=False,
                data=DISP.encode(signals),
            )
        )
    return messages


def write_log(path: Path, messages: list[can.Message]) -> Path:
    with can.Logger(path) as logger:
        for msg in messages:
            logger.on_message_received(msg)
    return path


def read(stream: CanSensorStream) -> dict[str, np.ndarray]:
    with stream:
        blocks = list(stream.read())
    empty = np.zeros(0)
    return {
        "time_s": np.concatenate([empty, *(b.vehicle.time_s for b in blocks)]),
        "left_mm": np.concatenate([empty, *(b.vehicle.left_mm for b in blocks)]),
        "fault": np.concatenate([empty.astype(bool), *(b.vehicle.fault for b in blocks)]),
        "position_m": np.concatenate([empty, *(b.encoder.position_m for b in blocks)]),
    }


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".csv", ".log", ".trc", ".asc.gz"])
def test_logs_written_by_python_can_read_back(tmp_path: Path, suffix: str) -> None:
    messages = sensor_frames(240, skip=frozenset({30}), stuck=range(100, 210))
    path = write_log(tmp_path / f"run{suffix}", messages)
    out = read(open_can({"log": str(path), "chunk_frames": 64}))
    # time zero is the first frame (an encoder frame at T0), whatever the format's clock
    expected_t = np.arange(240) * PERIOD_S + 0.0005
    np.testing.assert_allclose(out["time_s"], expected_t, atol=2e-6)
    assert set(np.flatnonzero(out["fault"])) == {30, *range(100, 210)}
    decoded = [DISP.decode(m.data)["left_mm"] for m in messages if m.arbitration_id == 0x110]
    received = np.delete(out["left_mm"], 30)
    np.testing.assert_allclose(received, decoded, atol=1e-9)
    assert out["position_m"][-1] == pytest.approx(
        10.0 * 239 * PERIOD_S, abs=DEFAULT_METRES_PER_PULSE
    )


def test_unknown_frames_in_a_log_are_counted(tmp_path: Path) -> None:
    messages = sensor_frames(20)
    messages.insert(
        3,
        can.Message(
            timestamp=T0 + 0.011, arbitration_id=0x18FF0010, is_extended_id=True, data=b"\x01\x02"
        ),
    )
    messages.insert(7, can.Message(timestamp=T0 + 0.021, is_error_frame=True))
    path = write_log(tmp_path / "mixed.blf", messages)
    stream = open_log(path)
    out = read(stream)
    assert out["time_s"].shape == (20,) and not out["fault"].any()
    assert stream.statistics.unknown_ids == {"0x18FF0010x": 1}
    assert stream.statistics.error_frames == 1
    assert "1 unknown" in stream.summary() and "1 error frames" in stream.summary()


def test_time_zero_and_reading_up_to_a_time(tmp_path: Path) -> None:
    path = write_log(tmp_path / "run.blf", sensor_frames(100))
    with open_can({"log": str(path), "time_zero_s": T0 + 0.1}) as stream:
        first = list(stream.vehicle_samples(0.0))
        rest = list(stream.vehicle_samples(1.0, final=True))
        assert stream.exhausted
    t_first = np.concatenate([s.time_s for s in first])
    t_rest = np.concatenate([s.time_s for s in rest])
    assert t_first[0] == pytest.approx(-0.0995) and t_first[-1] <= 0.0
    assert t_rest[-1] == pytest.approx(0.3955)
    both = np.concatenate((t_first, t_rest))  # the last sample of the first read may be held
    assert both.shape == (100,) and (np.diff(both) > 0).all()


def test_a_damaged_log_ends_the_samples_and_says_so(tmp_path: Path) -> None:
    path = write_log(tmp_path / "run.blf", sensor_frames(400))
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = b"\xff" * 64
    damaged = tmp_path / "damaged.blf"
    damaged.write_bytes(bytes(data))
    stream = open_log(damaged)
    out = read(stream)  # no exception: the samples end where the file became unreadable
    assert out["time_s"].shape[0] < 400
    assert stream.exhausted
    assert "damaged.blf: unreadable after frame" in stream.summary()


def test_log_errors_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"nope\.blf: no such CAN log file"):
        open_can({"log": str(tmp_path / "nope.blf")})
    odd = tmp_path / "run.xyz"
    odd.write_text("hello")
    with pytest.raises(UserError, match=r"run\.xyz: not a CAN log python-can reads"):
        open_can({"log": str(odd)})


def test_the_can_source_is_registered() -> None:
    registry = PluginRegistry()
    source = registry.vehicle_sources()["can"]
    assert registry.owner("vehicle source", "can") == "can"
    assert not registry.errors
    with pytest.raises(UserError, match="either 'log'"):
        source.open({})
