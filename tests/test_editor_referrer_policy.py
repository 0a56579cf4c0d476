"""The editor's page URL carries its token: every HTTP response says ``Referrer-Policy: no-referrer``
(:data:`workflows.editor.access.REFERRER_POLICY`), so a browser never sends that URL to another site in a
``Referer`` header (issue 36). Real HTTP requests to a running editor on 127.0.0.1."""

from __future__ import annotations

import urllib.error
import urllib.request

import pytest

pytest.importorskip("viser")

WAIT_S = 60.0


@pytest.fixture(scope="module")
def app(shipped_solver, tmp_path_factory):
    import torch

    from workflows.editor.app import EditorApp
    from workflows.editor.state import EditorState, fresh_scene

    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("editor")
    editor = EditorApp(EditorState(fresh_scene(), shipped_solver, path=folder / "scene.json"), host="127.0.0.1",
                       port=0)
    yield editor
    editor.stop()


def test_the_page_is_sent_with_no_referrer(app):
    with urllib.request.urlopen(app.url, timeout=WAIT_S) as response:
        assert response.status == 200 and b"<html" in response.read().lower()
        assert response.headers["Referrer-Policy"] == "no-referrer"


def test_a_refused_request_is_sent_with_no_referrer_too(app):
    with pytest.raises(urllib.error.HTTPError) as info:
        urllib.request.urlopen(f"http://127.0.0.1:{app.port}/?token=wrong", timeout=WAIT_S)
    assert info.value.code == 403
    assert info.value.headers["Referrer-Policy"] == "no-referrer"
