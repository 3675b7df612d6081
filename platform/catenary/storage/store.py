"""The store of bulk data (samples files): a local folder or an S3-compatible object store.

Objects are addressed by keys: '/'-separated relative names (``samples_key``), the same on
every machine, so the database refers to a file by its key and any machine that reaches the
store reads it. Every write is checked by reading the object back (size and SHA-256) and is
atomic: a reader sees the whole object or none (a local file is written under a hidden name
and renamed; an S3 upload is completed in one request). Large files (run files) are put in
parts that a put cut short resumes (``Store.put_parts``). Errors are ``StoreError``: one line
naming the store's URL and the key.
"""

from __future__ import annotations

import base64
import fcntl
import hashlib
import hmac
import http.client
import io
import math
import os
import ssl
import time
import uuid
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO
from urllib.parse import quote, urlsplit
from xml.etree import ElementTree

import pyarrow as pa
import pyarrow.fs as pafs

if TYPE_CHECKING:
    import pyarrow.dataset as ds

from catenary.config import (
    DEFAULT_PART_MB,
    FolderStoreSettings,
    S3StoreSettings,
    Settings,
    store_settings,
)
from catenary.errors import UserError

#: The first part of the keys of samples files.
SAMPLES_PREFIX = "samples"
#: The first part of the keys of envelope files (``envelope_key``): apart from the samples,
#: so that the fleet's samples dataset never reads them.
ENVELOPES_PREFIX = "envelopes"
#: Bytes read or written at a time: memory stays flat whatever the file's size.
CHUNK_BYTES = 8 * 1024 * 1024
#: S3: how long connecting may take, in seconds (a refused connection fails at once).
CONNECT_TIMEOUT_S = 3.0
#: S3: how long a request may wait for the server's bytes, in seconds (the AWS SDK applies it
#: on Windows and macOS only; the store's own DeleteObject request everywhere).
REQUEST_TIMEOUT_S = 60.0
#: S3: attempts of a request before its error is reported (the first included).
MAX_ATTEMPTS = 3
#: S3: seconds before the second attempt of a request of the store's own (twice that before
#: the third).
RETRY_DELAY_S = 0.5
#: S3: the refusals that a request sent again may not meet (busy, timed out, or corrupted on
#: the way: the MD5 or SHA-256 of what arrived is not the one sent).
TRANSIENT_CODES = frozenset(
    {"BadDigest", "RequestTimeout", "SlowDown", "XAmzContentSHA256Mismatch"}
)
#: S3: the most parts an upload may have; a file that needs more at the configured part size
#: is sent in larger parts.
MAX_PARTS = 10_000
#: S3: the ``x-amz-content-sha256`` of a request whose body is not part of its signature.
UNSIGNED = "UNSIGNED-PAYLOAD"
#: The XML namespace of S3's requests and answers.
S3_XMLNS = "http://s3.amazonaws.com/doc/2006-03-01/"
#: Without these, the AWS SDK of current pyarrow sends checksums that S3-compatible services
#: refuse (HTTP 411 on multipart uploads) and checks them on ranged reads (a checksum error).
AWS_CHECKSUM_ENVIRONMENT = {
    "AWS_REQUEST_CHECKSUM_CALCULATION": "when_required",
    "AWS_RESPONSE_CHECKSUM_VALIDATION": "when_required",
}


class StoreError(UserError):
    """The store cannot be reached, or an object is missing, unreadable or corrupt."""


class ContentMismatch(StoreError):
    """A file put in the store is not the content it was expected to be (its SHA-256)."""


@dataclass(frozen=True)
class Part:
    """A part of a file put in parts (``Store.put_parts``): its number (from 1), its size in
    bytes, and whether it was sent now (False: in place from an earlier put cut short, and
    found the same as the file's)."""

    number: int
    size_bytes: int
    sent: bool


def part_size(size_bytes: int, part_bytes: int) -> int:
    """The size of the parts a file of ``size_bytes`` is put in: ``part_bytes``, or the
    multiple of 1 MiB that keeps it within ``MAX_PARTS`` parts."""
    needed = math.ceil(size_bytes / MAX_PARTS / (1 << 20)) << 20
    return max(part_bytes, needed)


@dataclass(frozen=True)
class StoredObject:
    """An object written to the store: its key, size in bytes and SHA-256 (hex)."""

    key: str
    size_bytes: int
    sha256: str


def check_key(key: str) -> str:
    """``key`` if it is a store key: '/'-separated non-empty parts, none starting with '.'
    (no '..', no hidden names), no leading '/', no backslash or control character; else
    ``ValueError``."""
    parts = key.split("/")
    if (
        not key
        or any(not part or part.startswith(".") for part in parts)
        or "\\" in key
        or any(ord(char) < 32 or ord(char) == 127 for char in key)
    ):
        raise ValueError(f"not a store key: {key!r}")
    return key


def samples_key(line: str, track: str, run: str, name: str) -> str:
    """``samples/line=LINE/track=TRACK/run=RUN/NAME.parquet``: the samples file ``NAME`` (a
    processing's UUID) of the run whose UUID is ``RUN``, the line and track percent-encoded
    (any text is safe; ``pyarrow.dataset``'s hive partitioning decodes them)."""
    if not line or not track or not run:
        raise ValueError(
            f"samples key needs a line, track and run, not {line!r}, {track!r}, {run!r}"
        )
    if "/" in name or "/" in run:
        raise ValueError(f"samples file name {name!r} or run {run!r} holds '/'")
    parts = (f"line={quote(line, safe='')}", f"track={quote(track, safe='')}", f"run={run}")
    return check_key(f"{SAMPLES_PREFIX}/{'/'.join(parts)}/{name}.parquet")


def envelope_key(samples: str) -> str:
    """The key of the envelope file of the samples file at key ``samples``: the same key under
    ``ENVELOPES_PREFIX`` instead of ``SAMPLES_PREFIX`` (``envelopes/line=LINE/track=TRACK/
    run=RUN/NAME.parquet``); ``ValueError`` if ``samples`` is not a store key."""
    rest = check_key(samples).removeprefix(f"{SAMPLES_PREFIX}/")
    return check_key(f"{ENVELOPES_PREFIX}/{rest}")


PARTITION_COLUMNS = ("line", "track", "run")
"""The columns a samples file's key gives it in the fleet's dataset (``samples_key``)."""


def samples_partitioning() -> ds.Partitioning:
    """The hive partitioning of samples keys: ``line``, ``track`` and ``run`` (the run's
    UUID) as (decoded) strings."""
    import pyarrow.dataset as ds  # here: it imports pandas, which ``process`` never needs

    schema = pa.schema([(name, pa.string()) for name in PARTITION_COLUMNS])
    return ds.partitioning(schema, flavor="hive")


def _parts(source: BinaryIO, count: int, part_bytes: int) -> Iterator[bytes]:
    """The next ``count`` parts of ``part_bytes`` of ``source`` (the last may be smaller)."""
    for _ in range(count):
        yield source.read(part_bytes)


def _held_alike(
    source: BinaryIO,
    part_bytes: int,
    count: int,
    held: Mapping[int, tuple[int, str]],
    digest: hashlib._Hash,
) -> list[str] | None:
    """The MD5s (hex) of the first parts of the file ``source`` (``count`` parts in all) when
    the parts an upload holds (``held``: size and ETag by number) are exactly those, each the
    same as the file's (their bytes then added to ``digest``); else None."""
    if sorted(held) != list(range(1, len(held) + 1)) or len(held) > count:
        return None
    md5s = []
    for number, data in enumerate(_parts(source, len(held), part_bytes), start=1):
        md5s.append(hashlib.md5(data, usedforsecurity=False).hexdigest())  # a part's ETag
        if held[number] != (len(data), md5s[-1]):
            return None
        digest.update(data)
    return md5s


def _reason(exc: BaseException) -> str:
    """An exception's message on one line."""
    return " ".join(str(exc).split()) or type(exc).__name__


class Store:
    """Objects under one folder or bucket prefix (``open_store``).

    ``filesystem`` is a ``pyarrow.fs`` filesystem rooted at the store: a key is its path
    there (``pyarrow.dataset.dataset(keys, filesystem=store.filesystem, ...)``).
    """

    def __init__(
        self,
        filesystem: pafs.FileSystem,
        url: str,
        *,
        folder: Path | None = None,
        s3: S3Objects | None = None,
        part_bytes: int = DEFAULT_PART_MB << 20,
    ) -> None:
        """``filesystem`` rooted at the store; ``folder`` for a local store, ``s3`` for an S3
        store whose keys are known (its objects are deleted and put in parts through it);
        ``part_bytes``: the size of the parts of ``put_parts``."""
        self.filesystem = filesystem
        self.url = url
        self.part_bytes = part_bytes
        self._folder = folder
        self._s3 = s3

    def __repr__(self) -> str:
        return f"Store({self.url!r})"

    def describe(self, key: str) -> str:
        """``URL/KEY``, for messages."""
        return f"{self.url.rstrip('/')}/{key}"

    @contextmanager
    def _errors(self, action: str, key: str) -> Iterator[None]:
        """Turn the filesystem's errors into a ``StoreError`` naming the action and key."""
        try:
            yield
        except FileNotFoundError:
            raise StoreError(f"{self.describe(key)}: no such object") from None
        except OSError as exc:
            raise StoreError(f"{self.describe(key)}: cannot {action}: {_reason(exc)}") from None

    def put_file(self, local_path: Path, key: str) -> StoredObject:
        """Copy the file ``local_path`` to ``key`` (replacing any object there), read it back
        and check its size and SHA-256. On failure no partial object is left at ``key`` (on S3,
        an object it was replacing may be gone too)."""
        check_key(key)
        try:
            source = local_path.open("rb")
        except OSError as exc:
            raise UserError(f"{local_path}: cannot read: {exc.strerror}") from None
        with source:
            return self._put(source, key, str(local_path))

    def put_bytes(self, data: bytes, key: str) -> StoredObject:
        """``put_file`` of a small object held in memory."""
        check_key(key)
        return self._put(io.BytesIO(data), key, "what was written")

    def _put(self, source: BinaryIO, key: str, what: str) -> StoredObject:
        """Write ``source`` to ``key`` (atomic), read it back and check it against ``what``."""
        if self._folder is not None:
            written = self._write_local(source, self._folder, key)
        else:
            try:
                written = self._upload(source, key)
            except BaseException:
                # closing the stream completed the upload with what it had been given
                self._discard(key)
                raise
        return self._read_back(written, what)

    def _read_back(self, written: StoredObject, what: str) -> StoredObject:
        """``written`` once the object is read back whole and found as written (else it is
        deleted: ``StoreError``)."""
        if not self.verify(written.key, written.size_bytes, written.sha256):
            self._discard(written.key)
            raise StoreError(
                f"{self.describe(written.key)}: the object read back differs from {what}"
            )
        return written

    def put_parts(
        self,
        local_path: Path,
        key: str,
        *,
        sha256: str | None = None,
        on_part: Callable[[Part], None] = lambda part: None,
    ) -> StoredObject:
        """``put_file`` of a large file, in parts (``part_size``), resuming a put of it to
        ``key`` that was cut short (interrupted, the link lost, the process killed): the parts
        in place that are found the same as the file's are not sent again.

        On S3, an upload in parts: the service checks each part's MD5 (``Content-MD5``), and
        on resuming, the parts it lists are checked against the file's (size, and MD5 as their
        ETag); in a folder, a hidden ``.NAME.part`` file beside the key's, kept as far as it
        equals the file, then renamed. ``on_part`` is told of each part in turn. With
        ``sha256``, a file of another content is a ``ContentMismatch`` and nothing is stored.
        Then the object is read back whole and checked as by ``put_file``. A put cut short
        keeps what it sent, for the next to resume; a refusal of the service aborts the
        upload. An S3 store without requests of its own (``open_store``: AWS with the SDK's
        own credentials) puts the file in one stream, which does not resume.
        """
        check_key(key)
        try:
            source = local_path.open("rb")
        except OSError as exc:
            raise UserError(f"{local_path}: cannot read: {exc.strerror}") from None

        def expect(digest: str) -> None:
            if sha256 is not None and digest != sha256.lower():
                raise ContentMismatch(
                    f"{local_path}: its SHA-256 is {digest}, not {sha256.lower()} (nothing stored)"
                )

        with source:
            size = os.fstat(source.fileno()).st_size
            part_bytes = part_size(size, self.part_bytes)
            count = max(1, math.ceil(size / part_bytes))  # one empty part for an empty file
            if self._folder is not None:
                parts = _parts(source, count, part_bytes)
                written = self._write_local_parts(parts, self._folder, key, on_part, expect)
            elif self._s3 is not None:
                written = self._upload_parts(
                    source, count, part_bytes, self._s3, key, on_part, expect
                )
            else:
                written = self._put(source, key, str(local_path))
                try:
                    expect(written.sha256)
                except ContentMismatch:
                    self.delete(key)
                    raise
                return written
        return self._read_back(written, str(local_path))

    def _upload_parts(
        self,
        source: BinaryIO,
        count: int,
        part_bytes: int,
        s3: S3Objects,
        key: str,
        on_part: Callable[[Part], None],
        expect: Callable[[str], None],
    ) -> StoredObject:
        """``put_parts`` on S3 of the ``count`` parts of ``source``: the upload to ``key``
        begun earlier goes on if the parts it holds are the file's first, each alike, else a
        new one is begun (the earlier aborted: a service may refuse to replace a part); the
        missing parts are sent, then the upload completed. An upload the service drops
        meanwhile (``rclone serve s3`` drops one whose part arrived corrupted, and may answer
        the part sent again by closing the connection) is begun anew, once."""
        digest = hashlib.sha256()
        with self._errors("write", key):
            upload = s3.pending_upload(key)
            held = {} if upload is None else s3.uploaded_parts(key, upload)
            etags = _held_alike(source, part_bytes, count, held, digest)
            if upload is not None and etags is None:
                s3.abort_upload(key, upload)
        for attempt in (1, 2):
            if upload is None or etags is None:
                with self._errors("write", key):
                    upload, etags = s3.begin_upload(key), []
                source.seek(0)
                digest = hashlib.sha256()
            try:
                size = self._send_parts(
                    source, count, part_bytes, s3, key, upload, etags, digest, on_part
                )
                expect(digest.hexdigest())
                s3.complete_upload(key, upload, etags)
                return StoredObject(key, size, digest.hexdigest())
            except ContentMismatch:
                with suppress(OSError):
                    s3.abort_upload(key, upload)
                raise
            except OSError as exc:
                if attempt == 1 and s3.dropped(key, upload):
                    etags = None
                    continue
                if isinstance(exc, S3Refused):
                    with suppress(OSError):
                        s3.abort_upload(key, upload)
                    raise StoreError(
                        f"{self.describe(key)}: cannot write: {_reason(exc)} (its upload aborted)"
                    ) from None
                raise StoreError(
                    f"{self.describe(key)}: cannot write: {_reason(exc)} (the parts sent are "
                    "kept: putting it again resumes)"
                ) from None
        raise AssertionError("unreachable")

    @staticmethod
    def _send_parts(
        source: BinaryIO,
        count: int,
        part_bytes: int,
        s3: S3Objects,
        key: str,
        upload: str,
        etags: list[str],
        digest: hashlib._Hash,
        on_part: Callable[[Part], None],
    ) -> int:
        """The parts of ``source`` after the ``etags`` held (which ``digest`` has read; the
        file is read on from there) sent to ``upload``, their ETags added to ``etags``, their
        bytes to ``digest``; ``on_part`` told of every part. The file's size in bytes."""
        size = source.tell()
        for number in range(1, len(etags) + 1):
            on_part(Part(number, min(part_bytes, size - (number - 1) * part_bytes), sent=False))
        for number, data in enumerate(
            _parts(source, count - len(etags), part_bytes), start=len(etags) + 1
        ):
            digest.update(data)
            size += len(data)
            md5 = hashlib.md5(data, usedforsecurity=False).digest()
            etags.append(s3.upload_part(key, upload, number, data, md5))
            on_part(Part(number, len(data), sent=True))
        return size

    def _write_local_parts(
        self,
        parts: Iterator[bytes],
        folder: Path,
        key: str,
        on_part: Callable[[Part], None],
        expect: Callable[[str], None],
    ) -> StoredObject:
        """``put_parts`` in a folder: the parts written to ``.NAME.part`` beside ``key``'s file
        from the first that differs from what it holds, flushed to disk, then renamed."""
        path = folder / key
        partial = path.with_name(f".{path.name}.part")
        digest, size = hashlib.sha256(), 0
        with self._errors("write", key):
            path.parent.mkdir(parents=True, exist_ok=True)
            with partial.open("a+b") as out:  # appended at its end, wherever it is read
                try:
                    fcntl.flock(out.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    raise StoreError(
                        f"{self.describe(key)}: another put of it is under way ({partial})"
                    ) from None
                out.seek(0)
                same = True
                for number, data in enumerate(parts, start=1):
                    digest.update(data)
                    if same and out.read(len(data)) != data:
                        same = False
                        out.truncate(size)  # this part and all after it written anew
                    if not same:
                        out.write(data)
                    size += len(data)
                    on_part(Part(number, len(data), sent=not same))
                out.truncate(size)  # what an earlier, longer file left beyond
                out.flush()
                os.fsync(out.fileno())
                try:
                    expect(digest.hexdigest())
                except ContentMismatch:
                    partial.unlink()
                    raise
            os.replace(partial, path)
        return StoredObject(key, size, digest.hexdigest())

    def _upload(self, source: BinaryIO, key: str) -> StoredObject:
        """Stream ``source`` to ``key`` through the filesystem (an S3 upload is atomic)."""
        digest, size = hashlib.sha256(), 0
        with self._errors("write", key), self.filesystem.open_output_stream(key) as out:
            while chunk := source.read(CHUNK_BYTES):
                digest.update(chunk)
                out.write(chunk)
                size += len(chunk)
        return StoredObject(key, size, digest.hexdigest())

    def _write_local(self, source: BinaryIO, folder: Path, key: str) -> StoredObject:
        """Write ``source`` to a hidden file beside ``key``'s, flushed to disk, then rename it."""
        path = folder / key
        digest, size = hashlib.sha256(), 0
        temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex}.part")
        with self._errors("write", key):
            path.parent.mkdir(parents=True, exist_ok=True)
            try:
                with temporary.open("wb") as out:
                    while chunk := source.read(CHUNK_BYTES):
                        digest.update(chunk)
                        out.write(chunk)
                        size += len(chunk)
                    out.flush()
                    os.fsync(out.fileno())
                os.replace(temporary, path)
            finally:
                temporary.unlink(missing_ok=True)
        return StoredObject(key, size, digest.hexdigest())

    def _discard(self, key: str) -> None:
        """Delete ``key`` after a failed write, if the store lets us (it may be unreachable)."""
        with suppress(OSError):
            self._delete(key)

    def _delete(self, key: str) -> None:
        """Delete ``key`` (missing: nothing to do), raising ``OSError``."""
        if self._s3 is not None:
            self._s3.delete(key)
            return
        with suppress(FileNotFoundError):
            self.filesystem.delete_file(key)
        if self._folder is not None:  # folders emptied go too, as on S3, but the top one
            parent = (self._folder / key).parent
            while parent.parent != self._folder and parent != self._folder:
                try:
                    parent.rmdir()
                except OSError:  # not empty, or already gone
                    break
                parent = parent.parent

    def digest(self, key: str) -> StoredObject:
        """Read ``key`` whole (streamed) and give its size and SHA-256."""
        check_key(key)
        digest, size = hashlib.sha256(), 0
        with self._errors("read", key), self.filesystem.open_input_stream(key) as stream:
            while chunk := stream.read(CHUNK_BYTES):
                digest.update(chunk)
                size += len(chunk)
        return StoredObject(key, size, digest.hexdigest())

    def verify(self, key: str, size_bytes: int, sha256: str) -> bool:
        """Whether ``key`` holds ``size_bytes`` bytes of SHA-256 ``sha256`` (read back whole;
        a missing object is False; an unreachable store raises ``StoreError``)."""
        if not self.exists(key) or self.size(key) != size_bytes:
            return False
        return self.digest(key) == StoredObject(key, size_bytes, sha256.lower())

    def check(self, key: str, size_bytes: int, sha256: str) -> None:
        """``verify``, raising ``StoreError`` naming the key when the object is not as given."""
        if not self.verify(key, size_bytes, sha256):
            raise StoreError(
                f"{self.describe(key)}: missing or corrupt (expected {size_bytes} bytes, "
                f"SHA-256 {sha256})"
            )

    def local_path(self, key: str) -> Path | None:
        """The file of ``key`` on this machine when the store is a folder, else None."""
        check_key(key)
        return None if self._folder is None else self._folder / key

    @contextmanager
    def readable(self, key: str, scratch: Path) -> Iterator[Path]:
        """``key`` as a local file: the store's own in a folder, else a copy in the folder
        ``scratch`` (streamed in ``CHUNK_BYTES`` pieces), removed on exit."""
        path = self.local_path(key)
        if path is not None:
            yield path
            return
        copy = scratch / Path(key).name
        with self.open_input(key) as source, copy.open("wb") as target:
            while chunk := source.read(CHUNK_BYTES):
                target.write(chunk)
        try:
            yield copy
        finally:
            copy.unlink(missing_ok=True)

    def open_input(self, key: str) -> pa.NativeFile:
        """``key`` as a random-access file (``pyarrow.parquet.ParquetFile(...)`` reads it);
        errors once open are the filesystem's ``OSError``."""
        check_key(key)
        with self._errors("open", key):
            return self.filesystem.open_input_file(key)

    def _info(self, key: str) -> pafs.FileInfo:
        check_key(key)
        with self._errors("look up", key):
            return self.filesystem.get_file_info(key)

    def exists(self, key: str) -> bool:
        """Whether an object is stored at ``key``."""
        return bool(self._info(key).type == pafs.FileType.File)

    def size(self, key: str) -> int:
        """The size of the object at ``key``, in bytes."""
        info = self._info(key)
        if info.type != pafs.FileType.File:
            raise StoreError(f"{self.describe(key)}: no such object")
        return int(info.size)

    def delete(self, key: str) -> None:
        """Delete the object at ``key``; a missing object is not an error."""
        check_key(key)
        with self._errors("delete", key):
            self._delete(key)

    def keys(self, prefix: str = "") -> list[str]:
        """The keys of the objects under the folder ``prefix`` ('' for all), sorted."""
        if prefix:
            check_key(prefix)
        selector = pafs.FileSelector(prefix, recursive=True, allow_not_found=True)
        with self._errors("list", prefix or "/"):
            infos = self.filesystem.get_file_info(selector)
        found = (
            info.path.lstrip("/")
            for info in infos
            if info.type == pafs.FileType.File and not info.base_name.startswith(".")
        )
        return sorted(found)

    def dataset(self, keys: Sequence[str]) -> ds.Dataset:
        """The samples files ``keys`` as one Parquet dataset with ``line``, ``track`` and
        ``run`` columns from their keys (filters on any column are pushed down to the files)."""
        import pyarrow.dataset as ds

        for key in keys:
            check_key(key)
        with self._errors("open as a dataset", keys[0] if keys else ""):
            return ds.dataset(
                list(keys),
                filesystem=self.filesystem,
                format="parquet",
                partitioning=samples_partitioning(),
            )


class S3Refused(OSError):
    """An S3 request answered with an error: its HTTP status and S3 error code (``code``)."""

    def __init__(self, action: str, status: int, code: str, message: str) -> None:
        super().__init__(f"{action} answered HTTP {status} {code}: {message}".rstrip(": "))
        self.status = status
        self.code = code

    @property
    def transient(self) -> bool:
        """Whether the same request may succeed if sent again (the service was busy or
        failing, or the bytes were corrupted on the way: ``BadDigest``)."""
        return self.status >= 500 or self.code in TRANSIENT_CODES


def _local_name(tag: str) -> str:
    """An XML tag without its namespace."""
    return tag.rpartition("}")[2]


def _xml(answer: bytes) -> ElementTree.Element | None:
    """The root element of an XML answer, or None for an empty or non-XML one."""
    if not answer.strip():
        return None
    try:
        return ElementTree.fromstring(answer)
    except ElementTree.ParseError:
        return None


def _children(element: ElementTree.Element, name: str) -> list[ElementTree.Element]:
    return [child for child in element if _local_name(child.tag) == name]


def _text(element: ElementTree.Element, name: str) -> str:
    """The text of ``element``'s child ``name`` ('' if it has none)."""
    found = _children(element, name)
    return (found[0].text or "") if found else ""


def _refusal(action: str, status: int, answer: bytes, ok: Collection[int]) -> S3Refused | None:
    """The error an answer is (an error status, or an ``<Error>`` in a 200 answer), if any."""
    root = _xml(answer)
    if status in ok and (root is None or _local_name(root.tag) != "Error"):
        return None
    code, message = (
        ("", answer[:300].decode(errors="replace"))
        if root is None
        else (_text(root, "Code"), _text(root, "Message"))
    )
    return S3Refused(action, status, code, " ".join(message.split()))


@dataclass(frozen=True)
class S3Objects:
    """Requests of its own to the service at ``endpoint`` for objects under ``base``
    (``BUCKET/PREFIX``), signed with AWS Signature Version 4 (path-style).

    DeleteObject: pyarrow's ``delete_file`` then writes an empty marker object ``FOLDER/`` for
    the key's folder; an S3 service on a file system (``rclone serve s3``) cannot keep it
    beside the folder's objects and from then on lists the folder as an empty file, hiding
    them. Uploads in parts (``Store.put_parts``): pyarrow neither resumes them nor lists them.
    """

    endpoint: str
    base: str
    region: str
    access_key: str
    secret_key: str = field(repr=False)

    def _path(self, key: str) -> str:
        return "/" + quote(f"{self.base}/{key}", safe="/-_.~")

    def _send(
        self, method: str, path: str, query: Mapping[str, str], body: bytes,
        headers: Mapping[str, str],
    ) -> tuple[int, http.client.HTTPMessage, bytes]:  # fmt: skip
        """One signed request: its answer's status, headers and body; ``OSError`` when the
        service cannot be reached or the connection fails. The body's SHA-256 is signed
        unless ``headers`` give ``x-amz-content-sha256`` (``UNSIGNED``: another check)."""
        endpoint = urlsplit(self.endpoint)
        query_text = "&".join(
            f"{quote(name, safe='-_.~')}={quote(value, safe='-_.~')}"
            for name, value in sorted(query.items())
        )
        now = datetime.now(UTC)
        amz_date, day = now.strftime("%Y%m%dT%H%M%SZ"), now.strftime("%Y%m%d")
        signing_headers = {name.lower(): value for name, value in headers.items()}
        payload = signing_headers.get("x-amz-content-sha256") or hashlib.sha256(body).hexdigest()
        signing_headers |= {
            "host": endpoint.netloc,
            "x-amz-content-sha256": payload,
            "x-amz-date": amz_date,
        }
        names = sorted(signing_headers)
        signed = ";".join(names)
        canonical = "\n".join(
            [method, path, query_text, *(f"{k}:{signing_headers[k]}" for k in names), "", signed,
             payload]
        )  # fmt: skip
        scope = f"{day}/{self.region}/s3/aws4_request"
        to_sign = "\n".join(
            ["AWS4-HMAC-SHA256", amz_date, scope, hashlib.sha256(canonical.encode()).hexdigest()]
        )
        signing = f"AWS4{self.secret_key}".encode()
        for part in (day, self.region, "s3", "aws4_request"):
            signing = hmac.new(signing, part.encode(), hashlib.sha256).digest()
        signature = hmac.new(signing, to_sign.encode(), hashlib.sha256).hexdigest()
        signing_headers["authorization"] = (
            f"AWS4-HMAC-SHA256 Credential={self.access_key}/{scope}, "
            f"SignedHeaders={signed}, Signature={signature}"
        )
        connection = (
            http.client.HTTPSConnection(
                endpoint.netloc,
                timeout=REQUEST_TIMEOUT_S,
                context=ssl.create_default_context(cafile=os.environ.get("AWS_CA_BUNDLE")),
            )
            if endpoint.scheme == "https"
            else http.client.HTTPConnection(endpoint.netloc, timeout=REQUEST_TIMEOUT_S)
        )
        try:
            target = f"{path}?{query_text}" if query_text else path
            # a memoryview is sent as it is, where bytes would be copied after the headers
            connection.request(method, target, body=memoryview(body), headers=signing_headers)
            response = connection.getresponse()
            return response.status, response.headers, response.read()
        finally:
            connection.close()

    def _call(
        self, action: str, method: str, path: str, query: Mapping[str, str] | None = None,
        body: bytes = b"", headers: Mapping[str, str] | None = None,
        ok: Collection[int] = (200,),
    ) -> tuple[http.client.HTTPMessage, bytes]:  # fmt: skip
        """``_send`` until answered with a status in ``ok``, at most ``MAX_ATTEMPTS`` times
        (again after a failed connection or a transient refusal); the answer's headers and
        body. ``S3Refused`` when refused, ``OSError`` when the service cannot be reached."""
        failure: OSError | None = None
        for attempt in range(MAX_ATTEMPTS):
            if attempt:
                time.sleep(RETRY_DELAY_S * attempt)
            try:
                status, answer_headers, answer = self._send(
                    method, path, query or {}, body, headers or {}
                )
            except OSError as exc:  # refused, cut or timed out
                failure = exc
                continue
            refused = _refusal(action, status, answer, ok)
            if refused is None:
                return answer_headers, answer
            if not refused.transient:
                raise refused
            failure = refused
        assert failure is not None
        raise failure

    def delete(self, key: str) -> None:
        """DELETE the object (S3 answers 204 whether or not it existed); ``OSError`` on any
        other answer or when the service cannot be reached."""
        self._call("DeleteObject", "DELETE", self._path(key), ok=(200, 204))

    def pending_upload(self, key: str) -> str | None:
        """The id of an upload in parts to ``key`` begun and neither completed nor aborted
        (the last begun), if any."""
        bucket, _, prefix = self.base.partition("/")
        name = f"{prefix}/{key}" if prefix else key
        try:
            _, answer = self._call(
                "ListMultipartUploads", "GET", "/" + quote(bucket, safe="-_.~"),
                {"uploads": "", "prefix": name},
            )  # fmt: skip
        except S3Refused as exc:
            if exc.code == "NoSuchUpload":  # rclone: no upload begun in the bucket
                return None
            raise
        root = _xml(answer)
        uploads = [] if root is None else _children(root, "Upload")
        begun = sorted(
            (_text(upload, "Initiated"), _text(upload, "UploadId"))
            for upload in uploads
            if _text(upload, "Key") == name
        )
        return begun[-1][1] if begun else None

    def begin_upload(self, key: str) -> str:
        """Begin an upload in parts to ``key`` (CreateMultipartUpload); its id."""
        _, answer = self._call("CreateMultipartUpload", "POST", self._path(key), {"uploads": ""})
        root = _xml(answer)
        upload = "" if root is None else _text(root, "UploadId")
        if not upload:
            raise OSError(f"CreateMultipartUpload answered without an UploadId: {answer[:300]!r}")
        return upload

    def uploaded_parts(self, key: str, upload: str) -> dict[int, tuple[int, str]]:
        """The parts of the upload ``upload`` to ``key`` that the service holds (ListParts):
        each one's size in bytes and ETag (without quotes), by part number."""
        parts: dict[int, tuple[int, str]] = {}
        marker = "0"
        while True:
            _, answer = self._call(
                "ListParts", "GET", self._path(key),
                {"uploadId": upload, "part-number-marker": marker},
            )  # fmt: skip
            root = _xml(answer)
            if root is None:
                raise OSError(f"ListParts answered {answer[:300]!r}")
            for part in _children(root, "Part"):
                etag = _text(part, "ETag").strip('"').lower()
                parts[int(_text(part, "PartNumber"))] = (int(_text(part, "Size")), etag)
            marker = _text(root, "NextPartNumberMarker")
            if _text(root, "IsTruncated").lower() != "true" or not marker:
                return parts

    def upload_part(self, key: str, upload: str, number: int, data: bytes, md5: bytes) -> str:
        """Send part ``number`` of the upload ``upload`` to ``key`` (UploadPart), with its MD5
        digest ``md5`` for the service to check (``Content-MD5``; a corrupted part is refused
        with ``BadDigest`` and sent again; the part is not hashed again for the signature);
        its ETag."""
        headers, _ = self._call(
            "UploadPart", "PUT", self._path(key),
            {"partNumber": str(number), "uploadId": upload}, data,
            {"content-md5": base64.b64encode(md5).decode(), "x-amz-content-sha256": UNSIGNED},
        )  # fmt: skip
        etag = headers.get("ETag", "").strip('"')
        if not etag:
            raise OSError(f"UploadPart answered part {number} without an ETag")
        return etag

    def complete_upload(self, key: str, upload: str, etags: Sequence[str]) -> None:
        """Complete the upload ``upload`` to ``key`` with the parts ``etags`` (by number, from
        1): the object appears whole (CompleteMultipartUpload)."""
        parts = "".join(
            f'<Part><PartNumber>{number}</PartNumber><ETag>"{etag}"</ETag></Part>'
            for number, etag in enumerate(etags, start=1)
        )
        request = f'<CompleteMultipartUpload xmlns="{S3_XMLNS}">{parts}</CompleteMultipartUpload>'
        body = request.encode()
        self._call("CompleteMultipartUpload", "POST", self._path(key), {"uploadId": upload}, body)

    def dropped(self, key: str, upload: str) -> bool:
        """Whether the service no longer has the upload ``upload`` to ``key`` (ListParts
        answers ``NoSuchUpload``; False when it cannot tell)."""
        try:
            self.uploaded_parts(key, upload)
        except S3Refused as exc:
            return exc.code == "NoSuchUpload"
        except OSError:
            return False
        return False

    def abort_upload(self, key: str, upload: str) -> None:
        """Abort the upload ``upload`` to ``key``: the service drops its parts."""
        try:
            self._call(
                "AbortMultipartUpload", "DELETE", self._path(key), {"uploadId": upload},
                ok=(200, 204),
            )  # fmt: skip
        except S3Refused as exc:
            if exc.code != "NoSuchUpload":
                raise


def open_store(settings: Settings, environ: Mapping[str, str] | None = None) -> Store:
    """The store ``settings`` name (``store_settings``); for S3 the bucket is created if
    missing, and an unreachable service or refused keys are a ``StoreError`` within a few
    seconds. The keys come from ``environ`` (``os.environ`` by default)."""
    where = store_settings(settings)
    if isinstance(where, FolderStoreSettings):
        folder = where.folder.absolute()
        filesystem = pafs.SubTreeFileSystem(str(folder), pafs.LocalFileSystem())
        return Store(filesystem, str(folder), folder=folder)
    return _open_s3(where, os.environ if environ is None else environ)


def _open_s3(where: S3StoreSettings, environ: Mapping[str, str]) -> Store:
    credentials: dict[str, str] = {}
    for name, key in (("access_key", where.access_key_env), ("secret_key", where.secret_key_env)):
        if key is None:
            continue
        if not environ.get(key):
            raise UserError(f"{where.config_path}: store.{name}_env names ${key}, which is not set")
        credentials[name] = environ[key]
    for variable, value in AWS_CHECKSUM_ENVIRONMENT.items():
        os.environ.setdefault(variable, value)
    options: dict[str, object] = {}
    if where.endpoint is not None:
        endpoint = urlsplit(where.endpoint)
        options |= {"endpoint_override": endpoint.netloc, "scheme": endpoint.scheme}
    if where.region is not None:
        options["region"] = where.region
    s3 = pafs.S3FileSystem(
        **credentials,
        **options,
        allow_bucket_creation=True,
        background_writes=False,  # True buffers a whole upload's parts in memory
        connect_timeout=CONNECT_TIMEOUT_S,
        request_timeout=REQUEST_TIMEOUT_S,
        retry_strategy=pafs.AwsStandardS3RetryStrategy(max_attempts=MAX_ATTEMPTS),
    )
    url = where.url + (f" (endpoint {where.endpoint})" if where.endpoint else "")
    try:
        if s3.get_file_info(where.bucket).type == pafs.FileType.NotFound:
            s3.create_dir(where.bucket)
    except OSError as exc:
        raise StoreError(f"{url}: cannot reach the store: {_reason(exc)}") from None
    base = f"{where.bucket}/{where.prefix}".rstrip("/")
    objects = (
        S3Objects(
            where.endpoint,
            base,
            where.region or "us-east-1",
            credentials["access_key"],
            credentials["secret_key"],
        )
        if where.endpoint is not None and credentials
        else None  # AWS: pyarrow's folder markers do no harm there
    )
    return Store(
        pafs.SubTreeFileSystem(base, s3), where.url, s3=objects, part_bytes=where.part_bytes
    )
