"""The web service's settings: ``[web]`` of the config file.

    [web]
    secret_key_env = "CATENARY_WEB_SECRET"  # an environment variable holding the cookie key
    session_hours = 12                      # how long a sign-in lasts
    sign_in_attempts = 5                    # failed sign-ins allowed per window...
    sign_in_window_s = 900                  # ...per user name and per client address

Without ``secret_key_env`` the key is a random one kept in ``web-secret`` in the data
directory (made on first start, readable by its owner only), so sessions survive restarts.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catenary.config import Settings, did_you_mean
from catenary.errors import UserError

__all__ = ["WebSettings", "web_settings"]

_KEYS = {"secret_key_env", "session_hours", "sign_in_attempts", "sign_in_window_s"}
SECRET_FILE = "web-secret"
MIN_SECRET_LENGTH = 32
"""The shortest cookie key accepted [characters]."""


@dataclass(frozen=True)
class WebSettings:
    """What the web service needs beyond the database and the store."""

    secret_key: str
    session_s: float = 12 * 3600.0
    sign_in_attempts: int = 5
    sign_in_window_s: float = 900.0


def _number(where: str, key: str, value: object, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise UserError(f"{where}: {key} must be a number from {low:g} to {high:g}, not {value!r}")
    return float(value)


def _stored_secret(data_dir: Path) -> str:
    """The key kept in ``data_dir/web-secret``, made (mode 0600) if there is none."""
    path = data_dir / SECRET_FILE
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        pass
    except OSError as exc:
        raise UserError(f"{path}: cannot make the web service's key: {exc.strerror}") from None
    else:
        with os.fdopen(descriptor, "w") as file:
            file.write(secrets.token_urlsafe(48))
    try:
        secret = path.read_text().strip()
    except OSError as exc:
        raise UserError(f"{path}: cannot read the web service's key: {exc.strerror}") from None
    if len(secret) < MIN_SECRET_LENGTH:
        raise UserError(f"{path}: the key must be at least {MIN_SECRET_LENGTH} characters")
    return secret


def web_settings(settings: Settings, environ: Mapping[str, str] | None = None) -> WebSettings:
    """``[web]`` of ``settings`` (every key optional), checked; secrets from the environment
    (``os.environ`` by default) or the data directory."""
    env = os.environ if environ is None else environ
    where = f"{settings.config_path or 'config'}: [web]"
    section: Any = settings.sections.get("web", {})
    if not isinstance(section, Mapping):
        raise UserError(f"{where} must be a table")
    unknown = sorted(set(section) - _KEYS)
    if unknown:
        raise UserError(f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], _KEYS)}")
    variable = section.get("secret_key_env")
    if variable is None:
        secret = _stored_secret(settings.data_dir)
    elif not isinstance(variable, str) or not variable:
        raise UserError(f"{where}: secret_key_env must name an environment variable")
    else:
        secret = env.get(variable, "")
        if len(secret) < MIN_SECRET_LENGTH:
            raise UserError(
                f"{where}: environment variable {variable} must hold a key of at least "
                f"{MIN_SECRET_LENGTH} characters"
            )
    hours = _number(where, "session_hours", section.get("session_hours", 12), 0.1, 24 * 90)
    attempts = _number(where, "sign_in_attempts", section.get("sign_in_attempts", 5), 1, 1000)
    window = _number(where, "sign_in_window_s", section.get("sign_in_window_s", 900), 1, 86400)
    return WebSettings(secret, hours * 3600.0, int(attempts), window)
