"""The ``webhook`` notifier: the alert as JSON, POSTed to a URL (``urllib.request``).

Settings (``[notifications.channels.settings]``)::

    url = "https://maintenance.example.org/hooks/catenary"   # or url_env = "VARIABLE"
    headers = { "X-Source" = "catenary" }                  # optional
    headers_env = { "Authorization" = "CATENARY_HOOK_AUTH" }  # optional: values from variables
    timeout = 10                                           # seconds

The body is ``{"event": "alert", "text": <one-line summary>, "alert": <the alert's fields>}``
in UTF-8. Only a 2xx answer is success: any other status, a redirect included, is a failure
to retry. Error messages name the URL's scheme and host only (its path or query may be a
secret).
"""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from collections.abc import Mapping
from typing import Any
from urllib.parse import urlsplit

from catenary.plugins import AlertRecord
from catenary_notify import message
from catenary_notify.settings import (
    SettingsError,
    check_keys,
    from_environment,
    seconds,
    text,
    variable_name,
)

NAME = "webhook"
KEYS = {"url", "url_env", "headers", "headers_env", "timeout"}
DEFAULT_TIMEOUT_S = 10.0


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """Refuse redirects: urllib would repeat a POST as a GET without its body."""

    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None


_OPENER = urllib.request.build_opener(_NoRedirect)


def _http_url(url: str, key: str) -> str:
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if port is not None and not 0 < port < 65536:
        raise SettingsError(f"{NAME} settings: {key} has a port that is not 1-65535")
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise SettingsError(f"{NAME} settings: {key} must be an http(s) URL, not {_where(url)!r}")
    return url


def _url(settings: Mapping[str, Any]) -> str:
    if "url" in settings:
        return _http_url(text(NAME, settings, "url"), "url")
    return _http_url(from_environment(NAME, "url_env", settings["url_env"]), "url (url_env)")


def _where(url: str) -> str:
    parts = urlsplit(url)
    return f"{parts.scheme}://{parts.hostname or ''}{f':{parts.port}' if parts.port else ''}"


def check(settings: Mapping[str, Any]) -> None:
    """Refuse settings ``send`` would refuse whatever the environment (``Notifier.check``): the
    keys, the URL (or the name of its variable), the headers and the timeout."""
    check_keys(NAME, settings, KEYS)
    if ("url" in settings) == ("url_env" in settings):
        raise SettingsError(f"{NAME} settings: give url or url_env (one of them)")
    if "url" in settings:
        _http_url(text(NAME, settings, "url"), "url")
    else:
        variable_name(NAME, "url_env", settings["url_env"])
    for key in ("headers", "headers_env"):
        table = settings.get(key, {})
        if not isinstance(table, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in table.items()
        ):
            raise SettingsError(f"{NAME} settings: {key} must be a table of strings")
    for variable in settings.get("headers_env", {}).values():
        variable_name(NAME, "headers_env", variable)
    seconds(NAME, settings, "timeout", DEFAULT_TIMEOUT_S)


def _headers(settings: Mapping[str, Any]) -> dict[str, str]:
    headers = {"Content-Type": "application/json; charset=utf-8", "User-Agent": "catenary"}
    headers.update(settings.get("headers", {}))
    for header, variable in settings.get("headers_env", {}).items():
        headers[header] = from_environment(NAME, "headers_env", variable)
    return headers


def payload(alert: AlertRecord) -> bytes:
    """The JSON body of one alert."""
    document = {"event": "alert", "text": message.summary(alert), "alert": alert.as_json()}
    return json.dumps(document, ensure_ascii=False).encode()


def send(alert: AlertRecord, settings: Mapping[str, Any]) -> None:
    """POST ``alert``; raise unless the server answers 2xx within the timeout."""
    check(settings)
    url = _url(settings)
    headers = _headers(settings)
    timeout_s = seconds(NAME, settings, "timeout", DEFAULT_TIMEOUT_S)
    request = urllib.request.Request(url, data=payload(alert), headers=headers, method="POST")
    try:
        with _OPENER.open(request, timeout=timeout_s) as response:
            status = response.status
            reason = response.reason
    except urllib.error.HTTPError as exc:
        status, reason = exc.code, exc.reason
        exc.close()
    except urllib.error.URLError as exc:
        raise ConnectionError(f"{_where(url)}: {exc.reason}") from None
    except TimeoutError:
        raise TimeoutError(f"{_where(url)}: no answer within {timeout_s:g} s") from None
    if not 200 <= status < 300:
        raise RuntimeError(f"{_where(url)} answered HTTP {status} {reason}")
