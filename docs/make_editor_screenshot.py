"""Make docs/editor_scene.png: the editor on the demo's custom-character scene, in headless Chromium.

``PYTHONPATH=. python docs/make_editor_screenshot.py [--out docs/editor_scene.png]`` runs the demo
into a temporary folder (``workflows.demo.run_demo``), opens ``character/scene.json`` in the editor
on a free loopback port and screenshots it with Debian's Chromium (``/usr/bin/chromium``).

``--drag`` (docs/editor_drag.png): the demo's SMPL scene instead, after a drag of a new left-wrist handle
50 cm up (the case of docs/editing.md); the status line shows what the drag relaxed and the conflict report.

``--animation ANIMATION.json [--frame N]`` (docs/editor_timeline.png): the editor with its timeline on an
animation of ``smplik scene animate`` (docs/editor_timeline.png: GVHMR's ``hmr4d_results.pt`` of a real video,
``--fps 30``), at frame N (default: the second keyframe), with its keyframe handles.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def main() -> None:
    import torch
    from playwright.sync_api import sync_playwright
    from test_editor_browser import CHROMIUM, CHROMIUM_ARGS, body_pixels

    from smplik.solver import IKSolver
    from workflows.demo import run_demo
    from workflows.editor.app import EditorApp
    from workflows.editor.state import EditorState

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--drag", action="store_true", help="Screenshot a wrist drag on the SMPL scene.")
    parser.add_argument("--animation", type=Path, default=None, help="Screenshot the timeline on this animation.")
    parser.add_argument("--frame", type=int, default=None, help="Frame of --animation (default: 2nd keyframe).")
    args = parser.parse_args()
    if args.out is None:
        name = "editor_timeline.png" if args.animation else "editor_drag.png" if args.drag else "editor_scene.png"
        args.out = ROOT / "docs" / name
    torch.set_num_threads(1)
    solver = IKSolver.load()
    with tempfile.TemporaryDirectory() as tmp:
        if args.animation is not None:
            from workflows.editor.timeline import AnimationTimeline
            from workflows.editor.timeline_app import AnimationEditorApp

            timeline = AnimationTimeline.open(args.animation, solver)
            app = AnimationEditorApp(timeline, solver, port=0)
            keys = timeline.keyframes()
            app.goto(args.frame if args.frame is not None else keys[min(1, len(keys) - 1)])
        else:
            run_demo(Path(tmp), solver)
            scene = Path(tmp) / ("smpl" if args.drag else "character") / "scene.json"
            app = EditorApp(EditorState.open(scene, solver), port=0)
        if args.drag:
            drag_left_wrist(app)
        try:
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, timeout=60_000)
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(app.url)
                page.wait_for_selector("canvas", timeout=60_000)
                deadline = time.monotonic() + 120
                while body_pixels(page.screenshot(timeout=60_000)) < 5000 and time.monotonic() < deadline:
                    time.sleep(1.0)
                close = page.locator(".mantine-Notification-closeButton")
                if close.count():
                    close.first.click()
                time.sleep(5.0)  # let the scene finish fading in
                args.out.write_bytes(page.screenshot(timeout=60_000))
                browser.close()
        finally:
            app.stop()
    print(f"wrote {args.out}")


def drag_left_wrist(app, raise_m: float = 0.5) -> None:  # noqa: ANN001 - EditorApp
    """Add a left-wrist position handle and drag it up by ``raise_m`` in ten steps (one gesture)."""
    import numpy as np

    state = app.state
    k = state.add_effector("left_wrist", "position")
    start = state.view().joints[state.character().effectors[k].joint].copy()
    for dy in np.linspace(raise_m / 10, raise_m, 10):
        state.move_effector(k, position=start + np.array([0.0, dy, 0.0]))
    state.end_gesture()
    app.refresh()
    app._set_status(state.drag_summary())


if __name__ == "__main__":
    main()
