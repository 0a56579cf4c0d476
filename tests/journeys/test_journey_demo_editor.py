"""Journey: ``smplik demo --out demo_out``, then what its printout tells the user to open: the pictures, the
scenes in the editor (``smplik edit demo_out/character/scene.json``: the SMPL scene and the custom-character
scene), and the export command it names.

The editor runs as the user starts it, a separate ``smplik edit SCENE --port 0`` process; the test reads the URL
it prints and fetches the page with its token, as a browser does. A scene with a custom character once crashed
the editor before it printed its URL (its skeleton record, holding a dict, was a cache key).
"""

from __future__ import annotations

import queue
import re
import signal
import subprocess
import threading
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the editor needs viser (pip install -e '.[edit]')")

REPO = Path(__file__).resolve().parents[2]
HANG_S = 1200  # guards against a hang only, never a speed check
PRINTED_PATH = re.compile(r"^\s+(\S+\.(?:json|png|bvh|npz))\s", re.MULTILINE)


def printed_files(printout: str) -> list[str]:
    """The files the demo's printout lists, one per line (``  path  what it is``)."""
    return PRINTED_PATH.findall(printout)


def test_every_file_the_demo_lists_exists_and_opens(demo):
    from PIL import Image

    from smplik.data.bvh import read_bvh
    from workflows.scene import load_scene

    files = printed_files(demo.printout)
    kinds = {Path(f).suffix for f in files}
    assert {".json", ".png", ".bvh", ".npz"} <= kinds, demo.printout
    for name in files:
        path = demo.cwd / name  # printed relative to where the user ran the demo
        assert path.is_file(), f"the printout lists {name}, which does not exist"
        if path.suffix == ".png":
            with Image.open(path) as image:
                assert min(image.size) >= 100
        elif path.suffix == ".bvh":
            assert read_bvh(path).num_frames >= 1
        elif path.suffix == ".json":
            assert load_scene(path).characters


class EditorProcess:
    """``smplik edit ARGS`` in its own process (cwd: where the user is); :attr:`url` is what it prints."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self.url = self._wait_for_url()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put(None)  # the process closed its output: it ended

    def _wait_for_url(self) -> str | None:
        while True:
            try:
                line = self._lines.get(timeout=HANG_S)
            except queue.Empty:
                return None
            if line is None:
                return None
            match = re.search(r"(http://127\.0\.0\.1:\d+/\?token=\S+)", line)
            if match:
                return match.group(1)

    def failure(self) -> str:
        self.stop()
        return f"smplik edit ended without its URL (exit {self.proc.returncode}):\n{self.proc.stderr.read()}"

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)  # Ctrl+C, as the printed line says
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@pytest.mark.slow
def test_the_editor_opens_each_scene_the_demo_writes(demo, smplik_process):
    printed = demo.printed_command("edit")
    assert printed == ["demo_out/character/scene.json"], demo.printout  # the custom-character scene
    for args in (printed, ["demo_out/smpl/scene.json"]):
        editor = EditorProcess(smplik_process("edit", *args, "--port", "0", cwd=demo.cwd))
        try:
            assert editor.url is not None, editor.failure()
            with urllib.request.urlopen(editor.url, timeout=120) as response:
                assert response.status == 200
                assert b"<html" in response.read().lower()
            without_token = editor.url.split("?")[0]
            with pytest.raises(urllib.error.HTTPError) as refused:
                urllib.request.urlopen(without_token, timeout=120)
            assert refused.value.code == 403
        finally:
            editor.stop()


def test_the_editor_draws_each_character_where_the_scene_puts_it(shipped_solver, demo):
    """What the editor draws: the posed body at the scene's solved joints, and a custom character's own
    skeleton on that body (the part that crashed)."""
    import torch

    from workflows.editor.state import EditorState
    from workflows.scene import character_joints, load_scene

    torch.set_num_threads(1)
    solver = shipped_solver
    for name in ("smpl", "character"):
        path = demo.out / name / "scene.json"
        scene = load_scene(path)
        state = EditorState(scene, solver, path=path)
        for i, character in enumerate(scene.characters):
            joints = character_joints(character)  # (24, 3) the solved pose, character space
            view = state.view(i)
            np.testing.assert_allclose(view.joints, joints, atol=2e-3)
            lo, hi = view.vertices.min(0), view.vertices.max(0)
            assert np.all(lo <= joints.min(0) + 1e-3) and np.all(hi >= joints.max(0) - 1e-3)  # the mesh wraps them
            bones = state.skeleton_bones(i)
            if character.skeleton is None:
                assert bones is None
                continue
            assert name == "character" and bones is not None and len(bones) >= 20
            points = bones.reshape(-1, 3)
            # the custom skeleton stands on the body: its feet at the body's, centred on it across the floor
            assert abs(points[:, 1].min() - joints[:, 1].min()) < 0.05
            centre = (points.min(0) + points.max(0)) / 2 - (joints.min(0) + joints.max(0)) / 2
            assert np.linalg.norm(centre[[0, 2]]) < 0.05, centre


def test_the_export_command_the_demo_prints_writes_files_that_open(demo, smplik):
    import pygltflib

    from smplik.data.bvh import read_bvh

    args = demo.printed_command("scene export")
    run = smplik("scene", "export", *args, cwd=demo.cwd)
    out = demo.cwd / args[args.index("--out") + 1]
    written = re.findall(r"wrote (\S+)", run.output)
    assert {Path(w).suffix for w in written} == {".bvh", ".glb"}, run.output
    for name in written:
        path = demo.cwd / name if not Path(name).is_absolute() else Path(name)
        assert path.parent.resolve() == out.resolve() and path.is_file()
        if path.suffix == ".bvh":
            assert read_bvh(path).num_joints == 24  # an SMPL character's skeleton
        else:
            gltf = pygltflib.GLTF2().load(str(path))
            assert len(gltf.skins) == 1 and len(gltf.skins[0].joints) == 24 and gltf.meshes


def test_the_readme_caption_tells_what_the_demo_prints(demo):
    """The README's picture is the demo's ``smpl/scene.png``; its caption's effector count is the demo's."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    caption = re.search(r"each reduced to (\d+) effectors", readme)
    assert caption, "the README's demo caption no longer says how many effectors"
    smpl_part = demo.printout.split("2. ")[0]
    counts = {int(n) for n in re.findall(r"person_\d+: (\d+) effectors", smpl_part)}
    assert counts == {int(caption.group(1))}, demo.printout
