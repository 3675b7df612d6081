"""The store of bulk data: ``[store]`` settings, and the same behaviour from a local folder
and from an S3-compatible server (``rclone serve s3`` on 127.0.0.1, the ``s3_server``
fixture)."""

from __future__ import annotations

import hashlib
import os
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from catenary.config import (
    FolderStoreSettings,
    S3StoreSettings,
    Settings,
    load_settings,
    store_settings,
)
from catenary.errors import UserError
from catenary.storage.store import (
    Store,
    StoredObject,
    StoreError,
    open_store,
    samples_key,
)

from ..conftest import S3Server

LINE, TRACK = "L/1=a b", "ü 2"
RUN = "657013f6-2aaa-5b0b-a92e-4f39c3ba8bf8"


def write_config(folder: Path, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "catenary.toml"
    path.write_text(text)
    return path


def free_port() -> int:
    """A port on 127.0.0.1 that nothing listens on."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
    return port


# --- [store] settings --------------------------------------------------------------------


def test_default_store_is_the_data_directory(isolated_environment: Path) -> None:
    settings = load_settings()
    assert settings.store is None
    assert store_settings(settings) == FolderStoreSettings(isolated_environment)
    assert open_store(settings).url == str(isolated_environment)


def test_folder_store_relative_to_the_config_file(tmp_path: Path) -> None:
    config = write_config(tmp_path / "etc", '[store]\nurl = "bulk/data"\n')
    assert load_settings(config_path=config).store == FolderStoreSettings(
        tmp_path / "etc" / "bulk" / "data"
    )
    config.write_text('[store]\nurl = "/srv/bulk"\n')
    assert load_settings(config_path=config).store == FolderStoreSettings(Path("/srv/bulk"))


def test_s3_store_settings(tmp_path: Path) -> None:
    config = write_config(
        tmp_path,
        '[store]\nurl = "s3://catenary/fleet/a/"\nendpoint = "https://s3.example:9000"\n'
        'region = "eu-central-1"\naccess_key_env = "AK_VAR"\nsecret_key_env = "SK_VAR"\n'
        "part_size_mb = 16\n",
    )
    store = load_settings(config_path=config).store
    assert store == S3StoreSettings(
        bucket="catenary",
        prefix="fleet/a",
        endpoint="https://s3.example:9000",
        region="eu-central-1",
        access_key_env="AK_VAR",
        secret_key_env="SK_VAR",
        config_path=config,
        part_bytes=16 << 20,
    )
    assert store.url == "s3://catenary/fleet/a"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("url = 3", "store.url must be a string, not 3"),
        ('ulr = "x"', "unknown key store.ulr (did you mean url?)"),
        ('url = "ftp://host/x"', "store.url 'ftp://host/x': unknown scheme ftp://"),
        ('url = "s3://"', "store.url 's3://' must be s3://BUCKET/PREFIX"),
        ('url = "s3:///fleet"', "store.url 's3:///fleet' must be s3://BUCKET/PREFIX"),
        ('url = "s3://Bad_Bucket/x"', "must be s3://BUCKET/PREFIX"),
        ('url = "s3://b12/a/../x"', "'.' and '..' are not allowed"),
        ('url = "bulk"\nendpoint = "http://h:1"', "store.endpoint needs an s3:// store.url"),
        ('endpoint = "http://h:1"', "store.endpoint needs an s3:// store.url"),
        ('url = "s3://b12"\nendpoint = "h:9000"', "store.endpoint 'h:9000' must be http(s)://"),
        ('url = "s3://b12"\naccess_key_env = "A"', "store.secret_key_env is missing"),
        ('url = "s3://b12"\nregion = 1', "store.region must be a string, not 1"),
        (
            'url = "s3://b12"\npart_size_mb = 4',
            "store.part_size_mb must be a whole number of MiB from 5 to 5120, not 4",
        ),
        ('url = "s3://b12"\npart_size_mb = "64"', "store.part_size_mb must be a whole number"),
        ('url = "bulk"\npart_size_mb = 64', "store.part_size_mb needs an s3:// store.url"),
    ],
)
def test_bad_store_settings_are_one_line_naming_file_and_key(
    tmp_path: Path, text: str, message: str
) -> None:
    config = write_config(tmp_path, f"[store]\n{text}\n")
    with pytest.raises(UserError) as raised:
        load_settings(config_path=config)
    assert str(raised.value).startswith(f"{config}: ")
    assert message in str(raised.value)
    assert "\n" not in str(raised.value)


def test_key_variable_not_set_is_named_and_no_secret_shown(tmp_path: Path) -> None:
    config = write_config(
        tmp_path,
        '[store]\nurl = "s3://b12/x"\nendpoint = "http://127.0.0.1:9"\n'
        'access_key_env = "AK_VAR"\nsecret_key_env = "SK_VAR"\n',
    )
    settings = load_settings(config_path=config)
    with pytest.raises(UserError) as raised:
        open_store(settings, environ={"AK_VAR": "the-access-key-value"})
    message = str(raised.value)
    assert message == f"{config}: store.secret_key_env names $SK_VAR, which is not set"
    assert "the-access-key-value" not in message


# --- the same behaviour from both stores -------------------------------------------------


@pytest.fixture(params=["folder", "s3"])
def store(request: pytest.FixtureRequest) -> Store:
    """A store in the data directory, or in a new bucket on the test S3 server."""
    if request.param == "folder":
        return open_store(load_settings())
    settings: Settings = request.getfixturevalue("s3_settings")
    return open_store(settings)


def make_file(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_put_verify_open_exists_delete_keys(store: Store, tmp_path: Path) -> None:
    data = b"contact wire" * 1000
    key = samples_key(LINE, TRACK, RUN, "run-1")
    stored = store.put_file(make_file(tmp_path / "a.bin", data), key)
    assert stored == StoredObject(key, len(data), hashlib.sha256(data).hexdigest())
    assert store.exists(key)
    assert store.size(key) == len(data)
    assert store.verify(key, len(data), stored.sha256)
    assert not store.verify(key, len(data), "0" * 64)
    assert not store.verify(key, len(data) + 1, stored.sha256)
    with store.open_input(key) as handle:
        assert handle.size() == len(data)
        assert handle.read_at(7, 1004) == data[1004:1011]

    other = store.put_file(make_file(tmp_path / "b.bin", b"x"), "runs/b.h5")
    assert store.keys() == sorted([key, other.key])
    assert store.keys("samples") == [key]
    assert store.keys("nothing/here") == []

    replaced = store.put_file(make_file(tmp_path / "c.bin", b"new"), key)
    assert store.size(key) == 3
    assert store.verify(key, 3, replaced.sha256)

    store.delete(key)
    assert not store.exists(key)
    store.delete(key)  # missing: no error
    assert not store.verify(key, 3, replaced.sha256)
    assert store.keys() == ["runs/b.h5"]
    with pytest.raises(StoreError, match="no such object"):
        store.open_input(key)
    with pytest.raises(StoreError, match="no such object"):
        store.size(key)


def test_delete_keeps_neighbours_and_emptied_folders_reusable(store: Store, tmp_path: Path) -> None:
    """Deleting leaves the folder's other objects listed and readable, and an emptied folder
    takes new objects (pyarrow's folder markers would break both on rclone serve s3)."""
    source = make_file(tmp_path / "a.bin", b"abc")
    first, second = samples_key(LINE, TRACK, RUN, "run-1"), samples_key(LINE, TRACK, RUN, "run-2")
    store.put_file(source, first)
    kept = store.put_file(source, second)
    store.delete(first)
    assert store.keys() == [second]
    assert store.verify(second, kept.size_bytes, kept.sha256)
    store.delete(second)
    assert store.keys() == []
    store.put_file(source, first)
    assert store.keys() == [first]


def test_large_upload_round_trips(store: Store, tmp_path: Path) -> None:
    """40 MB: several parts of a multipart upload on S3."""
    source = tmp_path / "large.bin"
    digest = hashlib.sha256()
    with source.open("wb") as out:
        for _ in range(40):
            block = os.urandom(1024 * 1024)
            digest.update(block)
            out.write(block)
    stored = store.put_file(source, "runs/large.bin")
    assert stored.size_bytes == 40 * 1024 * 1024
    assert stored.sha256 == digest.hexdigest()
    assert store.verify("runs/large.bin", stored.size_bytes, digest.hexdigest())
    with store.open_input("runs/large.bin") as handle, source.open("rb") as local:
        local.seek(33_000_000)
        assert handle.read_at(1000, 33_000_000) == local.read(1000)


def test_corrupted_object_fails_verify(store: Store, tmp_path: Path) -> None:
    data = os.urandom(100_000)
    stored = store.put_file(make_file(tmp_path / "a.bin", data), "runs/a.bin")
    with store.filesystem.open_output_stream("runs/a.bin") as out:  # behind the store's back
        out.write(data[:50_000] + bytes([data[50_000] ^ 1]) + data[50_001:])
    assert store.size("runs/a.bin") == len(data)
    assert not store.verify("runs/a.bin", stored.size_bytes, stored.sha256)
    with pytest.raises(StoreError, match=r"runs/a.bin: missing or corrupt"):
        store.check("runs/a.bin", stored.size_bytes, stored.sha256)


@pytest.mark.parametrize(
    "key", ["", "/etc/passwd", "../x", "a/../../x", "a//b", "a/", "./a", ".hidden", "a\\b", "a\nb"]
)
def test_hostile_keys_are_refused(store: Store, tmp_path: Path, key: str) -> None:
    source = make_file(tmp_path / "a.bin", b"x")
    for call in (
        lambda: store.put_file(source, key),
        lambda: store.exists(key),
        lambda: store.delete(key),
        lambda: store.open_input(key),
        lambda: store.verify(key, 1, "0" * 64),
    ):
        with pytest.raises(ValueError, match="not a store key"):
            call()
    assert store.keys() == []


def test_missing_local_file_is_named(store: Store, tmp_path: Path) -> None:
    with pytest.raises(UserError, match=f"{tmp_path / 'none.bin'}: cannot read"):
        store.put_file(tmp_path / "none.bin", "runs/none.bin")
    assert not store.exists("runs/none.bin")


def test_local_write_leaves_no_partial_file(isolated_environment: Path, tmp_path: Path) -> None:
    store = open_store(load_settings())
    store.put_file(make_file(tmp_path / "a.bin", b"abc"), "runs/a.bin")
    assert sorted(p.name for p in (isolated_environment / "runs").iterdir()) == ["a.bin"]
    # a key whose folder is a file: the write fails, nothing is left beside it
    with pytest.raises(StoreError, match=r"runs/a.bin/b: cannot write"):
        store.put_file(make_file(tmp_path / "b.bin", b"b"), "runs/a.bin/b")
    assert sorted(p.name for p in (isolated_environment / "runs").iterdir()) == ["a.bin"]
    assert (isolated_environment / "runs" / "a.bin").read_bytes() == b"abc"


# --- samples keys and the fleet's dataset ------------------------------------------------


def test_samples_key_percent_encodes_line_and_track() -> None:
    assert (
        samples_key(LINE, TRACK, RUN, "run-1")
        == f"samples/line=L%2F1%3Da%20b/track=%C3%BC%202/run={RUN}/run-1.parquet"
    )
    for line, track, run, name in [
        ("", "1", RUN, "r"),
        ("L", "1", "", "r"),
        ("L", "1", "a/b", "r"),
        ("L", "1", RUN, "a/b"),
        ("L", "1", RUN, ""),
    ]:
        with pytest.raises(ValueError):
            samples_key(line, track, run, name)


def test_samples_read_as_one_hive_dataset(store: Store, tmp_path: Path) -> None:
    keys = []
    for number, (line, track) in enumerate([(LINE, TRACK), ("100", "1")]):
        table = pa.table(
            {
                "chainage_m": [1000.0 + 10 * i for i in range(10)],
                "residual_thickness_mm": [11.0 + number] * 10,
            }
        )
        local = tmp_path / f"{number}.parquet"
        pq.write_table(table, local)
        key = samples_key(line, track, f"{RUN[:-1]}{number}", f"run-{number}")
        keys.append(store.put_file(local, key).key)
    assert store.keys("samples") == sorted(keys)

    dataset = store.dataset(keys)
    rows = dataset.to_table(
        filter=(ds.field("chainage_m") >= 1075.0) & (ds.field("line") == LINE)
    ).to_pylist()
    assert rows == [
        {
            "chainage_m": c,
            "residual_thickness_mm": 11.0,
            "line": LINE,
            "track": TRACK,
            "run": f"{RUN[:-1]}0",
        }
        for c in (1080.0, 1090.0)
    ]
    # the identifiers stay text even where they read as numbers
    assert dataset.to_table(filter=ds.field("track") == "1").column("line").to_pylist() == (
        ["100"] * 10
    )

    # pyarrow's own hive partitioning decodes the keys' percent-encoding too
    plain = ds.dataset(keys, filesystem=store.filesystem, format="parquet", partitioning="hive")
    lines = plain.to_table(filter=ds.field("chainage_m") < 1005.0).column("line").to_pylist()
    assert sorted(map(str, lines)) == sorted([LINE, "100"])
    with store.open_input(keys[0]) as handle:
        assert pq.ParquetFile(handle).metadata.num_rows == 10


# --- an S3 service that is unreachable or goes away --------------------------------------


def s3_config(tmp_path: Path, endpoint: str, *, access_key: str = "catenary-test-access") -> Path:
    return write_config(
        tmp_path,
        f'[store]\nurl = "s3://unreachable/x"\nendpoint = "{endpoint}"\n'
        'access_key_env = "AK_VAR"\nsecret_key_env = "SK_VAR"\n',
    )


def test_unreachable_endpoint_is_one_line_within_seconds(tmp_path: Path) -> None:
    endpoint = f"http://127.0.0.1:{free_port()}"
    settings = load_settings(config_path=s3_config(tmp_path, endpoint))
    start = time.monotonic()
    with pytest.raises(StoreError) as raised:
        open_store(settings, environ={"AK_VAR": "a", "SK_VAR": "s"})
    assert time.monotonic() - start < 5.0
    message = str(raised.value)
    assert message.startswith(f"s3://unreachable/x (endpoint {endpoint}): cannot reach the store")
    assert "\n" not in message


def test_refused_keys_are_one_line(s3_server: S3Server, tmp_path: Path) -> None:
    s3_server.start()
    settings = load_settings(config_path=s3_config(tmp_path, s3_server.endpoint))
    with pytest.raises(StoreError, match=r"cannot reach the store: .*ACCESS_DENIED") as raised:
        open_store(settings, environ={"AK_VAR": "catenary-test-access", "SK_VAR": "wrong-secret"})
    assert "wrong-secret" not in str(raised.value)


@pytest.fixture
def s3_store(s3_settings: Settings, s3_server: S3Server) -> Iterator[Store]:
    yield open_store(s3_settings)
    s3_server.start()  # a failed test may leave it stopped


def test_server_stopped_mid_transfer_then_back(
    s3_store: Store, s3_server: S3Server, tmp_path: Path
) -> None:
    """The link is cut while a file is being uploaded: a one-line error, no object; once the
    server is back, what was stored before is intact and uploads work again."""
    before = s3_store.put_file(make_file(tmp_path / "a.bin", os.urandom(1000)), "runs/a.bin")
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    block = os.urandom(1024 * 1024)

    def feed() -> None:
        """30 MB, the server stopped after the first 20 MB."""
        try:
            with pipe.open("wb") as out:
                for number in range(30):
                    if number == 20:
                        s3_server.stop()
                    out.write(block)
        except BrokenPipeError:  # the store gave up reading
            pass

    feeder = threading.Thread(target=feed)
    feeder.start()
    start = time.monotonic()
    with pytest.raises(StoreError) as raised:
        s3_store.put_file(pipe, "runs/cut.bin")
    feeder.join(timeout=30)
    assert not feeder.is_alive()
    assert time.monotonic() - start < 20.0
    message = str(raised.value)
    assert message.startswith(f"{s3_store.url}/runs/cut.bin: cannot write: ")
    assert "\n" not in message
    with pytest.raises(StoreError, match=r"runs/a.bin: cannot look up"):
        s3_store.exists("runs/a.bin")

    s3_server.start()
    assert s3_store.verify("runs/a.bin", before.size_bytes, before.sha256)
    assert not s3_store.exists("runs/cut.bin")
    again = s3_store.put_file(make_file(tmp_path / "b.bin", block), "runs/cut.bin")
    assert s3_store.verify("runs/cut.bin", again.size_bytes, again.sha256)
