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
  ``[paths] data_dir``, else the per-user data directory.

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
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import platformdirs

from catenary.errors import UserError

APP_NAME = "catenary"
#: How long connecting to a database server may take before the command gives up, in seconds.
DEFAULT_CONNECT_TIMEOUT_S = 10.0
KNOWN_KEYS: dict[str, set[str]] = {
    "database": {"url", "connect_timeout_s", "statement_timeout_s"},
    "paths": {"data_dir"},
    "plugins": {"disabled"},
}
CORE_SECTIONS = frozenset(
    {"limits", "maintenance", "notifications", "processing", "processors", "record", "scheduler"}
)
"""Sections other modules of the core read, each checking its keys as it reads them: [limits]
(``catenary.limits``), [maintenance] (alert rules), [notifications], [scheduler], [record]
(``catenary record``), [processing] and [processors.NAME] (``catenary process``)."""


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
class Settings:
    """The resolved settings of one invocation."""

    database_url: str
    data_dir: Path
    config_path: Path | None = None
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S
    statement_timeout_s: float | None = None
    disabled_plugins: tuple[str, ...] = ()
    sections: Mapping[str, Any] = field(default_factory=dict)


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
        sections={k: v for k, v in data.items() if k not in KNOWN_KEYS},
    )
