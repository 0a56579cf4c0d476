"""Who may drive the editor: a per-run token and the editor's own origin, checked at viser's handshake.

A web page of any site the user visits can open a WebSocket to ``127.0.0.1`` (browsers do not apply
the same-origin policy to WebSockets), so without a check any page could edit the scene, press Save
and Export, or ask viser for a public share tunnel. Like Jupyter, ``smplik edit`` therefore:

* makes a random token per run (:func:`secrets.token_urlsafe`) and prints the URL with it
  (``http://127.0.0.1:8080/?token=...``); the page request with the right token gets a cookie
  (``HttpOnly``, ``SameSite=Strict``, named after the port) so the viser client's WebSocket, which drops
  the query string, carries the token too; a raw client may pass ``?token=`` itself;
* accepts an HTTP request or a WebSocket only when the ``Host`` header names this port on a loopback
  name or an IP literal (a DNS-rebinding page has its own domain name there), and the token matches;
* accepts a WebSocket only when its ``Origin`` is the editor's own (``http://`` + the ``Host`` it
  asked for): ``Origin: http://evil.example.com``, ``Origin: null`` (a sandboxed frame, a local HTML
  file), another local port, or no ``Origin`` at all are refused with HTTP 403;
* sends ``Referrer-Policy: no-referrer`` with every HTTP response, so the token in the page's URL never
  leaves in a ``Referer`` header;
* answers a request websockets cannot parse (a method other than GET, HTTP/1.0, a header line over
  8 KiB or more than 128 headers, a line without a colon, a body) with HTTP 400 before closing
  (websockets itself closes without a word): :func:`answer_unparsed_requests`.

The check wraps the ``process_request`` hook that viser passes to :func:`websockets.asyncio.server.serve`
(viser >= 1.1 serves its page and its WebSocket from that one server): :func:`guarded_serve` replaces
that function only while viser starts its server, and :class:`~workflows.editor.app.EditorApp`
refuses to run when the hook was not reached (a viser that starts its server differently), so the
editor never runs unguarded.
"""

from __future__ import annotations

import contextlib
import hmac
import http
import ipaddress
import logging
import re
import secrets
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from http.cookies import CookieError, SimpleCookie
from typing import Any
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger(__name__)
TOKEN_PARAM = "token"
REFERRER_POLICY = "no-referrer"
"""Sent with every HTTP response: the page's URL holds the token, so no request it makes (a link, an image,
a script) may carry that URL to another site in its ``Referer`` header."""
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "[::1]")
_PATCH_LOCK = threading.Lock()


def cookie_name(port: int) -> str:
    """The token cookie of the editor on ``port`` (cookies are shared by every port of a host)."""
    return f"smplik_editor_token_{int(port)}"


def _host_name_ok(name: str) -> bool:
    """A loopback name or an IP literal (never a domain name a DNS-rebinding page could use); an IPv6
    literal in brackets (``[::1]``, not ``[::1`` or ``::1``)."""
    if name in LOOPBACK_NAMES:
        return True
    if name.startswith("[") != name.endswith("]") or (":" in name and not name.startswith("[")):
        return False
    try:
        ipaddress.ip_address(name[1:-1] if name.startswith("[") else name)
        return True
    except ValueError:
        return False


@dataclass(frozen=True)
class AccessGuard:
    """The per-run token and the checks of one request (see the module docstring)."""

    token: str = field(default_factory=lambda: secrets.token_urlsafe(24))

    def malformed(self, headers: Any) -> str | None:
        """Why the request's headers are malformed (answered 400, never a server error), or None: a header
        that must appear once (``Host``, ``Origin``, ``Upgrade``) given several times."""
        for name in ("Host", "Origin", "Upgrade"):
            values = headers.get_all(name) if hasattr(headers, "get_all") else [headers.get(name)]
            if len(values) > 1:
                return f"{len(values)} {name} headers (at most one is allowed)"
        return None

    def refusal(self, path: str, headers: Any, port: int) -> str | None:
        """Why the request (``path`` with query, its ``headers``) to the editor on ``port`` is refused, or None."""
        host = str(headers.get("Host") or "")
        name, _, host_port = host.rpartition(":")
        if not name or host_port != str(port) or not _host_name_ok(name.lower()):
            return f"Host {host[:80]!r} is not this editor's address"
        if not self._token_ok(path, headers, port):
            return "missing or wrong token: open the URL that smplik edit printed (it ends in ?token=...)"
        if str(headers.get("Upgrade") or "").lower() == "websocket":
            origin = headers.get("Origin")
            if origin is None:
                return "a WebSocket without an Origin header"
            if str(origin).lower().rstrip("/") != f"http://{host}".lower():
                return f"a WebSocket from origin {str(origin)[:80]!r}, not this editor's page"
        return None

    def token_in_query(self, path: str) -> bool:
        values = parse_qs(urlsplit(path).query).get(TOKEN_PARAM, [])
        return any(hmac.compare_digest(v.encode(), self.token.encode()) for v in values)

    def _token_ok(self, path: str, headers: Any, port: int) -> bool:
        if self.token_in_query(path):
            return True
        for raw in headers.get_all("Cookie") if hasattr(headers, "get_all") else [headers.get("Cookie") or ""]:
            try:
                jar = SimpleCookie(str(raw))
            except CookieError:
                continue
            morsel = jar.get(cookie_name(port))
            if morsel is not None and hmac.compare_digest(morsel.value.encode(), self.token.encode()):
                return True
        return False

    def wrap(self, inner: Callable[..., Any] | None) -> Callable[..., Any]:
        """A websockets ``process_request`` that refuses (403) what :meth:`refusal` names, else runs ``inner``
        (viser's page server) and sets the token cookie on a page served to a request carrying the token."""

        def process_request(connection: Any, request: Any) -> Any:
            port = int(connection.local_address[1])
            try:
                bad = self.malformed(request.headers)
                reason = None if bad else self.refusal(request.path, request.headers, port)
            except (LookupError, ValueError, TypeError, UnicodeError) as exc:  # a header websockets cannot give once
                bad, reason = f"malformed request headers ({type(exc).__name__})", None
            if bad is not None:
                log.warning("smplik editor: refused a malformed request for %s: %s",
                            str(request.path).split("?")[0][:80], bad)
                refused = connection.respond(http.HTTPStatus.BAD_REQUEST, f"smplik editor: {bad}.\n")
                refused.headers["Referrer-Policy"] = REFERRER_POLICY
                return refused
            if reason is not None:
                log.warning("smplik editor: refused a request for %s: %s", request.path.split("?")[0][:80], reason)
                refused = connection.respond(http.HTTPStatus.FORBIDDEN, f"smplik editor: {reason}.\n")
                refused.headers["Referrer-Policy"] = REFERRER_POLICY
                return refused
            response = inner(connection, request) if inner is not None else None
            if response is not None:
                response.headers["Referrer-Policy"] = REFERRER_POLICY  # the page's URL carries the token
                if self.token_in_query(request.path):
                    response.headers["Set-Cookie"] = (f"{cookie_name(port)}={self.token}; Path=/; HttpOnly; "
                                                      "SameSite=Strict")
            return response

        return process_request


def answer_unparsed_requests(base: type) -> type:
    """A websockets ``ServerConnection`` subclass (of ``base``) whose protocol answers an HTTP request it
    cannot parse with ``400 Bad Request`` before the end of the stream (websockets sends only the end)."""
    from websockets.exceptions import InvalidMessage
    from websockets.protocol import CONNECTING

    class AnsweringConnection(base):  # type: ignore[misc, valid-type]
        def __init__(self, protocol: Any, *args: Any, **kwargs: Any) -> None:
            super().__init__(protocol, *args, **kwargs)
            send_eof = protocol.send_eof

            def answer_then_eof() -> None:
                exc = protocol.handshake_exc
                if protocol.state is CONNECTING and isinstance(exc, InvalidMessage) and not protocol.writes \
                        and not isinstance(exc.__cause__, EOFError):  # a request it could not parse, no answer
                    reason = str(exc.__cause__ or exc).encode("ascii", "backslashreplace").decode()[:200]
                    reason = re.sub(rf"{TOKEN_PARAM}=[^&\s]*", f"{TOKEN_PARAM}=...", reason)  # never log the token
                    refused = protocol.reject(http.HTTPStatus.BAD_REQUEST,
                                              f"smplik editor: malformed HTTP request ({reason}).\n")
                    refused.headers["Referrer-Policy"] = REFERRER_POLICY
                    protocol.writes.append(refused.serialize())
                    log.warning("smplik editor: refused a malformed request: %s", reason)
                send_eof()

            protocol.send_eof = answer_then_eof

    return AnsweringConnection


@contextlib.contextmanager
def guarded_serve(guard: AccessGuard) -> Iterator[list[int]]:
    """While open, every :func:`websockets.asyncio.server.serve` call gets ``guard``'s ``process_request``
    around its own; yields a list that records one entry per guarded call (empty: the hook was not reached)."""
    import websockets.asyncio.server as ws_server

    calls: list[int] = []
    with _PATCH_LOCK:
        original = ws_server.serve

        def serve(*args: Any, **kwargs: Any) -> Any:
            kwargs["process_request"] = guard.wrap(kwargs.get("process_request"))
            kwargs["create_connection"] = answer_unparsed_requests(kwargs.get("create_connection")
                                                                   or ws_server.ServerConnection)
            calls.append(1)
            return original(*args, **kwargs)

        ws_server.serve = serve  # type: ignore[assignment, misc]
        try:
            yield calls
        finally:
            ws_server.serve = original  # type: ignore[misc]
