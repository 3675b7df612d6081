"""Large files put in parts (``Store.put_parts``): a put cut short resumes with the parts
missing, every part in place is checked first, a part corrupted on the way is refused by the
server (``rclone serve s3`` on 127.0.0.1) and sent again, and a file of another content than
expected is not stored."""

from __future__ import annotations

import hashlib
import os
import socket
import threading
from collections.abc import Callable, Iterator
from contextlib import suppress
from pathlib import Path

import pytest
import tomli_w

from catenary.config import load_settings
from catenary.storage.store import (
    MAX_PARTS,
    ContentMismatch,
    Part,
    Store,
    StoredObject,
    open_store,
    part_size,
)

from ..conftest import S3Server

MIB = 1 << 20
PART_MB = 5  # the smallest S3 allows
KEY = "runs/run.h5"


class Cut(Exception):
    """The put cut short (as by a lost link or a killed process)."""


def cut_after(count: int, seen: list[Part]) -> Callable[[Part], None]:
    """An ``on_part`` that records the parts and cuts the put once ``count`` are done."""

    def on_part(part: Part) -> None:
        seen.append(part)
        if len(seen) == count:
            raise Cut

    return on_part


def s3_store(server: S3Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
             endpoint: str | None = None) -> Store:  # fmt: skip
    """A store in a new bucket of ``server`` (through ``endpoint`` if given), in parts of
    ``PART_MB``."""
    server.start()
    for name, value in server.environ().items():
        monkeypatch.setenv(name, value)
    section = server.store_section(f"parts-{os.urandom(6).hex()}")
    if endpoint is not None:
        section["endpoint"] = endpoint
    config = tmp_path / "store.toml"
    config.write_text(tomli_w.dumps({"store": {**section, "part_size_mb": PART_MB}}))
    return open_store(load_settings(config_path=config))


def run_file(path: Path, size: int) -> tuple[Path, str]:
    """A file of ``size`` random bytes and its SHA-256."""
    data = os.urandom(size)
    path.write_bytes(data)
    return path, hashlib.sha256(data).hexdigest()


def pending(store: Store) -> str | None:
    """The upload in parts to ``KEY`` begun and not completed, if any."""
    assert store._s3 is not None
    return store._s3.pending_upload(KEY)


def test_part_size_keeps_within_the_parts_s3_allows() -> None:
    assert part_size(100 * MIB, 64 * MIB) == 64 * MIB
    assert part_size(MAX_PARTS * 64 * MIB, 64 * MIB) == 64 * MIB
    large = part_size(MAX_PARTS * 64 * MIB + 1, 64 * MIB)
    assert large == 65 * MIB  # whole MiB
    assert (MAX_PARTS * 64 * MIB + 1) / large <= MAX_PARTS


def test_s3_put_cut_short_resumes_with_the_missing_parts(
    s3_server: S3Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = s3_store(s3_server, tmp_path, monkeypatch)
    path, sha256 = run_file(tmp_path / "run.h5", 4 * PART_MB * MIB + MIB)
    first: list[Part] = []
    with pytest.raises(Cut):
        store.put_parts(path, KEY, sha256=sha256, on_part=cut_after(2, first))
    assert [(p.number, p.sent) for p in first] == [(1, True), (2, True)]
    assert not store.exists(KEY) and pending(store) is not None

    again: list[Part] = []
    stored = store.put_parts(path, KEY, sha256=sha256, on_part=again.append)
    assert [(p.number, p.sent) for p in again] == [
        (1, False), (2, False), (3, True), (4, True), (5, True)
    ]  # fmt: skip
    assert [p.size_bytes for p in again] == [PART_MB * MIB] * 4 + [MIB]
    assert stored == StoredObject(KEY, path.stat().st_size, sha256)
    assert store.digest(KEY) == stored  # the object, read whole
    assert pending(store) is None


def test_s3_upload_holding_a_part_unlike_the_files_is_begun_anew(
    s3_server: S3Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A part the server holds that is not the file's (here: the file's first part changed
    after the cut) is not taken: that upload is aborted and every part sent to a new one
    (rclone, like other services, cannot replace a part it holds)."""
    store = s3_store(s3_server, tmp_path, monkeypatch)
    path, _ = run_file(tmp_path / "run.h5", 3 * PART_MB * MIB)
    with pytest.raises(Cut):
        store.put_parts(path, KEY, on_part=cut_after(2, []))
    data = bytearray(path.read_bytes())
    data[1000] ^= 0xFF
    path.write_bytes(data)
    cut = pending(store)
    again: list[Part] = []
    stored = store.put_parts(path, KEY, on_part=again.append)
    assert [p.sent for p in again] == [True, True, True]
    assert cut is not None and pending(store) is None  # the cut upload aborted
    assert (
        store.digest(KEY)
        == stored
        == StoredObject(KEY, len(data), hashlib.sha256(data).hexdigest())
    )


class CorruptingProxy:
    """Forwards connections to 127.0.0.1:``port`` on to ``target``, flipping one byte of the
    body of the first request whose head holds ``pattern``; ``answer``: the server's answer
    to that request."""

    def __init__(self, target: int, pattern: bytes) -> None:
        self.target = target
        self.pattern = pattern
        self.answer = b""
        self._corrupted = threading.Event()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        threading.Thread(target=self._accept, daemon=True).start()

    def close(self) -> None:
        self._listener.close()

    def _accept(self) -> None:
        with suppress(OSError):
            while True:
                client, _ = self._listener.accept()
                server = socket.create_connection(("127.0.0.1", self.target))
                flipped = threading.Event()  # in this connection's request
                threading.Thread(target=self._answer, args=(server, client, flipped)).start()
                threading.Thread(target=self._request, args=(client, server, flipped)).start()

    def _request(
        self, client: socket.socket, server: socket.socket, flipped: threading.Event
    ) -> None:
        head: bytes | None = b""
        skip = -1  # the bytes before the one to flip, from this chunk's start (-1: none)
        with suppress(OSError), client, server:
            while chunk := client.recv(1 << 16):
                if head is not None:
                    head += chunk
                    end = head.find(b"\r\n\r\n")
                    if end >= 0:
                        if self.pattern in head[:end] and not self._corrupted.is_set():
                            self._corrupted.set()
                            flipped.set()
                            skip = end + 4 + 100 - (len(head) - len(chunk))  # in the body
                        head = None
                if 0 <= skip < len(chunk):
                    changed = bytearray(chunk)
                    changed[skip] ^= 0xFF
                    chunk, skip = bytes(changed), -1
                elif skip >= 0:
                    skip -= len(chunk)
                server.sendall(chunk)

    def _answer(
        self, server: socket.socket, client: socket.socket, flipped: threading.Event
    ) -> None:
        with suppress(OSError):
            while chunk := server.recv(1 << 16):
                if flipped.is_set():
                    self.answer += chunk  # before the client has it
                client.sendall(chunk)
        with suppress(OSError):
            client.close()


@pytest.fixture
def corrupting_proxy(s3_server: S3Server) -> Iterator[CorruptingProxy]:
    proxy = CorruptingProxy(s3_server.port, b"partNumber=2&")
    yield proxy
    proxy.close()


def test_s3_part_corrupted_on_the_way_is_refused_and_sent_again(
    s3_server: S3Server,
    corrupting_proxy: CorruptingProxy,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The server checks each part's MD5 (Content-MD5): the part corrupted on the way is
    refused (BadDigest); rclone then drops the upload, so the put begins a new one, and the
    object is the file's (without the check it would be corrupt)."""
    store = s3_store(
        s3_server, tmp_path, monkeypatch, endpoint=f"http://127.0.0.1:{corrupting_proxy.port}"
    )
    path, sha256 = run_file(tmp_path / "run.h5", 2 * PART_MB * MIB + MIB)
    parts: list[Part] = []
    stored = store.put_parts(path, KEY, sha256=sha256, on_part=parts.append)
    answer = corrupting_proxy.answer
    assert answer.startswith(b"HTTP/1.1 400 ") and b"<Code>BadDigest</Code>" in answer, answer
    assert [(p.number, p.sent) for p in parts] == [(1, True), (1, True), (2, True), (3, True)]
    assert store.digest(KEY) == stored == StoredObject(KEY, path.stat().st_size, sha256)
    assert pending(store) is None


def test_s3_file_of_another_content_is_not_stored(
    s3_server: S3Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = s3_store(s3_server, tmp_path, monkeypatch)
    path, sha256 = run_file(tmp_path / "run.h5", PART_MB * MIB + 10)
    with pytest.raises(ContentMismatch, match=f"^{path}: its SHA-256 is {sha256}, not 0+ "):
        store.put_parts(path, KEY, sha256="0" * 64)
    assert not store.exists(KEY)
    assert pending(store) is None  # aborted


def test_folder_put_cut_short_resumes_from_what_its_part_file_holds_alike(
    isolated_environment: Path, tmp_path: Path
) -> None:
    store = open_store(load_settings())
    store.part_bytes = MIB
    path, sha256 = run_file(tmp_path / "run.h5", 4 * MIB + 100)
    with pytest.raises(Cut):
        store.put_parts(path, KEY, sha256=sha256, on_part=cut_after(3, []))
    partial = isolated_environment / "runs" / ".run.h5.part"
    assert partial.stat().st_size == 3 * MIB
    assert not store.exists(KEY) and store.keys() == []
    with partial.open("r+b") as damaged:  # the third part's bytes are not the file's
        damaged.seek(2 * MIB + 5)
        damaged.write(b"\0\0\0")
    again: list[Part] = []
    stored = store.put_parts(path, KEY, sha256=sha256, on_part=again.append)
    assert [(p.number, p.sent) for p in again] == [
        (1, False), (2, False), (3, True), (4, True), (5, True)
    ]  # fmt: skip
    assert stored == StoredObject(KEY, path.stat().st_size, sha256) == store.digest(KEY)
    assert not partial.exists()


def test_folder_file_of_another_content_leaves_nothing(
    isolated_environment: Path, tmp_path: Path
) -> None:
    store = open_store(load_settings())
    path, _ = run_file(tmp_path / "run.h5", 1000)
    with pytest.raises(ContentMismatch):
        store.put_parts(path, KEY, sha256="0" * 64)
    assert not store.exists(KEY)
    assert not list((isolated_environment / "runs").iterdir())
