"""Settings: a TOML config file, environment variables and command-line options.

Precedence, highest first: command-line option, environment variable, config file, default.

- config file: ``--config PATH``, else ``$CATENARY_CONFIG``, else ``config.toml`` in the
  per-user config directory if it exists;
- database URL: ``--db URL``, ``$CATENARY_DATABASE_URL``, ``[database] url``, else a SQLite
  file ``catenary.sqlite`` in the data directory;
- database connect timeout (PostgreSQL): ``[database] connect_timeout_s``, else 10 s;
- statement timeout of interactive commands: ``[database] statement_timeout_s``, else none
  (batch commands and scheduler jobs never have one; ``storage.database.make_engine``);
- data directory (SQLite file, per-run sample files, reports): ``$CATENARY_DATA_DIR``,
  ``[paths] data_dir``, else the per-user data directory;
- store of bulk data (``catenary.storage.store``): ``[store] url``, a folder (relative to the
  config file's folder) or ``s3://BUCKET/PREFIX`` with ``endpoint``, ``region``, the names of
  the environment variables holding the keys (``access_key_env``, ``secret_key_env``) and the
  size of the parts large files are uploaded in (``part_size_mb``, MiB, else 64), else the
  data directory (``store_settings``).

The sections above are resolved here; the other sections are kept in ``Settings.sections`` for
the modules and plugins that read them: the core's (``CORE_SECTIONS``) and those plugins declare
(hook ``catenary_config_sections``). A section nobody reads, or an unknown key, is an error
naming it and the nearest known name (``PluginRegistry.check_settings``, when a command loads its
settings), so a misspelt ``[databse]`` is never ignored.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import urlsplit

import platformdirs

from catenary.errors import UserError

APP_NAME = "catenary"
#: An S3 bucket's name (AWS's rules, without the rarely used dotted forms' checks).
BUCKET_NAME = re.compile(r"[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]")
#: The parts large files are uploaded to an S3 store in (``[store] part_size_mb``), in MiB, and
#: the sizes S3 allows (the last part of an upload may be smaller).
DEFAULT_PART_MB = 64
PART_MB_RANGE = (5, 5 * 1024)
#: How long connecting to a database server may take before the command gives up, in seconds.
DEFAULT_CONNECT_TIMEOUT_S = 10.0
KNOWN_KEYS: dict[str, set[str]] = {
    "database": {"url", "connect_timeout_s", "statement_timeout_s"},
    "paths": {"data_dir"},
    "plugins": {"disabled"},
    "store": {"url", "endpoint", "region", "access_key_env", "secret_key_env", "part_size_mb"},
}
CORE_SECTIONS = frozenset(
    {
        "limits",
        "maintenance",
        "notifications",
        "processing",
        "processors",
        "record",
        "scheduler",
        "web",
    }
)
"""Sections other modules of the core read, each checking its keys as it reads them: [limits]
(``catenary.limits``), [maintenance] (alert rules), [notifications], [scheduler], [record]
(``catenary record``), [processing] and [processors.NAME] (``catenary process``), [web]
(``catenary serve``)."""


def did_you_mean(name: str, known: Iterable[str], *, brackets: bool = False) -> str:
    """`` (did you mean X?)`` for the known name nearest ``name`` (``difflib``), else
    `` (known: A, B)``; ``brackets`` writes section names as ``[X]``."""
    names = sorted(known)
    shown = [f"[{n}]" if brackets else n for n in names]
    near = difflib.get_close_matches(name, names, n=1)
    if near:
        return f" (did you mean {shown[names.index(near[0])]}?)"
    return f" (known: {', '.join(shown) or 'none'})"


@dataclass(frozen=True)
class FolderStoreSettings:
    """A store in a local folder (absolute, or relative to the working directory)."""

    folder: Path

    @property
    def url(self) -> str:
        """The folder, for messages."""
        return str(self.folder)


@dataclass(frozen=True)
class S3StoreSettings:
    """A store in an S3-compatible object store, under ``prefix`` of ``bucket``.

    ``endpoint`` is the service's ``http(s)://HOST[:PORT]`` (None: AWS); the keys are read from
    the environment variables ``access_key_env`` and ``secret_key_env`` when the store is
    opened (None: the AWS SDK's own chain: ``AWS_ACCESS_KEY_ID``, ``~/.aws``, instance role).
    ``part_bytes``: the size of the parts a large file is uploaded in (``Store.put_parts``).
    """

    bucket: str
    prefix: str = ""
    endpoint: str | None = None
    region: str | None = None
    access_key_env: str | None = None
    secret_key_env: str | None = None
    config_path: Path | None = None
    part_bytes: int = DEFAULT_PART_MB << 20

    @property
    def url(self) -> str:
        """``s3://BUCKET/PREFIX``, for messages."""
        return f"s3://{self.bucket}/{self.prefix}".rstrip("/")


StoreSettings = FolderStoreSettings | S3StoreSettings


@dataclass(frozen=True)
class Settings:
    """The resolved settings of one invocation (``store`` None: the data directory)."""

    database_url: str
    data_dir: Path
    config_path: Path | None = None
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S
    statement_timeout_s: float | None = None
    disabled_plugins: tuple[str, ...] = ()
    store: StoreSettings | None = None
    sections: Mapping[str, Any] = field(default_factory=dict)


def store_settings(settings: Settings) -> StoreSettings:
    """Where ``settings`` keep bulk data: ``[store]``, else the data directory."""
    return settings.store or FolderStoreSettings(settings.data_dir)


def default_config_path() -> Path:
    return Path(platformdirs.user_config_dir(APP_NAME)) / "config.toml"


def read_config_file(path: Path) -> dict[str, Any]:
    """Parse a TOML config file, naming the file in any error."""
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        raise UserError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{path}: invalid TOML: {exc}") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot read config file: {exc.strerror}") from None
    for section, keys in KNOWN_KEYS.items():
        value = data.get(section, {})
        if not isinstance(value, dict):
            raise UserError(f"{path}: [{section}] must be a table")
        unknown = sorted(set(value) - keys)
        if unknown:
            raise UserError(
                f"{path}: unknown key {section}.{unknown[0]}{did_you_mean(unknown[0], keys)}"
            )
    return data


def _seconds(config_path: Path | None, key: str, value: object) -> float:
    """``value`` of ``[database] KEY``: a positive, finite number of seconds."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < math.inf:
        raise UserError(
            f"{config_path}: database.{key} must be a positive number of seconds, not {value!r}"
        )
    return float(value)


def _store(config_path: Path | None, section: Mapping[str, object]) -> StoreSettings | None:
    """``[store]`` resolved: None when it gives no ``url``."""
    section = dict(section)
    part_given = "part_size_mb" in section
    part_mb = section.pop("part_size_mb", DEFAULT_PART_MB)
    low, high = PART_MB_RANGE
    if isinstance(part_mb, bool) or not isinstance(part_mb, int) or not low <= part_mb <= high:
        raise UserError(
            f"{config_path}: store.part_size_mb must be a whole number of MiB from {low} to "
            f"{high}, not {part_mb!r}"
        )
    for key, value in section.items():
        if not isinstance(value, str):
            raise UserError(f"{config_path}: store.{key} must be a string, not {value!r}")
    text: dict[str, str] = {key: str(value) for key, value in section.items() if value}
    url = text.get("url")
    if url is None or "://" not in url:
        s3_only = ("endpoint", "region", "access_key_env", "secret_key_env")
        given = [key for key in s3_only if key in text] + ["part_size_mb"] * part_given
        if given:
            raise UserError(f"{config_path}: store.{given[0]} needs an s3:// store.url")
        if url is None:
            return None
        folder = Path(url).expanduser()
        if not folder.is_absolute() and config_path is not None:
            folder = config_path.parent / folder
        return FolderStoreSettings(folder)
    parts = urlsplit(url)
    if parts.scheme != "s3":
        raise UserError(
            f"{config_path}: store.url {url!r}: unknown scheme {parts.scheme}:// "
            "(a folder or s3://BUCKET/PREFIX)"
        )
    if not BUCKET_NAME.fullmatch(parts.netloc) or parts.query or parts.fragment:
        raise UserError(
            f"{config_path}: store.url {url!r} must be s3://BUCKET/PREFIX "
            "(a bucket of 3 to 63 lower-case letters, digits, '.' and '-')"
        )
    prefix = PurePosixPath(parts.path.strip("/"))
    if any(part in {".", ".."} for part in prefix.parts):
        raise UserError(f"{config_path}: store.url {url!r}: '.' and '..' are not allowed")
    endpoint = text.get("endpoint")
    if endpoint is not None:
        split = urlsplit(endpoint)
        if split.scheme not in {"http", "https"} or not split.netloc or split.path.strip("/"):
            raise UserError(
                f"{config_path}: store.endpoint {endpoint!r} must be http(s)://HOST[:PORT]"
            )
    access, secret = text.get("access_key_env"), text.get("secret_key_env")
    if (access is None) != (secret is None):
        missing = "secret_key_env" if secret is None else "access_key_env"
        raise UserError(f"{config_path}: store.{missing} is missing (give both key variables)")
    return S3StoreSettings(
        bucket=parts.netloc,
        prefix="" if str(prefix) == "." else str(prefix),
        endpoint=endpoint,
        region=text.get("region"),
        access_key_env=access,
        secret_key_env=secret,
        config_path=config_path,
        part_bytes=part_mb << 20,
    )


def load_settings(
    *,
    config_path: Path | None = None,
    database_url: str | None = None,
    environ: Mapping[str, str] | None = None,
) -> Settings:
    """Resolve settings from options, the environment (``os.environ`` by default) and file."""
    env = os.environ if environ is None else environ
    if config_path is None and env.get("CATENARY_CONFIG"):
        config_path = Path(env["CATENARY_CONFIG"])
    if config_path is None and default_config_path().is_file():
        config_path = default_config_path()
    data = read_config_file(config_path) if config_path is not None else {}

    data_dir_value = env.get("CATENARY_DATA_DIR") or data.get("paths", {}).get("data_dir")
    if data_dir_value is not None and not isinstance(data_dir_value, str):
        raise UserError(f"{config_path}: paths.data_dir must be a string, not {data_dir_value!r}")
    data_dir = (
        Path(data_dir_value).expanduser()
        if data_dir_value
        else Path(platformdirs.user_data_dir(APP_NAME))
    )

    url = database_url or env.get("CATENARY_DATABASE_URL") or data.get("database", {}).get("url")
    if url is not None and not isinstance(url, str):
        raise UserError(f"{config_path}: database.url must be a string, not {url!r}")
    if not url:
        url = f"sqlite:///{data_dir / 'catenary.sqlite'}"

    database = data.get("database", {})
    timeout = _seconds(
        config_path,
        "connect_timeout_s",
        database.get("connect_timeout_s", DEFAULT_CONNECT_TIMEOUT_S),
    )
    statement_timeout = (
        _seconds(config_path, "statement_timeout_s", database["statement_timeout_s"])
        if "statement_timeout_s" in database
        else None
    )

    disabled = data.get("plugins", {}).get("disabled", [])
    if not isinstance(disabled, list) or not all(isinstance(x, str) for x in disabled):
        raise UserError(f"{config_path}: plugins.disabled must be a list of plugin names")

    return Settings(
        database_url=url,
        data_dir=data_dir,
        config_path=config_path,
        connect_timeout_s=timeout,
        statement_timeout_s=statement_timeout,
        disabled_plugins=tuple(disabled),
        store=_store(config_path, data.get("store", {})),
        sections={k: v for k, v in data.items() if k not in KNOWN_KEYS},
    )
