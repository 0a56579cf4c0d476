"""Who may drive the editor (:mod:`workflows.editor.access`): only its own page, opened with the token.

A real browser (Debian's Chromium through playwright, as in ``test_editor_browser.py``) loads a page of
another origin, served by a second HTTP server on 127.0.0.1, that tries to open the editor's WebSocket:
refused, even after the browser opened the editor (so the token cookie exists) and even with the token
in the URL. Raw WebSocket clients (the ``websockets`` library, what any local program can send) with
``Origin: http://evil.example.com``, ``Origin: null``, no Origin, another port's origin, a missing or
wrong token, a rebinding ``Host``: refused with HTTP 403. The editor's own page with the token works.
Save/Export outside the allowed folders and viser's share-URL request are refused. Loopback only.
"""

from __future__ import annotations

import http.server
import json
import threading
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from editor_helpers import CHROMIUM, CHROMIUM_ARGS, WAIT_S, wait_for, ws_attempt

pytest.importorskip("viser")


@pytest.fixture(scope="module")
def app(shipped_solver, tmp_path_factory):
    import torch

    from workflows.editor.app import EditorApp
    from workflows.editor.state import EditorState, fresh_scene

    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("editor")
    state = EditorState(fresh_scene(), shipped_solver, path=folder / "scene.json")
    editor = EditorApp(state, host="127.0.0.1", port=0)
    yield editor
    editor.stop()


def test_raw_websocket_clients_need_the_token_and_the_editors_origin(app):
    port, token = app.port, app.access.token
    own = f"http://127.0.0.1:{port}"
    with_token = f"ws://127.0.0.1:{port}/?token={token}"
    assert ws_attempt(with_token, own) == "open"
    assert ws_attempt(f"ws://localhost:{port}/?token={token}", f"http://localhost:{port}") == "open"
    for origin in ("http://evil.example.com", "null", None, f"http://127.0.0.1:{port + 1}", f"https://127.0.0.1:{port}",
                   f"http://localhost:{port}"):  # localhost is not the origin of a request made to 127.0.0.1
        assert ws_attempt(with_token, origin) == "refused 403", origin
    for url in (f"ws://127.0.0.1:{port}/", f"ws://127.0.0.1:{port}/?token=wrong", f"ws://127.0.0.1:{port}/?token="):
        assert ws_attempt(url, own) == "refused 403", url
    # DNS rebinding: a page of evil.example.com resolved to 127.0.0.1 sends its own name as Host and Origin
    assert handshake_status(port, f"/?token={token}", f"evil.example.com:{port}", f"http://evil.example.com:{port}") \
        == 403
    assert handshake_status(port, f"/?token={token}", f"127.0.0.1:{port}", own) == 101  # the same request, own Host


def handshake_status(port: int, path: str, host: str, origin: str) -> int:
    """The HTTP status of a WebSocket opening handshake with the given ``Host`` and ``Origin`` headers."""
    import http.client

    import viser

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=WAIT_S)
    try:
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        for name, value in (("Host", host), ("Origin", origin), ("Upgrade", "websocket"), ("Connection", "Upgrade"),
                            ("Sec-WebSocket-Key", "dGhlIHNhbXBsZSBub25jZQ=="), ("Sec-WebSocket-Version", "13"),
                            ("Sec-WebSocket-Protocol", f"viser-v{viser.__version__}")):
            conn.putheader(name, value)
        conn.endheaders()
        return conn.getresponse().status
    finally:
        conn.close()


def test_the_page_needs_the_token_and_sets_a_strict_cookie(app):
    with pytest.raises(urllib.error.HTTPError) as info:
        urllib.request.urlopen(f"http://127.0.0.1:{app.port}/", timeout=WAIT_S)
    assert info.value.code == 403 and b"token" in info.value.read()
    with urllib.request.urlopen(app.url, timeout=WAIT_S) as response:
        assert response.status == 200 and b"<html" in response.read().lower()
        cookie = response.headers["Set-Cookie"]
    assert cookie.startswith(f"smplik_editor_token_{app.port}={app.access.token};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert app.url.startswith("http://127.0.0.1:") and app.url.endswith(f"/?token={app.access.token}")


def test_share_url_requests_are_refused(app):
    assert app.server.request_share_url() is None
    assert "share URLs" in app.status


def test_save_and_export_write_only_in_the_allowed_folders(app, tmp_path):
    outside = tmp_path / "outside"
    for field, button, target in ((app.path_text, app.save, outside / "scene.json"),
                                  (app.export_text, app.export, outside / "export"),
                                  (app.path_text, app.save, app.write_dirs[0] / ".." / "escape.json")):
        field.value = str(target)
        app._run(button)
        assert "outside the folders the editor may write in" in app.status
    assert not outside.exists() and not (app.write_dirs[0].parent / "escape.json").exists()
    app.path_text.value = str(app.write_dirs[0] / "sub" / "scene.json")
    (app.write_dirs[0] / "sub").mkdir()
    app._run(app.save)
    assert json.loads((app.write_dirs[0] / "sub" / "scene.json").read_text())["format"] == "smplik-scene"


FOREIGN_PAGE = """<!doctype html><html><body><script>
window.results = {};
function attempt(name, url) {
  const ws = new WebSocket(url, ["viser-v%(version)s"]);
  ws.onopen = () => { window.results[name] = "open"; };
  ws.onmessage = () => { window.results[name] = "message"; };
  ws.onerror = () => { if (!window.results[name]) window.results[name] = "error"; };
  ws.onclose = () => { if (!window.results[name]) window.results[name] = "closed"; };
}
attempt("no_token", "ws://127.0.0.1:%(port)d/");
attempt("with_token", "ws://127.0.0.1:%(port)d/?token=%(token)s");
attempt("localhost", "ws://localhost:%(port)d/");
</script></body></html>"""


@pytest.mark.skipif(not Path(CHROMIUM).is_file(), reason="Debian chromium is not installed (apt-get install chromium)")
def test_a_page_of_another_origin_cannot_open_the_editor_in_a_real_browser(app):
    import viser
    from playwright.sync_api import sync_playwright

    page_html = (FOREIGN_PAGE % {"version": viser.__version__, "port": app.port, "token": app.access.token}).encode()

    class Foreign(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(page_html)))
            self.end_headers()
            self.wfile.write(page_html)

        def log_message(self, *args) -> None:
            pass

    foreign = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Foreign)
    threading.Thread(target=foreign.serve_forever, daemon=True).start()
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True,
                                         timeout=30_000)
            try:
                context = browser.new_context()
                page = context.new_page()
                page.set_default_timeout(WAIT_S * 1000)
                # the editor's own page with the token: the viser client connects (its GUI appears)
                page.goto(app.url)
                page.get_by_role("button", name="Save").wait_for()
                wait_for(lambda: len(app.server.get_clients()) >= 1, "the editor page's connection")
                clients = set(app.server.get_clients())
                # the same browser (the token cookie is set for 127.0.0.1) opens a page of another origin
                other = context.new_page()
                other.goto(f"http://127.0.0.1:{foreign.server_address[1]}/")
                results = wait_for(lambda: (r := other.evaluate("window.results")) and len(r) == 3 and r,
                                   "the foreign page's three attempts")
                assert results == {"no_token": "error", "with_token": "error", "localhost": "error"}, results
                assert set(app.server.get_clients()) == clients  # no new client got in
                # the editor's page keeps working: a reload still connects
                page.reload()
                page.get_by_role("button", name="Save").wait_for()
            finally:
                browser.close()
    finally:
        foreign.shutdown()
