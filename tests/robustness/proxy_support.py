"""A TCP proxy on 127.0.0.1 that a test freezes or cuts: a database that goes silent or
vanishes, without touching the shared server behind it."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from urllib.parse import urlsplit, urlunsplit


class Proxy:
    """Forwards each connection to ``127.0.0.1:port`` to ``target``.

    ``freeze()``: stop forwarding, every socket kept open (a server that is there and silent);
    ``cut()``: close every socket and close new connections at once (a server that vanished);
    ``cut_on(pattern)``, ``freeze_on(pattern)``: cut or freeze as soon as a client sends bytes
    holding ``pattern``, before they reach the server; ``restore()``: forward again.
    """

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        self._sockets: list[socket.socket] = []
        self._lock = threading.Lock()
        self._flowing = threading.Event()
        self._flowing.set()
        self._cut = False
        self._trigger: tuple[bytes, Callable[[], None]] | None = None
        threading.Thread(target=self._accept, daemon=True).start()

    def url(self, url: str) -> str:
        """``url`` with its host and port replaced by the proxy's (user and password kept)."""
        parts = urlsplit(url)
        user = parts.netloc.rpartition("@")[0]
        netloc = f"{user}@127.0.0.1:{self.port}" if user else f"127.0.0.1:{self.port}"
        return urlunsplit(parts._replace(netloc=netloc))

    def freeze(self) -> None:
        self._flowing.clear()

    def cut(self) -> None:
        with self._lock:
            self._cut = True
            for sock in self._sockets:
                _close(sock)
            self._sockets.clear()
        self._flowing.set()

    def cut_on(self, pattern: bytes) -> None:
        self._trigger = (pattern, self.cut)

    def freeze_on(self, pattern: bytes) -> None:
        self._trigger = (pattern, self.freeze)

    def restore(self) -> None:
        with self._lock:
            self._cut = False
            self._trigger = None
        self._flowing.set()

    def close(self) -> None:
        self.cut()
        _close(self._listener)

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            with self._lock:
                if self._cut:
                    _close(client)
                    continue
                try:
                    server = socket.create_connection(self.target)
                except OSError:
                    _close(client)
                    continue
                self._sockets += [client, server]
            threading.Thread(target=self._pump, args=(client, server, True), daemon=True).start()
            threading.Thread(target=self._pump, args=(server, client, False), daemon=True).start()

    def _pump(self, source: socket.socket, sink: socket.socket, upstream: bool) -> None:
        while True:
            try:
                data = source.recv(65536)
            except OSError:
                data = b""
            trigger = self._trigger
            if upstream and trigger is not None and trigger[0] in data:
                self._trigger = None
                trigger[1]()
            self._flowing.wait()
            if not data or self._cut:
                _close(sink)
                return
            try:
                sink.sendall(data)
            except OSError:
                _close(source)
                return


def _close(sock: socket.socket) -> None:
    with suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()


@contextmanager
def proxy_for(url: str) -> Iterator[Proxy]:
    """A ``Proxy`` in front of the server of the database ``url``, closed on exit."""
    parts = urlsplit(url)
    proxy = Proxy((parts.hostname or "127.0.0.1", parts.port or 5432))
    try:
        yield proxy
    finally:
        proxy.close()
