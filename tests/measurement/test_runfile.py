"""The recorded run file (FORMATS.md "Recorded run: HDF5"): writer, reader, validation."""

from __future__ import annotations

import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from catenary.domain import ScanBlock
from catenary.errors import FormatError, UserError
from catenary.measurement import runfile
from catenary.measurement.runfile import (
    RunFile,
    RunFileReader,
    RunFileWarning,
    RunFileWriter,
    chunk_rows_for,
    open_run,
)

# Camera "a": 8-bit in uint8; camera "b": 12-bit in uint16.
CAMERAS = {"a": (64, 8), "b": (48, 12)}
SCAN_RATE_HZ = 2000.0
HEADER = {
    "line": "L1",
    "track": "up",
    "vehicle": "demo-car",
    "direction": "decreasing",
    "start_chainage_m": 12345.5,
    "started_at": "2024-05-01T10:00:00.000Z",
    "scan_rate_hz": SCAN_RATE_HZ,
}


@dataclass
class Expected:
    """What was written: every scan's data, and the vehicle samples."""

    position_m: np.ndarray
    time_s: np.ndarray
    lines: dict[str, np.ndarray]
    vehicle: dict[str, np.ndarray]


def make_lines(first: int, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    lines = {}
    for name, (pixels, bit_depth) in CAMERAS.items():
        dtype = np.uint8 if bit_depth <= 8 else np.uint16
        lines[name] = rng.integers(0, 1 << bit_depth, size=(n, pixels), dtype=dtype)
    return lines


def write_run(
    path: Path,
    block_sizes: list[int],
    *,
    vehicle_time_s: np.ndarray | None = None,
    chunk_scans: int | None = 16,
    seed: int = 0,
    **writer_options: Any,
) -> Expected:
    """A run of ``sum(block_sizes)`` scans appended in those blocks.

    Scans every 0.5 ms (time) and 2.5 mm (position, with a repeated position at scan 3 to
    show that non-decreasing is allowed). Vehicle sensors (default: at 1 kHz over the run,
    in blocks of 7) are linear in time: left = 1 + 2t, right = -3 + 5t, lateral = 10 - t.
    """
    rng = np.random.default_rng(seed)
    n = sum(block_sizes)
    index = np.arange(n, dtype=np.float64)
    position = index * 0.0025
    if n > 3:
        position[3] = position[2]
    times = index / SCAN_RATE_HZ
    lines_parts: dict[str, list[np.ndarray]] = {name: [] for name in CAMERAS}
    if vehicle_time_s is None:
        vehicle_time_s = np.arange(0.0, max(n, 1) / SCAN_RATE_HZ + 0.002, 0.001)
    vehicle = linear_vehicle(vehicle_time_s)
    with RunFileWriter(
        path, cameras=CAMERAS, chunk_scans=chunk_scans, **HEADER, **writer_options
    ) as writer:
        first = 0
        for size in block_sizes:
            lines = make_lines(first, size, rng)
            writer.append(position[first : first + size], times[first : first + size], lines)
            for name in CAMERAS:
                lines_parts[name].append(lines[name].copy())
            first += size
        for start in range(0, vehicle_time_s.shape[0], 7):
            sl = slice(start, start + 7)
            writer.append_vehicle(
                vehicle["time_s"][sl],
                vehicle["left_mm"][sl],
                vehicle["right_mm"][sl],
                vehicle["lateral_mm"][sl],
            )
        assert writer.scans == n
    lines_all = {
        name: np.concatenate(parts)
        if parts
        else np.zeros((0, CAMERAS[name][0]), dtype=np.uint8 if CAMERAS[name][1] <= 8 else np.uint16)
        for name, parts in lines_parts.items()
    }
    return Expected(position, times, lines_all, vehicle)


def linear_vehicle(t: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "time_s": np.asarray(t, dtype=np.float64),
        "left_mm": 1.0 + 2.0 * t,
        "right_mm": -3.0 + 5.0 * t,
        "lateral_mm": 10.0 - t,
    }


def read_all(run: RunFile, block_scans: int = 10**9, **kwargs: Any) -> list[ScanBlock]:
    return list(run.blocks(block_scans, **kwargs))


def concat(blocks: list[ScanBlock], field: str) -> np.ndarray:
    return np.concatenate([getattr(b, field) for b in blocks])


def concat_vehicle(blocks: list[ScanBlock], field: str) -> np.ndarray:
    return np.concatenate([getattr(b.vehicle, field) for b in blocks])


def concat_lines(blocks: list[ScanBlock], camera: str) -> np.ndarray:
    return np.concatenate([b.cameras[camera].lines for b in blocks])


@pytest.fixture
def no_warnings() -> Iterator[None]:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


@pytest.fixture
def run_path(tmp_path: Path) -> Path:
    return tmp_path / "run.h5"


# -- round trip ------------------------------------------------------------------------------


def test_round_trip_multi_block_is_exact(run_path: Path, no_warnings: None) -> None:
    # Single scans (staged), blocks smaller and larger than a chunk, an empty block.
    sizes = [1, 1, 5, 40, 0, 3, 100, 16, 7]
    expected = write_run(run_path, sizes)
    with open_run(run_path) as run:
        assert run.complete
        header = run.header
        assert header.scans == sum(sizes)
        assert header.line == "L1"
        assert header.track == "up"
        assert header.vehicle == "demo-car"
        assert header.direction == "decreasing"
        assert header.start_chainage_m == 12345.5
        assert header.started_at == "2024-05-01T10:00:00.000Z"
        assert header.scan_rate_hz == SCAN_RATE_HZ
        assert header.camera_pixels == {"a": 64, "b": 48}
        assert header.camera_bit_depth == {"a": 8, "b": 12}
        assert run.cameras == ("a", "b")
        blocks = read_all(run)
    assert len(blocks) == 1
    block = blocks[0]
    assert block.first_scan == 0
    np.testing.assert_array_equal(block.position_m, expected.position_m)
    np.testing.assert_array_equal(block.time_s, expected.time_s)
    for name in CAMERAS:
        lines = block.cameras[name].lines
        assert lines.dtype == expected.lines[name].dtype
        np.testing.assert_array_equal(lines, expected.lines[name])
        assert block.cameras[name].bit_depth == CAMERAS[name][1]


def test_root_attributes_follow_formats_md(run_path: Path) -> None:
    write_run(run_path, [10])
    with h5py.File(run_path, "r") as f:
        assert f.attrs["format"] == "catenary-run"
        assert f.attrs["format_version"] == 1
        assert f.attrs["direction"] == "decreasing"
        assert f.attrs["complete"] is np.True_
        assert f.attrs["completed_scans"] == 10
        assert isinstance(f.attrs["completed_at"], str)
        assert f["scans/position_m"].dtype == np.float64
        assert f["scans/position_m"].chunks is not None
        assert f["cameras/a/lines"].dtype == np.uint8
        assert f["cameras/b/lines"].dtype == np.uint16
        assert f["cameras/b/lines"].attrs["bit_depth"] == 12
        assert f["cameras/a/lines"].chunks == (16, 64)
        assert f["cameras/a/lines"].maxshape == (None, 64)
        for name in ("time_s", "left_mm", "right_mm", "lateral_mm"):
            assert f[f"vehicle/{name}"].dtype == np.float64


def test_default_chunks_are_one_to_two_mib(tmp_path: Path) -> None:
    path = tmp_path / "big.h5"
    cams = {"u8": (4096, 8), "u16": (16384, 16), "odd": (3000, 10)}
    with RunFileWriter(path, scan_rate_hz=1.0, cameras=cams):
        pass
    with h5py.File(path, "r") as f:
        for name in cams:
            ds = f[f"cameras/{name}/lines"]
            chunk_bytes = ds.chunks[0] * ds.chunks[1] * ds.dtype.itemsize
            assert 1 << 20 <= chunk_bytes <= 2 << 20, name
            assert ds.chunks[1] == cams[name][0]


def test_chunk_rows_for() -> None:
    assert chunk_rows_for(4096) == 512
    assert chunk_rows_for(3000) == 512
    assert chunk_rows_for(8) == 262144
    assert chunk_rows_for(10 * 1024 * 1024) == 1


@pytest.mark.parametrize("block_scans", [1, 7, 16, 33, 100, 1000])
def test_streaming_in_blocks_gives_the_same_data(run_path: Path, block_scans: int) -> None:
    expected = write_run(run_path, [50, 50, 72])
    with open_run(run_path) as run:
        whole = read_all(run)[0]
        blocks = read_all(run, block_scans)
    n = expected.position_m.shape[0]
    assert [b.first_scan for b in blocks] == list(range(0, n, block_scans))
    assert all(b.scans == block_scans for b in blocks[:-1])
    assert sum(b.scans for b in blocks) == n
    np.testing.assert_array_equal(concat(blocks, "position_m"), expected.position_m)
    np.testing.assert_array_equal(concat(blocks, "time_s"), expected.time_s)
    for name in CAMERAS:
        np.testing.assert_array_equal(concat_lines(blocks, name), expected.lines[name])
    for field in ("left_mm", "right_mm", "lateral_mm", "fault", "time_s"):
        np.testing.assert_array_equal(concat_vehicle(blocks, field), getattr(whole.vehicle, field))


def test_start_and_stop_select_scans(run_path: Path) -> None:
    expected = write_run(run_path, [60])
    with open_run(run_path) as run:
        blocks = read_all(run, 8, start=13, stop=47)
        assert blocks[0].first_scan == 13
        np.testing.assert_array_equal(concat(blocks, "time_s"), expected.time_s[13:47])
        np.testing.assert_array_equal(concat_lines(blocks, "b"), expected.lines["b"][13:47])
        left = concat_vehicle(blocks, "left_mm")
        np.testing.assert_allclose(left, 1.0 + 2.0 * expected.time_s[13:47], rtol=0, atol=1e-12)
        assert read_all(run, 8, start=20, stop=20) == []
        with pytest.raises(ValueError, match="start"):
            run.blocks(8, start=10, stop=5)
        with pytest.raises(ValueError, match="block_scans"):
            run.blocks(0)


def test_reader_alias_and_repr(run_path: Path) -> None:
    write_run(run_path, [3])
    assert RunFileReader is RunFile
    with RunFile(run_path) as run:
        assert "3 scans" in repr(run)
    with pytest.raises(ValueError, match="closed"):
        run.blocks()


@pytest.mark.parametrize(
    ("compression", "options"),
    [
        (None, {}),
        ("gzip", {}),
        ("gzip", {"compression_opts": 9, "shuffle": True, "fletcher32": True}),
        ("lzf", {}),
        ("lzf", {"shuffle": False}),
        pytest.param(
            "szip",
            {},
            marks=pytest.mark.skipif(
                not h5py.h5z.filter_avail(h5py.h5z.FILTER_SZIP), reason="no szip in this HDF5"
            ),
        ),
    ],
)
def test_compressed_files_round_trip(
    run_path: Path, compression: str | None, options: dict[str, Any]
) -> None:
    expected = write_run(run_path, [30, 30, 11], compression=compression, **options)
    with h5py.File(run_path, "r") as f:
        assert f["cameras/b/lines"].compression == compression
        assert f["scans/time_s"].compression == compression
        if compression == "gzip" and not options:
            assert f["cameras/b/lines"].compression_opts == runfile.DEFAULT_GZIP_LEVEL
            assert f["cameras/b/lines"].shuffle
    with open_run(run_path) as run:
        blocks = read_all(run, 13)
    np.testing.assert_array_equal(concat(blocks, "position_m"), expected.position_m)
    for name in CAMERAS:
        np.testing.assert_array_equal(concat_lines(blocks, name), expected.lines[name])


def test_uint16_lines_with_bit_depth_12(run_path: Path) -> None:
    expected = write_run(run_path, [20])
    assert expected.lines["b"].max() > 255  # really uses the upper bits
    with open_run(run_path) as run:
        block = read_all(run)[0]
    lines = block.cameras["b"]
    assert lines.bit_depth == 12
    assert lines.lines.dtype == np.uint16
    assert int(lines.lines.max()) <= 4095
    np.testing.assert_array_equal(lines.lines, expected.lines["b"])


def test_a_third_party_file_in_the_formats_md_layout_is_read(run_path: Path) -> None:
    """Big-endian data, fixed-length byte-string attributes, contiguous datasets, no marker."""
    n = 9
    lines = np.arange(n * 5, dtype=">u2").reshape(n, 5) * 100
    with h5py.File(run_path, "w") as f:
        for key, value in {
            "format": b"catenary-run",
            "line": b"",
            "track": b"2",
            "vehicle": b"",
            "direction": b"increasing",
            "started_at": b"2023-01-01T00:00:00Z",
        }.items():
            f.attrs.create(key, np.bytes_(value))
        f.attrs["format_version"] = np.int32(1)
        f.attrs["start_chainage_m"] = 100  # an integer is a number
        f.attrs["scan_rate_hz"] = 500.0
        f.attrs["operator_note"] = "ignored"
        f["scans/position_m"] = np.arange(n, dtype=">f8")
        f["scans/time_s"] = np.arange(n, dtype="<f8") / 500.0
        f["cameras/cam0/lines"] = lines
        f["cameras/cam0/lines"].attrs["bit_depth"] = 16
        f["cameras/cam0/notes"] = [1, 2, 3]  # unknown extra dataset
        f["vehicle/time_s"] = np.array([0.0, 0.01, 0.02])
        for name in ("left_mm", "right_mm", "lateral_mm"):
            f[f"vehicle/{name}"] = np.array([0.0, 1.0, 2.0])
        f.create_group("extra/stuff")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no recording state: nothing known, no warning
        run = open_run(run_path)
    with run:
        assert run.complete is None
        assert run.header.scans == n
        assert run.header.track == "2"
        assert run.header.start_chainage_m == 100.0
        block = read_all(run)[0]
    assert block.cameras["cam0"].lines.dtype == np.uint16
    np.testing.assert_array_equal(block.cameras["cam0"].lines, lines)
    np.testing.assert_array_equal(block.position_m, np.arange(n))
    # vehicle at 100 Hz, scans at 500 Hz: left = 100 * t
    np.testing.assert_allclose(block.vehicle.left_mm, 100.0 * block.time_s, atol=1e-12)


def test_unknown_groups_and_attributes_are_ignored(run_path: Path, no_warnings: None) -> None:
    expected = write_run(run_path, [12])
    with h5py.File(run_path, "r+") as f:
        f.attrs["something_new"] = 3
        f["scans/position_m"].attrs["unit_note"] = "metres"
        f.create_group("calibration").create_dataset("m", data=np.eye(3))
        f["scans/quality"] = np.ones(12)
    with open_run(run_path) as run:
        block = read_all(run)[0]
    np.testing.assert_array_equal(block.position_m, expected.position_m)


@pytest.mark.parametrize("compression", [None, "gzip"])
def test_image_blocks_read_the_lines_anywhere(run_path: Path, compression: str | None) -> None:
    # unfiltered lines are read at their chunks' offsets (a few rows), compressed ones by
    # HDF5: the same rows either way, within a chunk of 16, across chunks, at the end
    expected = write_run(run_path, [30, 30, 11], compression=compression)
    with open_run(run_path) as run:
        for first, last in [(0, 5), (3, 16), (14, 18), (5, 71), (64, 71), (40, 40)]:
            block = run.image_block(first, last)
            np.testing.assert_array_equal(block.position_m, expected.position_m[first:last])
            for name in CAMERAS:
                lines = block.cameras[name].lines
                assert lines.dtype == expected.lines[name].dtype
                np.testing.assert_array_equal(lines, expected.lines[name][first:last])


# -- vehicle sensors -------------------------------------------------------------------------


def test_vehicle_sensors_are_linearly_interpolated_to_scan_times(run_path: Path) -> None:
    # Sensors at 1 kHz, scans at 2 kHz: every other scan falls half-way between two samples.
    expected = write_run(run_path, [64])
    with open_run(run_path) as run:
        assert run.vehicle_interval_s == pytest.approx(0.001)
        vehicle = read_all(run, 10)
    t = concat_vehicle(vehicle, "time_s")
    np.testing.assert_array_equal(t, expected.time_s)
    np.testing.assert_allclose(concat_vehicle(vehicle, "left_mm"), 1.0 + 2.0 * t, atol=1e-12)
    np.testing.assert_allclose(concat_vehicle(vehicle, "right_mm"), -3.0 + 5.0 * t, atol=1e-12)
    np.testing.assert_allclose(concat_vehicle(vehicle, "lateral_mm"), 10.0 - t, atol=1e-12)
    assert not concat_vehicle(vehicle, "fault").any()


def test_vehicle_interpolation_of_a_non_linear_signal(run_path: Path) -> None:
    # Samples (0, 0), (0.002, 4), (0.004, 0): a scan at 0.0005 s reads 1.0, at 0.003 s 2.0.
    with RunFileWriter(run_path, scan_rate_hz=2000.0, cameras={"a": (4, 8)}) as w:
        times = np.array([0.0, 0.0005, 0.003, 0.004])
        w.append(np.arange(4.0), times, {"a": np.zeros((4, 4), np.uint8)})
        w.append_vehicle([0.0, 0.002, 0.004], [0.0, 4.0, 0.0], [1.0, 1.0, 1.0], [0.0, -2.0, 2.0])
    with open_run(run_path) as run:
        v = read_all(run)[0].vehicle
    np.testing.assert_allclose(v.left_mm, [0.0, 1.0, 2.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(v.right_mm, [1.0, 1.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(v.lateral_mm, [0.0, -0.5, 0.0, 2.0], atol=1e-12)
    assert not v.fault.any()


def test_scans_outside_the_sensor_time_range_are_faults(run_path: Path) -> None:
    # Sensors from 0.005 s to 0.015 s; scans from 0 to 0.0315 s.
    write_run(run_path, [64], vehicle_time_s=np.arange(5, 16) / 1000.0)
    with open_run(run_path) as run:
        blocks = read_all(run, 9)
    t = concat_vehicle(blocks, "time_s")
    fault = concat_vehicle(blocks, "fault")
    left = concat_vehicle(blocks, "left_mm")
    inside = (t >= 0.005 - 1e-12) & (t <= 0.015 + 1e-12)
    np.testing.assert_array_equal(fault, ~inside)
    np.testing.assert_allclose(left[inside], 1.0 + 2.0 * t[inside], atol=1e-12)
    # outside: the edge sample's value is held (and flagged)
    np.testing.assert_allclose(left[t < 0.005], 1.0 + 2.0 * 0.005, atol=1e-12)
    np.testing.assert_allclose(left[t > 0.015 + 1e-9], 1.0 + 2.0 * 0.015, atol=1e-12)


def test_scans_inside_a_gap_in_the_sensor_samples_are_faults(run_path: Path) -> None:
    # 1 kHz samples; one sample missing at 0.005 s (a 2 ms interval: tolerated) and three
    # missing at 0.011-0.013 s (a 4 ms interval, over 2.5 x the median 1 ms: a gap).
    t_v = np.arange(0.0, 0.033, 0.001)
    keep = ~np.isin(np.round(t_v * 1000).astype(int), [5, 11, 12, 13])
    write_run(run_path, [64], vehicle_time_s=t_v[keep])
    with open_run(run_path) as run:
        blocks = read_all(run, 5)
        assert run.vehicle_interval_s == pytest.approx(0.001)
    t = concat_vehicle(blocks, "time_s")
    fault = concat_vehicle(blocks, "fault")
    in_gap = (t > 0.010 + 1e-12) & (t < 0.014 - 1e-12)
    np.testing.assert_array_equal(fault, in_gap)
    # values are still interpolated (across the gap), exactly for a linear signal
    np.testing.assert_allclose(concat_vehicle(blocks, "left_mm"), 1 + 2 * t, atol=1e-12)
    # a larger factor tolerates the gap
    with open_run(run_path) as run:
        assert not concat_vehicle(read_all(run, 5, max_gap_factor=5.0), "fault").any()


def test_non_finite_sensor_values_count_as_missing(run_path: Path) -> None:
    with RunFileWriter(run_path, scan_rate_hz=1000.0, cameras={"a": (2, 8)}) as w:
        t = np.arange(20) / 1000.0
        w.append(t, t, {"a": np.zeros((20, 2), np.uint8)})
        left = t * 1.0
        left[8:11] = np.nan  # samples 8, 9, 10 missing: a 4 ms interval from 7 to 11
        w.append_vehicle(t, left, t, t)
    with open_run(run_path) as run:
        v = read_all(run)[0].vehicle
    expected_fault = np.zeros(20, bool)
    expected_fault[8:11] = True
    np.testing.assert_array_equal(v.fault, expected_fault)
    assert np.isfinite(v.left_mm).all()


def test_no_vehicle_samples_means_every_scan_is_a_fault(run_path: Path) -> None:
    write_run(run_path, [10], vehicle_time_s=np.zeros(0))
    with open_run(run_path) as run:
        assert run.vehicle_samples == 0
        assert run.vehicle_interval_s is None
        v = read_all(run)[0].vehicle
    assert v.fault.all()
    np.testing.assert_array_equal(v.left_mm, np.zeros(10))


def test_vehicle_samples_are_streamed_across_many_chunks(
    run_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Tiny chunks and validation slices: the reader never needs a whole vehicle dataset."""
    monkeypatch.setattr(runfile, "SERIES_CHUNK", 5)
    monkeypatch.setattr(runfile, "_VALIDATE_SLICE", 6)
    t_v = np.arange(0.0, 0.0345, 0.0005) + 0.0001  # 2 kHz, offset from the scans
    t_v = np.delete(t_v, [30, 31, 32])  # a gap from 0.0146 to 0.0166 s
    expected = write_run(run_path, [40, 29], vehicle_time_s=t_v)
    with h5py.File(run_path, "r") as f:
        assert f["vehicle/time_s"].chunks == (5,)
    with open_run(run_path) as run:
        assert run.vehicle_interval_s == pytest.approx(0.0005)
        blocks = read_all(run, 4)
    t = concat_vehicle(blocks, "time_s")
    np.testing.assert_array_equal(t, expected.time_s)
    fault = concat_vehicle(blocks, "fault")
    expected_fault = (t < 0.0001) | ((t > 0.0146) & (t < 0.0166)) | (t > t_v[-1])
    np.testing.assert_array_equal(fault, expected_fault)
    ok = ~fault
    np.testing.assert_allclose(concat_vehicle(blocks, "right_mm")[ok], -3 + 5 * t[ok], atol=1e-12)


class _SpyDataset:
    """Records how many rows each read asks for."""

    def __init__(self, ds: Any, reads: list[int]) -> None:
        self._ds = ds
        self._reads = reads
        self.shape = ds.shape
        self.dtype = ds.dtype

    def read_direct(self, out: np.ndarray, source_sel: Any, dest_sel: Any) -> None:
        self._reads.append(source_sel.stop - source_sel.start)
        self._ds.read_direct(out, source_sel, dest_sel)

    def __getitem__(self, item: Any) -> Any:
        raise AssertionError(f"read by indexing {item!r}, not in bounded slices")


def test_blocks_read_every_dataset_in_bounded_slices(
    run_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(runfile, "SERIES_CHUNK", 6)
    expected = write_run(run_path, [100])  # 100 scans, 52 vehicle samples
    reads: list[int] = []
    with open_run(run_path) as run:
        for table in (run._series, run._lines, run._vehicle):
            for name in table:
                table[name] = _SpyDataset(table[name], reads)
        blocks = read_all(run, 8)
    assert reads
    assert max(reads) <= 8
    np.testing.assert_array_equal(concat_lines(blocks, "a"), expected.lines["a"])
    np.testing.assert_allclose(
        concat_vehicle(blocks, "left_mm"), 1 + 2 * expected.time_s, rtol=0, atol=1e-12
    )


# -- malformed files ---------------------------------------------------------------------


def _set_attr(name: str, value: Any) -> Callable[[h5py.File], None]:
    def mutate(f: h5py.File) -> None:
        f.attrs[name] = value

    return mutate


def _del_attr(name: str, where: str = "/") -> Callable[[h5py.File], None]:
    def mutate(f: h5py.File) -> None:
        del f[where].attrs[name]

    return mutate


def _delete(where: str) -> Callable[[h5py.File], None]:
    def mutate(f: h5py.File) -> None:
        del f[where]

    return mutate


def _replace(where: str, dtype: Any) -> Callable[[h5py.File], None]:
    def mutate(f: h5py.File) -> None:
        data = f[where][()]
        attrs = dict(f[where].attrs)
        del f[where]
        f[where] = data.astype(dtype)
        f[where].attrs.update(attrs)

    return mutate


def _set_value(where: str, index: int, value: float) -> Callable[[h5py.File], None]:
    def mutate(f: h5py.File) -> None:
        f[where][index] = value

    return mutate


def _resize(where: str, length: int) -> Callable[[h5py.File], None]:
    def mutate(f: h5py.File) -> None:
        f[where].resize(length, axis=0)

    return mutate


MALFORMED: dict[str, tuple[Callable[[h5py.File], None], list[str]]] = {
    "wrong format": (
        _set_attr("format", "catenary-calibration"),
        ["format", "catenary-calibration"],
    ),
    "unknown version": (_set_attr("format_version", 2), ["format_version", "2"]),
    "version not int": (_set_attr("format_version", "1"), ["format_version", "'1'"]),
    "no format": (_del_attr("format"), ["format", "missing"]),
    "no direction": (_del_attr("direction"), ["direction", "missing"]),
    "bad direction": (_set_attr("direction", "north"), ["direction", "north"]),
    "rate not positive": (_set_attr("scan_rate_hz", 0.0), ["scan_rate_hz", "0.0"]),
    "chainage not a number": (
        _set_attr("start_chainage_m", "km 12"),
        ["start_chainage_m", "km 12"],
    ),
    "bad started_at": (_set_attr("started_at", "yesterday"), ["started_at", "yesterday"]),
    "line with ESC": (
        _set_attr("line", "L1\x1b[2J"),
        ["/ attribute line = 'L1\\x1b[2J' holds a control character"],
    ),
    "track with CR LF": (_set_attr("track", "1\r\n"), ["/ attribute track = '1\\r\\n'"]),
    "vehicle with C1": (_set_attr("vehicle", "V\x9b"), ["/ attribute vehicle = 'V\\x9b'"]),
    "no positions": (_delete("scans/position_m"), ["/scans/position_m", "missing"]),
    "no times": (_delete("scans/time_s"), ["/scans/time_s", "missing"]),
    "no scans group": (_delete("scans"), ["/scans/position_m", "missing"]),
    "no vehicle lateral": (_delete("vehicle/lateral_mm"), ["/vehicle/lateral_mm", "missing"]),
    "no lines": (_delete("cameras/b/lines"), ["/cameras/b/lines", "missing"]),
    "no cameras": (_delete("cameras"), ["/cameras", "missing"]),
    "no bit_depth": (_del_attr("bit_depth", "cameras/a/lines"), ["/cameras/a/lines", "bit_depth"]),
    "bad bit_depth": (
        lambda f: f["cameras/a/lines"].attrs.__setitem__("bit_depth", 24),
        ["/cameras/a/lines", "bit_depth", "24"],
    ),
    "uint8 for 12 bits": (
        _replace("cameras/b/lines", np.uint8),
        ["/cameras/b/lines", "uint8", "12"],
    ),
    "int16 lines": (_replace("cameras/a/lines", np.int16), ["/cameras/a/lines", "int16"]),
    "float32 times": (_replace("scans/time_s", np.float32), ["/scans/time_s", "float32"]),
    "int vehicle": (_replace("vehicle/left_mm", np.int64), ["/vehicle/left_mm", "int64"]),
    "lines shorter (marked complete)": (
        _resize("cameras/a/lines", 30),
        ["/cameras/a/lines", "30", "completed_scans = 40"],
    ),
    "complete without completed_scans": (
        _del_attr("completed_scans"),
        ["complete = True", "without completed_scans"],
    ),
    "incomplete with completed_scans": (
        _set_attr("complete", False),
        ["complete = False", "completed_scans = 40"],
    ),
    "complete not a bool": (_set_attr("complete", "yes"), ["/ attribute complete", "'yes'"]),
    "complete = 2": (_set_attr("complete", 2), ["/ attribute complete = 2"]),
    "negative offset_px": (
        lambda f: f["cameras/a"].attrs.__setitem__("offset_px", -1),
        ["/cameras/a", "offset_px = -1"],
    ),
    "fractional offset_px": (
        lambda f: f["cameras/a"].attrs.__setitem__("offset_px", 2.5),
        ["/cameras/a", "offset_px = 2.5"],
    ),
    "vehicle lengths differ (marked complete)": (
        _resize("vehicle/right_mm", 3),
        ["/vehicle/right_mm", "3", "mismatched"],
    ),
    "decreasing position": (
        _set_value("scans/position_m", 17, -1.0),
        ["/scans/position_m", "17", "-1.0"],
    ),
    "NaN position": (_set_value("scans/position_m", 9, np.nan), ["/scans/position_m", "9", "nan"]),
    "decreasing time": (_set_value("scans/time_s", 21, 0.0), ["/scans/time_s", "21"]),
    "decreasing vehicle time": (_set_value("vehicle/time_s", 4, 0.0), ["/vehicle/time_s", "4"]),
    "bad marker": (_set_attr("completed_scans", "yes"), ["completed_scans", "yes"]),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_files_raise_format_error_naming_path_and_value(
    run_path: Path, case: str
) -> None:
    write_run(run_path, [25, 15])
    mutate, needles = MALFORMED[case]
    with h5py.File(run_path, "r+") as f:
        mutate(f)
    with pytest.raises(FormatError) as info:
        open_run(run_path)
    message = str(info.value)
    assert str(run_path) in message
    assert "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)
    assert isinstance(info.value, UserError)


def test_a_file_that_is_not_hdf5(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    path.write_text("time_s,position_m\n0,0\n")
    with pytest.raises(FormatError, match="HDF5") as info:
        open_run(path)
    assert str(path) in str(info.value)


def test_a_missing_file_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no such file"):
        open_run(tmp_path / "nope.h5")


# -- the recording state ------------------------------------------------------------------


def interrupt(f: h5py.File) -> None:
    """Make a closed run file read as the project's recorder leaves an interrupted one."""
    del f.attrs["completed_scans"]
    del f.attrs["completed_at"]
    f.attrs["complete"] = False


def test_an_interrupted_recording_reads_everything_with_one_warning(run_path: Path) -> None:
    expected = write_run(run_path, [30])
    with h5py.File(run_path, "r+") as f:
        interrupt(f)
    with pytest.warns(RunFileWarning) as record:
        run = open_run(run_path)
    assert len(record) == 1
    message = str(record[0].message)
    assert "\n" not in message
    for needle in (str(run_path), "complete = False", "interrupted", "30 scans"):
        assert needle in message, (needle, message)
    with run:
        assert run.complete is False
        block = read_all(run)[0]
    np.testing.assert_array_equal(block.position_m, expected.position_m)


def no_warning_open(path: Path) -> RunFile:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return open_run(path)


@pytest.mark.parametrize("attrs", [("complete", "completed_scans", "completed_at"), ("complete",)])
def test_a_file_without_the_recording_state_reads_without_a_warning(
    run_path: Path, attrs: tuple[str, ...]
) -> None:
    """No attribute at all: another recorder (or an interrupted recording of this project's
    before ``complete`` existed, which cannot be told apart): nothing known, no warning. The
    marker alone (this project's files before ``complete`` existed): complete."""
    expected = write_run(run_path, [30])
    with h5py.File(run_path, "r+") as f:
        for name in attrs:
            del f.attrs[name]
    with no_warning_open(run_path) as run:
        assert run.complete is (True if "completed_scans" not in attrs else None)
        assert run.header.scans == 30
        np.testing.assert_array_equal(read_all(run)[0].position_m, expected.position_m)


def test_datasets_longer_than_completed_scans_are_read_up_to_it(run_path: Path) -> None:
    expected = write_run(run_path, [40])
    with h5py.File(run_path, "r+") as f:
        f.attrs["completed_scans"] = 35
        f["scans/time_s"].resize(45, axis=0)  # a row written after the count: not read
        f["scans/time_s"][40:] = 1.0
    with no_warning_open(run_path) as run:
        assert run.complete is True
        assert run.header.scans == 35
        blocks = read_all(run, 8)
    np.testing.assert_array_equal(concat(blocks, "time_s"), expected.time_s[:35])
    np.testing.assert_array_equal(concat_lines(blocks, "a"), expected.lines["a"][:35])


def test_another_recorders_file_of_unequal_lengths_warns_once(run_path: Path) -> None:
    write_run(run_path, [30])
    with h5py.File(run_path, "r+") as f:
        for name in ("complete", "completed_scans", "completed_at"):
            del f.attrs[name]
        f["cameras/b/lines"].resize(20, axis=0)
    with pytest.warns(RunFileWarning) as record:
        run = open_run(run_path)
    assert len(record) == 1
    assert "different lengths" in str(record[0].message)
    assert "/cameras/b/lines 20" in str(record[0].message)
    with run:
        assert run.complete is None and run.header.scans == 20


@pytest.mark.parametrize(
    ("shorten", "length"),
    [
        ("cameras/a/lines", 33),
        ("cameras/b/lines", 1),
        ("scans/position_m", 40),
        ("scans/time_s", 0),
    ],
)
def test_truncated_file_reads_up_to_the_last_complete_scan(
    run_path: Path, shorten: str, length: int
) -> None:
    expected = write_run(run_path, [25, 25])
    with h5py.File(run_path, "r+") as f:
        interrupt(f)
        f[shorten].resize(length, axis=0)
    with pytest.warns(RunFileWarning, match=rf"the {length} scans") as record:
        run = open_run(run_path)
    assert str(run_path) in str(record[0].message)
    assert f"/{shorten} {length}" in str(record[0].message)
    with run:
        assert run.header.scans == length
        blocks = read_all(run, 8)
    assert sum(b.scans for b in blocks) == length
    if length:
        np.testing.assert_array_equal(concat(blocks, "position_m"), expected.position_m[:length])
        for name in CAMERAS:
            np.testing.assert_array_equal(concat_lines(blocks, name), expected.lines[name][:length])


def test_truncated_vehicle_datasets_are_read_up_to_the_shortest(run_path: Path) -> None:
    write_run(run_path, [50])
    with h5py.File(run_path, "r+") as f:
        interrupt(f)
        f["vehicle/lateral_mm"].resize((10,))  # samples 0..9: 0 to 0.009 s
    with pytest.warns(RunFileWarning, match="10 vehicle samples"):
        run = open_run(run_path)
    with run:
        assert run.header.scans == 50
        v = read_all(run)[0].vehicle
    np.testing.assert_array_equal(v.fault, v.time_s > 0.009 + 1e-12)


def test_a_recording_that_raised_is_read_as_interrupted(run_path: Path) -> None:
    rng = np.random.default_rng(3)
    with (
        pytest.raises(RuntimeError, match="camera lost"),
        RunFileWriter(run_path, scan_rate_hz=1.0, cameras=CAMERAS, chunk_scans=4) as w,
    ):
        w.append(np.arange(10.0), np.arange(10.0), make_lines(0, 10, rng))
        raise RuntimeError("camera lost")
    with h5py.File(run_path, "r") as f:  # as created: the recording state is false
        assert f.attrs["complete"] is np.False_
        assert "completed_scans" not in f.attrs and "completed_at" not in f.attrs
    with pytest.warns(RunFileWarning, match="10 scans") as record:
        run = open_run(run_path)
    assert len(record) == 1
    with run:
        assert run.header.scans == 10 and run.complete is False


def test_a_truncated_file_that_is_also_malformed_is_an_error(run_path: Path) -> None:
    write_run(run_path, [30])
    with h5py.File(run_path, "r+") as f:
        interrupt(f)
        f["cameras/a/lines"].resize(20, axis=0)
        f["scans/position_m"][25] = 0.0  # beyond the usable scans: not checked
        f["scans/position_m"][12] = -5.0
    with pytest.warns(RunFileWarning), pytest.raises(FormatError, match="/scans/position_m"):
        open_run(run_path)


# -- the writer validates its input --------------------------------------------------------


def _writer(path: Path, **kwargs: Any) -> RunFileWriter:
    return RunFileWriter(path, scan_rate_hz=100.0, cameras=CAMERAS, **kwargs)


def _good_lines(n: int) -> dict[str, np.ndarray]:
    return make_lines(0, n, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("positions", "times", "lines", "needle"),
    [
        ([0.0, 1.0, 0.5], [0, 1, 2], _good_lines(3), "block_positions_m decreases at 3"),
        ([0.0, np.nan, 2.0], [0, 1, 2], _good_lines(3), "block_positions_m[2]"),
        ([0.0, 1.0, 2.0], [0, 2, 1], _good_lines(3), "time_s decreases"),
        ([0.0, 1.0], [0, 1, 2], _good_lines(3), "time_s has 3 values"),
        ([[0.0, 1.0, 2.0]], [0, 1, 2], _good_lines(3), "1-D"),
        ([0.0, 1.0, 2.0], [0, 1, 2], {"a": _good_lines(3)["a"]}, "no lines for camera(s) b"),
        (
            [0.0, 1.0, 2.0],
            [0, 1, 2],
            {**_good_lines(3), "c": _good_lines(3)["a"]},
            "unknown camera(s) c",
        ),
        (
            [0.0, 1.0, 2.0],
            [0, 1, 2],
            {**_good_lines(3), "a": _good_lines(3)["a"][:, :60]},
            "expected (3, 64)",
        ),
        (
            [0.0, 1.0, 2.0],
            [0, 1, 2],
            {**_good_lines(3), "b": _good_lines(3)["b"].astype(np.uint8)},
            "expected uint16 for bit_depth 12",
        ),
        (
            [0.0, 1.0, 2.0],
            [0, 1, 2],
            {**_good_lines(3), "a": _good_lines(3)["a"].astype(np.uint16)},
            "expected uint8 for bit_depth 8",
        ),
        (
            [0.0, 1.0, 2.0],
            [0, 1, 2],
            {**_good_lines(3), "b": np.full((3, 48), 4096, np.uint16)},
            "4096, above the 12-bit maximum 4095",
        ),
    ],
)
def test_writer_rejects_bad_blocks_and_writes_none_of_them(
    run_path: Path, positions: Any, times: Any, lines: dict[str, np.ndarray], needle: str
) -> None:
    with _writer(run_path) as w:
        w.append([0.0], [0.0], _good_lines(1))
        with pytest.raises(ValueError) as info:
            w.append(positions, times, lines)
        assert needle in str(info.value)
        assert str(run_path) in str(info.value)
        assert w.scans == 1
    with open_run(run_path) as run:
        assert run.header.scans == 1


def test_writer_rejects_positions_going_back_across_blocks(run_path: Path) -> None:
    with _writer(run_path) as w:
        w.append([0.0, 5.0], [0.0, 1.0], _good_lines(2))
        with pytest.raises(ValueError, match=r"block_positions_m decreases at 2: 5.0 -> 4.0"):
            w.append([4.0], [2.0], _good_lines(1))
        w.append_vehicle([0.0, 1.0], [0, 0], [0, 0], [0, 0])
        with pytest.raises(ValueError, match="vehicle time_s decreases"):
            w.append_vehicle(0.5, 0.0, 0.0, 0.0)
        with pytest.raises(ValueError, match="right_mm has 1 values"):
            w.append_vehicle([2.0, 3.0], [0, 0], [0], [0, 0])


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"direction": "up"}, "direction"),
        ({"scan_rate_hz": -1.0}, "scan_rate_hz"),
        ({"start_chainage_m": float("nan")}, "start_chainage_m"),
        ({"started_at": "noon"}, "started_at"),
        ({"cameras": {}}, "at least one camera"),
        ({"cameras": {"a/b": (10, 8)}}, "camera name"),
        ({"cameras": {"a": (0, 8)}}, "pixels"),
        ({"cameras": {"a": (10, 17)}}, "bit_depth"),
        ({"compression": "zstd"}, "compression"),
        ({"chunk_scans": 0}, "chunk_scans"),
    ],
)
def test_writer_rejects_bad_settings(run_path: Path, kwargs: dict[str, Any], needle: str) -> None:
    settings: dict[str, Any] = {"scan_rate_hz": 100.0, "cameras": CAMERAS, **kwargs}
    with pytest.raises(ValueError, match=needle):
        RunFileWriter(run_path, **settings)
    assert not run_path.exists()


def test_writer_does_not_overwrite_a_run(run_path: Path) -> None:
    write_run(run_path, [5])
    with pytest.raises(UserError, match="already exists"):
        _writer(run_path)
    with open_run(run_path) as run:
        assert run.header.scans == 5
    with _writer(run_path, overwrite=True):
        pass
    with open_run(run_path) as run:
        assert run.header.scans == 0


def test_cameras_may_have_any_name(run_path: Path) -> None:
    cams = {"time_s": (3, 8), "position_m": (2, 16), "cam 1": (1, 1)}
    lines = {
        "time_s": np.full((4, 3), 7, np.uint8),
        "position_m": np.full((4, 2), 65535, np.uint16),
        "cam 1": np.ones((4, 1), np.uint8),
    }
    with RunFileWriter(run_path, scan_rate_hz=1.0, cameras=cams) as w:
        w.append(np.arange(4.0) * 10, np.arange(4.0), lines)
    with open_run(run_path) as run:
        block = read_all(run)[0]
    np.testing.assert_array_equal(block.time_s, np.arange(4.0))
    np.testing.assert_array_equal(block.position_m, np.arange(4.0) * 10)
    for name in cams:
        np.testing.assert_array_equal(block.cameras[name].lines, lines[name])


def test_writer_copies_staged_blocks(run_path: Path) -> None:
    """A source may reuse its buffer after append (frame grabbers do)."""
    buffer = _good_lines(2)
    with _writer(run_path, chunk_scans=64) as w:
        w.append([0.0, 1.0], [0.0, 1.0], buffer)
        saved = {k: v.copy() for k, v in buffer.items()}
        for v in buffer.values():
            v[...] = 0
        w.append([2.0, 3.0], [2.0, 3.0], buffer)
    with open_run(run_path) as run:
        block = read_all(run)[0]
    for name in CAMERAS:
        np.testing.assert_array_equal(block.cameras[name].lines[:2], saved[name])
        assert not block.cameras[name].lines[2:].any()


def test_writer_flushes_staged_scans_to_the_file(run_path: Path) -> None:
    """What a power cut would leave: another process sees the flushed scans."""
    peek = (
        "import sys, h5py; f = h5py.File(sys.argv[1], 'r', locking=False); "
        "print(f['scans/position_m'].shape[0], f['cameras/b/lines'].shape[0])"
    )
    with _writer(run_path, chunk_scans=64, flush_interval_s=0.0) as w:
        w.append([0.0, 1.0], [0.0, 1.0], _good_lines(2))
        out = subprocess.run(
            [sys.executable, "-c", peek, str(run_path)], capture_output=True, text=True, check=True
        )
        assert out.stdout.split() == ["2", "2"]
        w.append([2.0], [2.0], _good_lines(1))
    with pytest.raises(ValueError, match="closed"):
        w.append([3.0], [3.0], _good_lines(1))


@pytest.mark.parametrize("series_chunk", [4, 9, 10, 1000])
def test_one_flagged_sample_faults_the_scans_that_depend_on_it(
    run_path: Path, series_chunk: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A recorder writes a flagged reading as NaN: even alone (a 2 ms interval, under the gap
    # factor) every scan between its valid neighbours must be flagged, across chunk bounds.
    monkeypatch.setattr("catenary.measurement.runfile.SERIES_CHUNK", series_chunk)
    with RunFileWriter(run_path, scan_rate_hz=2000.0, cameras={"a": (2, 8)}) as w:
        t_scan = np.arange(60) / 2000.0
        w.append(t_scan, t_scan, {"a": np.zeros((60, 2), np.uint8)})
        t = np.arange(32) / 1000.0
        left = t.copy()
        left[[9, 20, 21]] = np.nan
        w.append_vehicle(t, left, t, t)
    with open_run(run_path) as run:
        fault = np.concatenate([b.vehicle.fault for b in run.blocks(7)])
    expected = ((t_scan > 0.008 + 1e-12) & (t_scan < 0.010 - 1e-12)) | (
        (t_scan > 0.019 + 1e-12) & (t_scan < 0.022 - 1e-12)
    )
    np.testing.assert_array_equal(fault, expected)


# -- declared sizes ------------------------------------------------------------------------

HUGE = 10**12
"""Scans a forged file declares: streaming them would take days."""


def _forge_huge(run_path: Path) -> None:
    """A small run whose every scan dataset is resized to ``HUGE`` scans, marked complete:
    only its first chunks are written, the rest would read as fill values."""
    write_run(run_path, [40])
    with h5py.File(run_path, "r+") as f:
        for where in ("scans/position_m", "scans/time_s", "cameras/a/lines", "cameras/b/lines"):
            f[where].resize(HUGE, axis=0)
        f.attrs["completed_scans"] = HUGE


def test_a_declared_size_the_file_cannot_hold_is_refused(run_path: Path) -> None:
    _forge_huge(run_path)
    assert run_path.stat().st_size < 1 << 24  # 16 MiB, declaring 8 TB of positions alone
    with pytest.raises(FormatError) as info:
        open_run(run_path)
    message = str(info.value)
    assert "\n" not in message
    for needle in (str(run_path), "/scans/position_m", str(HUGE)):
        assert needle in message, (needle, message)


def test_a_contiguous_dataset_declaring_more_than_its_storage_is_refused(run_path: Path) -> None:
    write_run(run_path, [40])
    with h5py.File(run_path, "r+") as f:  # contiguous, allocated late: 0 bytes stored
        for name in ("time_s", "left_mm", "right_mm", "lateral_mm"):
            del f[f"vehicle/{name}"]
            f.create_dataset(f"vehicle/{name}", shape=(HUGE,), dtype=np.float64)
    with pytest.raises(FormatError, match=rf"/vehicle/time_s declares {HUGE} rows"):
        open_run(run_path)


def test_process_refuses_a_forged_size_in_one_line_at_once(run_path: Path) -> None:
    _forge_huge(run_path)
    command = [sys.executable, "-m", "catenary.cli", "process", str(run_path), "--rig", "x.toml"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    assert str(run_path) in lines[0] and "/scans/position_m" in lines[0]


def _damaged(path: Path, offset: int) -> Path:
    """A copy of ``path`` with the byte at ``offset`` inverted."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    copy = path.with_name(f"damaged-{offset}.h5")
    copy.write_bytes(data)
    return copy


def test_a_damaged_attribute_is_a_format_error_naming_it(run_path: Path) -> None:
    write_run(run_path, [10])
    name = run_path.read_bytes().index(b"scan_rate_hz\x00")
    damaged = _damaged(run_path, name + 16)  # the attribute's datatype, after its name
    with pytest.raises(FormatError, match="/ attribute scan_rate_hz cannot be read") as info:
        open_run(damaged)
    assert str(info.value).startswith(f"{damaged}: ") and "\n" not in str(info.value)


def test_an_attribute_holding_many_values_is_refused_unread(run_path: Path) -> None:
    write_run(run_path, [10])
    with h5py.File(run_path, "r+") as f:
        f.attrs["line"] = np.zeros(1000)
    with pytest.raises(FormatError, match="/ attribute line holds 1000 values, expected one"):
        open_run(run_path)


def test_a_root_group_damaged_past_what_opening_checks_is_a_format_error(run_path: Path) -> None:
    write_run(run_path, [10])
    # the root group's header lies near the start of the file, or continues near its end
    # where attributes were added last; HDF5 opens the file and fails only when the group is
    # read
    size = run_path.stat().st_size
    for offset in [*range(size - 1, size - 1024, -1), *range(4096)]:
        damaged = _damaged(run_path, offset)
        try:
            with h5py.File(damaged, "r") as f:
                f.attrs  # noqa: B018
        except KeyError:
            break
        except OSError:  # HDF5 does not open it at all
            pass
        damaged.unlink()
    else:
        pytest.fail("no byte near the file's ends holds the root group's header")
    with pytest.raises(FormatError, match="damaged HDF5 file") as info:
        open_run(damaged)
    assert str(info.value).startswith(f"{damaged}: ") and "\n" not in str(info.value)


def test_a_damaged_chunk_is_a_format_error_naming_the_dataset(run_path: Path) -> None:
    write_run(run_path, [40], compression="gzip")
    with h5py.File(run_path, "r") as f:
        chunk = f["cameras/b/lines"].id.get_chunk_info(1)
    damaged = _damaged(run_path, chunk.byte_offset + chunk.size // 2)
    with open_run(damaged) as run, pytest.raises(FormatError) as info:
        list(run.blocks(8))
    assert str(info.value).startswith(f"{damaged}: /cameras/b/lines[16:24] cannot be read (")
    assert "\n" not in str(info.value)


# -- regions of interest -------------------------------------------------------------------


def test_a_region_of_interest_is_written_and_read(run_path: Path) -> None:
    write_run(run_path, [12], offsets_px={"b": 700})
    with h5py.File(run_path, "r") as f:
        assert f["cameras/b"].attrs["offset_px"] == 700
        assert "offset_px" not in f["cameras/a"].attrs
    with open_run(run_path) as run:
        assert run.header.camera_offset_px == {"b": 700}
        block = read_all(run)[0]
    assert block.cameras["b"].offset_px == 700
    assert block.cameras["a"].offset_px == 0


@pytest.mark.parametrize(
    ("offsets", "needle"),
    [({"c": 3}, "unknown camera 'c'"), ({"a": -2}, "offset_px must be an integer >= 0, got -2")],
)
def test_the_writer_refuses_a_bad_offset(
    run_path: Path, offsets: dict[str, int], needle: str
) -> None:
    with pytest.raises(ValueError, match=needle):
        _writer(run_path, offsets_px=offsets)
    assert not run_path.exists()
