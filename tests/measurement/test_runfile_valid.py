"""FORMATS.md's optional ``/cameras/{name}/valid`` and ``/encoder/*``, written and read."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from catenary.errors import FormatError
from catenary.measurement.runfile import SERIES_CHUNK, RunFileWriter, open_run

CAMERAS = {"a": (8, 8), "b": (8, 8)}


def lines(first: int, n: int) -> dict[str, np.ndarray]:
    rows = (np.arange(first, first + n)[:, None] + np.arange(8)[None, :]) % 251
    return {"a": rows.astype(np.uint8), "b": (rows + 1).astype(np.uint8)}


def write(path: Path, valid_b: np.ndarray | None, sizes: list[int]) -> None:
    """Scans in appends of ``sizes``; camera ``b``'s flags from ``valid_b`` (None: none
    given), camera ``a`` never flagged (its flags given as all true in the odd appends)."""
    with RunFileWriter(path, scan_rate_hz=100.0, cameras=CAMERAS) as w:  # appends staged
        first = 0
        for k, n in enumerate(sizes):
            index = np.arange(first, first + n, dtype=np.float64)
            flags: dict[str, np.ndarray | None] = {}
            if valid_b is not None:
                flags["b"] = valid_b[first : first + n]
            if k % 2:
                flags["a"] = np.ones(n, dtype=bool)
            w.append(index * 0.01, index / 100.0, lines(first, n), flags)
            first += n
        assert w.invalid_lines == {
            "a": 0,
            "b": 0 if valid_b is None else int(np.count_nonzero(~valid_b)),
        }


def read_valid(path: Path, block_scans: int) -> dict[str, list[np.ndarray | None]]:
    with open_run(path) as run:
        blocks = list(run.blocks(block_scans))
    return {name: [b.cameras[name].valid for b in blocks] for name in CAMERAS}


@pytest.mark.parametrize("sizes", [[5, 3, 40, 1, 11], [60]])
def test_the_dataset_appears_at_the_first_invalid_line(tmp_path: Path, sizes: list[int]) -> None:
    path = tmp_path / "run.h5"
    valid = np.ones(60, dtype=bool)
    valid[[9, 10, 11, 47]] = False  # the earlier rows staged when the dataset appears
    write(path, valid, sizes)
    with h5py.File(path) as f:
        assert "valid" not in f["cameras/a"]  # all valid: no dataset
        ds = f["cameras/b/valid"]
        assert ds.dtype == np.bool_ and ds.chunks == (SERIES_CHUNK,) and ds.maxshape == (None,)
        np.testing.assert_array_equal(ds[:], valid)
    read = read_valid(path, 7)
    assert all(v is None for v in read["a"])
    np.testing.assert_array_equal(np.concatenate(read["b"]), valid)
    assert [v.shape for v in read["b"]] == [(7,)] * 8 + [(4,)]
    with open_run(path) as run:  # the workers' way, and the image evidence's
        np.testing.assert_array_equal(run.camera_lines(40, 50)["b"].valid, valid[40:50])
        np.testing.assert_array_equal(run.image_block(5, 12).cameras["b"].valid, valid[5:12])


def test_all_valid_flags_or_none_write_no_dataset(tmp_path: Path) -> None:
    for valid in (None, np.ones(20, dtype=bool)):
        path = tmp_path / f"run-{valid is None}.h5"
        write(path, valid, [10, 10])
        with h5py.File(path) as f:
            assert "valid" not in f["cameras/b"]
        assert all(v is None for v in read_valid(path, 10)["b"])  # every line valid


def test_the_writer_refuses_bad_flags(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with RunFileWriter(path, scan_rate_hz=100.0, cameras=CAMERAS) as w:
        t = np.arange(4) / 100.0
        with pytest.raises(ValueError, match=r"run.h5: append: valid of camera 'b' is bool \(3,\)"):
            w.append(t, t, lines(0, 4), {"b": np.ones(3, dtype=bool)})
        with pytest.raises(ValueError, match=r"valid of camera 'a' is int64 \(4,\), expected bool"):
            w.append(t, t, lines(0, 4), {"a": np.ones(4, dtype=np.int64)})
        with pytest.raises(ValueError, match=r"append: valid of unknown camera 'c'"):
            w.append(t, t, lines(0, 4), {"c": np.ones(4, dtype=bool)})
        assert w.scans == 0


def _valid_as(path: Path, data: np.ndarray) -> None:
    with h5py.File(path, "a") as f:
        del f["cameras/b/valid"]
        f["cameras/b/valid"] = data


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (np.ones((20, 2), dtype=bool), r"/cameras/b/valid has shape \(20, 2\), expected 1-D \[N\]"),
        (np.ones(20, dtype=np.float64), r"/cameras/b/valid has dtype float64, expected bool"),
        (np.ones(20, dtype=np.uint8), r"/cameras/b/valid has dtype uint8, expected bool"),
        (
            np.ones(12, dtype=bool),
            r"/cameras/b/valid has 12 scans but the file is marked complete with "
            r"completed_scans = 20",
        ),
    ],
)
def test_the_reader_refuses_a_wrong_dataset(tmp_path: Path, data: np.ndarray, message: str) -> None:
    path = tmp_path / "run.h5"
    valid = np.ones(20, dtype=bool)
    valid[3] = False
    write(path, valid, [20])
    _valid_as(path, data)
    with pytest.raises(FormatError, match=message) as raised:
        open_run(path)
    assert str(path) in str(raised.value) and "\n" not in str(raised.value)


def test_encoder_readings_are_appended(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    with RunFileWriter(path, scan_rate_hz=100.0, cameras=CAMERAS) as w:
        w.append_encoder(np.zeros(0), np.zeros(0))  # the datasets, empty
        w.append_encoder([0.0, 0.005], [0.0, 0.05])
        w.append_encoder(np.array([0.01]), np.array([0.11]))
        with pytest.raises(ValueError, match=r"encoder time_s decreases at 3: 0.01 -> 0.0"):
            w.append_encoder([0.0], [0.2])
        with pytest.raises(ValueError, match=r"position_m\[3\] is nan, not finite"):
            w.append_encoder([0.02], [np.nan])
        with pytest.raises(ValueError, match=r"one length"):
            w.append_encoder([0.02, 0.03], [0.2])
        assert w.encoder_readings == 3
        w.append(np.zeros(1), np.zeros(1), lines(0, 1))
    with h5py.File(path) as f:
        np.testing.assert_array_equal(f["encoder/time_s"][:], [0.0, 0.005, 0.01])
        np.testing.assert_array_equal(f["encoder/position_m"][:], [0.0, 0.05, 0.11])
        assert f["encoder/time_s"].dtype == np.float64
    with open_run(path) as run:  # a reader that does not use them reads the run as before
        assert run.header.scans == 1


def test_the_recorded_source_replays_the_flags(tmp_path: Path) -> None:
    """``catenary record --source recorded``: the flags go through the recorder unchanged."""
    from catenary.measurement.recording import record_run
    from catenary_recorded import open_recorded

    source = tmp_path / "run.h5"
    valid = np.ones(30, dtype=bool)
    valid[[0, 17, 18]] = False
    write(source, valid, [30])
    copy = tmp_path / "copy.h5"
    with open_recorded({"path": str(source)}) as stream:
        result = record_run(copy, stream, block_scans=8)
    assert result.invalid_lines == {"a": 0, "b": 3}
    read = read_valid(copy, 30)
    assert read["a"] == [None]
    np.testing.assert_array_equal(read["b"][0], valid)
