"""The store of bulk data (samples files): a local folder or an S3-compatible object store.

Objects are addressed by keys: '/'-separated relative names (``samples_key``), the same on
every machine, so the database refers to a file by its key and any machine that reaches the
store reads it. Every write is checked by reading the object back (size and SHA-256) and is
atomic: a reader sees the whole object or none (a local file is written under a hidden name
and renamed; an S3 upload is completed in one request). Errors are ``StoreError``: one line
naming the store's URL and the key.
"""

from __future__ import annotations

import hashlib
import hmac
import http.client
import io
import os
import ssl
import uuid
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO
from urllib.parse import quote, urlsplit

import pyarrow as pa
import pyarrow.fs as pafs

if TYPE_CHECKING:
    import pyarrow.dataset as ds

from catenary.config import FolderStoreSettings, S3StoreSettings, Settings, store_settings
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
#: Without these, the AWS SDK of current pyarrow sends checksums that S3-compatible services
#: refuse (HTTP 411 on multipart uploads) and checks them on ranged reads (a checksum error).
AWS_CHECKSUM_ENVIRONMENT = {
    "AWS_REQUEST_CHECKSUM_CALCULATION": "when_required",
    "AWS_RESPONSE_CHECKSUM_VALIDATION": "when_required",
}


class StoreError(UserError):
    """The store cannot be reached, or an object is missing, unreadable or corrupt."""


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
    ) -> None:
        """``filesystem`` rooted at the store; ``folder`` for a local store, ``s3`` for an S3
        store whose keys are known (its objects are deleted through it)."""
        self.filesystem = filesystem
        self.url = url
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
        if not self.verify(key, written.size_bytes, written.sha256):
            self._discard(key)
            raise StoreError(f"{self.describe(key)}: the object read back differs from {what}")
        return written

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


@dataclass(frozen=True)
class S3Objects:
    """Deletes objects under ``base`` (``BUCKET/PREFIX``) of the service at ``endpoint``.

    pyarrow's ``delete_file`` then writes an empty marker object ``FOLDER/`` for the key's
    folder; an S3 service on a file system (``rclone serve s3``) cannot keep it beside the
    folder's objects and from then on lists the folder as an empty file, hiding them. So the
    store sends the one DeleteObject request itself (AWS Signature Version 4, path-style).
    """

    endpoint: str
    base: str
    region: str
    access_key: str
    secret_key: str = field(repr=False)

    def delete(self, key: str) -> None:
        """DELETE the object (S3 answers 204 whether or not it existed); ``OSError`` on any
        other answer or when the service cannot be reached."""
        endpoint = urlsplit(self.endpoint)
        path = "/" + quote(f"{self.base}/{key}", safe="/-_.~")
        now = datetime.now(UTC)
        amz_date, day = now.strftime("%Y%m%dT%H%M%SZ"), now.strftime("%Y%m%d")
        payload = hashlib.sha256(b"").hexdigest()
        headers = {"host": endpoint.netloc, "x-amz-content-sha256": payload, "x-amz-date": amz_date}
        signed = ";".join(headers)
        canonical = "\n".join(
            ["DELETE", path, "", *(f"{k}:{v}" for k, v in headers.items()), "", signed, payload]
        )
        scope = f"{day}/{self.region}/s3/aws4_request"
        to_sign = "\n".join(
            ["AWS4-HMAC-SHA256", amz_date, scope, hashlib.sha256(canonical.encode()).hexdigest()]
        )
        signing = f"AWS4{self.secret_key}".encode()
        for part in (day, self.region, "s3", "aws4_request"):
            signing = hmac.new(signing, part.encode(), hashlib.sha256).digest()
        signature = hmac.new(signing, to_sign.encode(), hashlib.sha256).hexdigest()
        headers["authorization"] = (
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
            connection.request("DELETE", path, headers=headers)
            response = connection.getresponse()
            body = response.read(500)
        finally:
            connection.close()
        if response.status not in {200, 204}:
            raise OSError(
                f"DeleteObject answered HTTP {response.status}: {body.decode(errors='replace')}"
            )


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
    return Store(pafs.SubTreeFileSystem(base, s3), where.url, s3=objects)
