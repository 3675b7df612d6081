"""The shipped DBC and frame decoding with cantools: layout, round trip, what is counted."""

from __future__ import annotations

from pathlib import Path

import can
import cantools
import pytest

from catenary.errors import UserError
from catenary_can.reader import (
    DBC_PATH,
    CanStatistics,
    FrameDecoder,
    load_database,
    tracker_config,
)

DB = load_database()
DISP = DB.get_message_by_name("DisplacementSensors")
ENC = DB.get_message_by_name("WheelEncoder")


def test_dbc_layout_is_the_documented_one() -> None:
    assert (DISP.frame_id, DISP.is_extended_frame, DISP.length) == (0x110, False, 8)
    assert (ENC.frame_id, ENC.is_extended_frame, ENC.length) == (0x100, False, 8)
    assert DISP.cycle_time == 5 and ENC.cycle_time == 5
    for name, limit in (("left_mm", 250), ("right_mm", 250), ("lateral_mm", 200)):
        signal = DISP.get_signal_by_name(name)
        assert (signal.start, signal.length, signal.byte_order) == (
            {"left_mm": 0, "right_mm": 16, "lateral_mm": 32}[name],
            16,
            "little_endian",
        )
        assert (signal.scale, signal.offset, signal.unit) == (0.01, -300, "mm")
        assert (signal.minimum, signal.maximum) == (-limit, limit)
    for message in (DISP, ENC):
        counter = message.get_signal_by_name("counter")
        assert (counter.start, counter.length) == (56, 4)
        assert message.get_signal_by_name("status").start == 48
    pulses = ENC.get_signal_by_name("pulse_count")
    assert (pulses.start, pulses.length, pulses.is_signed) == (0, 32, False)
    config = tracker_config(DB)
    assert config.displacement_period_s == pytest.approx(0.005)
    assert config.limits_mm["lateral_mm"] == (-200.0, 200.0)


def decode(*messages: can.Message) -> tuple[FrameDecoder, CanStatistics]:
    stats = CanStatistics()
    decoder = FrameDecoder(DB, stats)
    for i, msg in enumerate(messages):
        decoder.add(msg, 0.005 * i)
    return decoder, stats


def frame(message: cantools.database.can.Message, **signals: float) -> can.Message:
    data = message.encode(signals, strict=False)
    return can.Message(arbitration_id=message.frame_id, is_extended_id=False, data=data)


def test_round_trip_of_frames_built_with_cantools() -> None:
    decoder, stats = decode(
        frame(DISP, left_mm=12.34, right_mm=-56.78, lateral_mm=199.99, status=5, counter=7),
        frame(ENC, pulse_count=4_000_000_000, status=1, counter=15),
        frame(DISP, left_mm=355.35, right_mm=-300.0, lateral_mm=0.0, status=0, counter=8),
    )
    displacement, encoder = decoder.take()
    assert displacement.left_mm.tolist() == pytest.approx([12.34, 355.35], abs=1e-9)
    assert displacement.right_mm.tolist() == pytest.approx([-56.78, -300.0], abs=1e-9)
    assert displacement.lateral_mm.tolist() == pytest.approx([199.99, 0.0], abs=1e-9)
    assert displacement.status.tolist() == [5, 0] and displacement.counter.tolist() == [7, 8]
    assert displacement.time_s.tolist() == pytest.approx([0.0, 0.01])
    assert encoder.pulse_count.tolist() == [4_000_000_000]
    assert encoder.status.tolist() == [1] and encoder.counter.tolist() == [15]
    assert (stats.frames, stats.displacement_frames, stats.encoder_frames) == (3, 2, 1)
    again, _ = decoder.take()
    assert again.frames == 0  # take() empties the buffers


def test_unknown_ids_error_and_malformed_frames_are_counted_not_raised() -> None:
    good = frame(DISP, left_mm=1.0, right_mm=2.0, lateral_mm=3.0, status=0, counter=0)
    extended_twin = can.Message(arbitration_id=0x110, is_extended_id=True, data=good.data)
    decoder, stats = decode(
        good,
        can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x00" * 8),
        extended_twin,  # the same id, extended: another frame
        can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01"),
        can.Message(is_error_frame=True),
        can.Message(arbitration_id=0x110, is_extended_id=False, is_remote_frame=True, dlc=8),
        can.Message(arbitration_id=0x110, is_extended_id=False, data=b"\x00\x01"),  # short
    )
    displacement, _ = decoder.take()
    assert displacement.frames == 1
    assert stats.unknown_frames == 3
    assert stats.unknown_ids == {"0x123": 2, "0x00000110x": 1}
    assert (stats.error_frames, stats.remote_frames, stats.malformed_frames) == (1, 1, 1)


def test_frames_going_back_in_time_are_counted_and_dropped() -> None:
    stats = CanStatistics()
    decoder = FrameDecoder(DB, stats)
    for t in (0.0, 0.01, 0.005, 0.015):
        decoder.add(frame(DISP, left_mm=0, right_mm=0, lateral_mm=0, status=0, counter=0), t)
    displacement, _ = decoder.take()
    assert displacement.time_s.tolist() == [0.0, 0.01, 0.015]
    assert stats.out_of_order_frames == 1


def test_a_dbc_without_the_sensor_frames_is_a_one_line_error(tmp_path: Path) -> None:
    text = DBC_PATH.read_text().replace("DisplacementSensors", "Displacement")
    other = tmp_path / "other.dbc"
    other.write_text(text)
    with pytest.raises(UserError, match=r"other\.dbc: no frame 'DisplacementSensors'"):
        load_database(other)
    with pytest.raises(UserError, match="no such DBC file"):
        load_database(tmp_path / "missing.dbc")
    broken = tmp_path / "broken.dbc"
    broken.write_text("BO_ nonsense")
    with pytest.raises(UserError, match=r"broken\.dbc: not a readable DBC file"):
        load_database(broken)
