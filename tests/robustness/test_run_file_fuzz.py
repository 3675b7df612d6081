"""A fuzzer over the run file's layout (FORMATS.md "Recorded run: HDF5").

Each example writes a valid small run with ``RunFileWriter`` (the writer every recording source
uses), mutates it (attributes and datasets missing, extra or of the wrong type, shape or rank;
declared lengths against what is stored; NaN, infinities, negative and huge values; empty
datasets; a truncated file; bytes that are not HDF5), then opens it with the reader and reads
its first block. The file is either read or refused with a ``UserError`` whose message is one
line naming the file and, for a single mutation, the field; never another exception, never a
hang (an alarm bounds each example).
"""

from __future__ import annotations

import math
import signal
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

import h5py
import numpy as np
from hypothesis import event, given
from hypothesis import strategies as st

from catenary.errors import UserError
from catenary.measurement.runfile import RunFileWarning, RunFileWriter, open_run

from .conftest import assert_names_file, examples

EXAMPLE_TIME_LIMIT_S = 10
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
ROOT_ATTRS = (
    "format", "format_version", "line", "track", "vehicle", "direction", "start_chainage_m",
    "started_at", "scan_rate_hz", "completed_scans", "completed_at",
)  # fmt: skip
SERIES = (
    "/scans/position_m", "/scans/time_s", "/vehicle/time_s", "/vehicle/left_mm",
    "/vehicle/right_mm", "/vehicle/lateral_mm",
)  # fmt: skip
DATASETS = (*SERIES, "/cameras/a/lines", "/cameras/b/lines")
GROUPS = ("/scans", "/vehicle", "/cameras", "/cameras/a")
ODD_NUMBERS = (math.nan, math.inf, -math.inf, -1.0, -1e300, 1e300, 0.0, 2.0**63)


@dataclass(frozen=True, repr=False)
class Mutation:
    """One change to a valid file; ``field``: the HDF5 path or attribute a refusal must name
    (None: any, e.g. a change the reader may accept)."""

    what: str
    field: str | None
    apply: Callable[[h5py.File], None]

    def __repr__(self) -> str:  # what Hypothesis prints for a failing example
        return self.what


def _text() -> st.SearchStrategy[str]:
    return st.text(st.characters(exclude_categories=("Cs",)), max_size=12)


ATTR_VALUES: st.SearchStrategy[Any] = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(),
    st.sampled_from(ODD_NUMBERS),
    _text(),
    st.binary(max_size=12).map(np.bytes_),
    st.booleans(),
    st.lists(st.integers(-5, 5), min_size=0, max_size=3).map(np.array),
    st.sampled_from(("f8", "S1", "i4")).map(h5py.Empty),
)
DTYPES = ("f8", "f4", "i8", "i2", "u1", "u2", "u4", "S4", "?", "c16")


def _set_attr(where: str, name: str, value: Any) -> Callable[[h5py.File], None]:
    def apply(f: h5py.File) -> None:
        f[where].attrs[name] = value

    return apply


def _del_attr(where: str, name: str) -> Callable[[h5py.File], None]:
    def apply(f: h5py.File) -> None:
        if name in f[where].attrs:
            del f[where].attrs[name]

    return apply


def _delete(where: str) -> Callable[[h5py.File], None]:
    def apply(f: h5py.File) -> None:
        del f[where]

    return apply


def _replace(where: str, data: np.ndarray[Any, Any]) -> Callable[[h5py.File], None]:
    """Put ``data`` in place of ``where`` (its attributes kept)."""

    def apply(f: h5py.File) -> None:
        attrs = dict(f[where].attrs) if isinstance(f[where], h5py.Dataset) else {}
        del f[where]
        f[where] = data
        f[where].attrs.update(attrs)

    return apply


def _link(where: str, link: Any) -> Callable[[h5py.File], None]:
    """Put ``link`` (a soft or external link, maybe dangling) in place of ``where``."""

    def apply(f: h5py.File) -> None:
        del f[where]
        f[where] = link

    return apply


def _set_value(where: str, index: int, value: float) -> Callable[[h5py.File], None]:
    def apply(f: h5py.File) -> None:
        ds = f[where]
        if ds.ndim == 1 and ds.shape[0]:
            ds[index % ds.shape[0]] = value

    return apply


def _declare(where: str, rows: int) -> Callable[[h5py.File], None]:
    """Resize ``where`` to ``rows`` without writing them (a declared length)."""

    def apply(f: h5py.File) -> None:
        f[where].resize(rows, axis=0)

    return apply


@st.composite
def mutations(draw: st.DrawFn) -> Mutation:
    kind = draw(
        st.sampled_from(
            (
                "set attr", "del attr", "camera attr", "delete", "replace", "value", "declare",
                "extra", "link", "group as dataset",
            )
        )
    )  # fmt: skip
    if kind == "set attr":
        name, value = draw(st.sampled_from(ROOT_ATTRS)), draw(ATTR_VALUES)
        return Mutation(f"/ attr {name} = {value!r}", None, _set_attr("/", name, value))
    if kind == "del attr":
        name = draw(st.sampled_from(ROOT_ATTRS[:-2]))
        return Mutation(f"no / attr {name}", name, _del_attr("/", name))
    if kind == "camera attr":
        where = draw(st.sampled_from(("/cameras/a/lines", "/cameras/b/lines")))
        value = draw(st.one_of(st.none(), ATTR_VALUES))
        if value is None:
            return Mutation(f"no {where} bit_depth", "bit_depth", _del_attr(where, "bit_depth"))
        return Mutation(
            f"{where} bit_depth = {value!r}", None, _set_attr(where, "bit_depth", value)
        )
    if kind == "delete":
        where = draw(st.sampled_from((*DATASETS, *GROUPS)))
        return Mutation(f"no {where}", None, _delete(where))
    if kind == "replace":
        where = draw(st.sampled_from(DATASETS))
        dtype = draw(st.sampled_from(DTYPES))
        shape = draw(st.lists(st.integers(0, 6), min_size=0, max_size=3).map(tuple))
        data = np.zeros(shape, dtype=dtype)
        return Mutation(f"{where} = zeros({shape}, {dtype})", None, _replace(where, data))
    if kind == "value":
        where = draw(st.sampled_from(SERIES))
        index, value = draw(st.integers(0, 100)), draw(st.sampled_from(ODD_NUMBERS))
        return Mutation(f"{where}[{index}] = {value!r}", None, _set_value(where, index, value))
    if kind == "declare":
        where = draw(st.sampled_from(DATASETS))
        rows = draw(st.one_of(st.integers(0, 80), st.sampled_from((10**6, 10**12, 2**40))))
        return Mutation(f"{where} declares {rows} rows", None, _declare(where, rows))
    if kind == "extra":
        where = draw(st.sampled_from(("/", *GROUPS)))
        name = draw(st.text("abcxyz_", min_size=1, max_size=6))
        return Mutation(f"extra {where} {name}", None, _set_attr(where, name, 1.0))
    if kind == "link":
        where = draw(st.sampled_from((*DATASETS, *GROUPS)))
        link = draw(
            st.sampled_from(
                (
                    h5py.SoftLink("/nowhere"),
                    h5py.SoftLink(where),  # itself
                    h5py.SoftLink("/scans/time_s"),
                    h5py.ExternalLink("missing.h5", "/x"),
                )
            )
        )
        return Mutation(f"{where} -> {link!r}", None, _link(where, link))
    where = draw(st.sampled_from(GROUPS))
    return Mutation(f"{where} is a dataset", where, _replace(where, np.zeros(3)))


def write_valid(path: Path, scans: int, samples: int) -> None:
    """A valid run: two cameras (8 and 12 bits), ``scans`` scans, ``samples`` vehicle samples."""
    with RunFileWriter(
        path,
        line="L1",
        track="1",
        direction="increasing",
        scan_rate_hz=1000.0,
        cameras={"a": (8, 8), "b": (6, 12)},
        started_at="2024-05-01T10:00:00Z",
        chunk_scans=16,
    ) as writer:
        if scans:
            writer.append(
                np.arange(scans) * 0.01,
                np.arange(scans) / 1000.0,
                {
                    "a": np.full((scans, 8), 7, dtype=np.uint8),
                    "b": np.full((scans, 6), 900, dtype=np.uint16),
                },
            )
        t = np.arange(samples) / 500.0
        writer.append_vehicle(t, t + 1.0, t - 1.0, t * 0.5)


class _TooLong(Exception):
    pass


@contextmanager
def time_limit(seconds: int) -> Iterator[None]:
    """Raise ``_TooLong`` in this (main) thread if the block runs longer than ``seconds``."""

    def expire(signum: int, frame: FrameType | None) -> None:
        raise _TooLong(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def read_or_refuse(path: Path, field: str | None) -> None:
    """Open ``path`` and read its first block, or check the one-line refusal."""
    try:
        with time_limit(EXAMPLE_TIME_LIMIT_S), warnings.catch_warnings():
            warnings.simplefilter("ignore", RunFileWarning)
            with open_run(path) as run:
                next(run.blocks(64), None)
        event("read")
    except UserError as exc:
        event("refused")
        message = assert_names_file(exc, path)
        if field is not None:
            assert field in message, (field, message)


@examples(150)
@given(
    scans=st.integers(0, 40),
    samples=st.integers(0, 20),
    changes=st.lists(mutations(), min_size=1, max_size=3),
    truncate=st.one_of(st.none(), st.floats(0.0, 0.99)),
    garble=st.lists(
        st.tuples(st.integers(-8192, 8191), st.binary(min_size=1, max_size=8)), max_size=3
    ),
)
def test_a_mutated_run_file_is_read_or_refused_in_one_line(
    examples_folder: Path,
    scans: int,
    samples: int,
    changes: list[Mutation],
    truncate: float | None,
    garble: list[tuple[int, bytes]],
) -> None:
    path = examples_folder / "run.h5"
    path.unlink(missing_ok=True)
    write_valid(path, scans, samples)
    clean = True  # every change applied whole
    with h5py.File(path, "r+") as f:
        for change in changes:
            try:
                change.apply(f)
            except (KeyError, TypeError, ValueError, RuntimeError):  # e.g. in a deleted group
                clean = False  # maybe half done
    data = bytearray(path.read_bytes())
    for at, junk in garble:  # bytes overwritten in the metadata, at the start or the end
        at %= len(data)
        data[at : at + len(junk)] = junk
    if truncate is not None:
        del data[int(len(data) * truncate) :]
    path.write_bytes(data)
    single = len(changes) == 1 and clean and truncate is None and not garble
    read_or_refuse(path, changes[0].field if single else None)


@examples(30)
@given(content=st.binary(max_size=600).flatmap(lambda b: st.sampled_from((b, HDF5_SIGNATURE + b))))
def test_bytes_that_are_not_a_run_file_are_refused_in_one_line(
    examples_folder: Path, content: bytes
) -> None:
    path = examples_folder / "bytes.h5"
    path.write_bytes(content)
    read_or_refuse(path, None)
