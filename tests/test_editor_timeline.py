"""The editor on an animation (:mod:`workflows.editor.timeline_app`): timeline controls driven server-side.

The animation is made by ``smplik scene animate`` from a GVHMR ``hmr4d_results.pt`` in GVHMR's layout
(``animation_fixtures.write_gvhmr_video``). The tests drive the real :class:`AnimationEditorApp` on a viser
server (loopback, port 0): its GUI callbacks (as a browser event reaches them), :meth:`drag` (what a gizmo
runs), :meth:`play_step` (one playback tick: no test waits on a clock). A drag + Apply must change only the
blend window, bit for bit as ``smplik scene edit-keyframe`` does with the same effectors; Save writes that
animation. The last test loads the page in Debian's headless Chromium and uses the timeline controls.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from animation_fixtures import video_motion, write_gvhmr_video, write_phalp_video

from workflows.animation.files import load_animation

pytest.importorskip("viser")

FRAMES = 30
WINDOW = 4


@pytest.fixture(scope="module")
def animation_file(tmp_path_factory, best_solver) -> Path:
    """``smplik scene animate hmr4d_results.pt --fps 30`` (GVHMR world trajectory) -> animation.json."""
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    folder = tmp_path_factory.mktemp("timeline")
    aa, transl = video_motion(FRAMES, seed=11)
    results = write_gvhmr_video(folder, aa, transl)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
        res = CliRunner().invoke(scene_app, ["animate", str(results), "--out", str(folder), "--fps", "30",
                                             "--max-effectors", "3", "--export", ""])
    assert res.exit_code == 0, res.output
    return folder / "animation.json"


@pytest.fixture()
def app(animation_file, best_solver, tmp_path):
    import shutil

    import torch

    from workflows.editor.timeline import AnimationTimeline
    from workflows.editor.timeline_app import AnimationEditorApp

    torch.set_num_threads(1)
    path = tmp_path / "animation.json"
    shutil.copy(animation_file, path)
    timeline = AnimationTimeline.open(path, best_solver, window=WINDOW)
    editor = AnimationEditorApp(timeline, best_solver, host="127.0.0.1", port=0)
    yield editor
    editor.stop()


def user_event(handle, value=None) -> None:
    """Run a GUI handle's callbacks as a person's input does (viser calls them with the event's client)."""
    if value is not None:
        handle._impl.value = value
    for cb in handle._impl.update_cb:
        cb(SimpleNamespace(client=object(), client_id=1, target=handle))


def shown_pose(app) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pose = app.state.scene.characters[0].pose
    return pose.global_orient, pose.body_pose, pose.transl


def test_scrub_shows_that_frames_pose_and_keyframes_are_picked(app):
    tl = app.timeline
    track = tl.animation.tracks[0]
    assert tl.frame == 0 and app.frame_slider.value == 0
    assert (app.frame_slider.min, app.frame_slider.max) == (0, FRAMES - 1)
    before = app._meshes[0].vertices.copy()

    user_event(app.frame_slider, 17)  # the slider, moved by a person
    assert tl.frame == 17
    go, bp, t = shown_pose(app)
    assert np.array_equal(go, track.global_orient[17]) and np.array_equal(bp, track.body_pose[17])
    assert np.array_equal(t, track.transl[17])
    assert np.array_equal(app._meshes[0].vertices, app.state.view(0).vertices)  # what the browser gets
    assert np.abs(app._meshes[0].vertices - before).max() > 0.01  # the body moved
    assert "Frame 17" in app.frame_md.content

    keys = tl.keyframes()
    assert len(keys) >= 2 and keys[0] == 0
    assert app.keyframe_dropdown.options[1:] == tuple(str(k) for k in keys)
    user_event(app.prev_key_button)
    previous = max(k for k in keys if k < 17)
    assert tl.frame == previous and app.keyframe_dropdown.value == str(previous)
    assert app.state.character().effectors == next(k.effectors for k in track.keyframes if k.frame == previous)
    assert len(app._gizmos) == len(app.state.character().effectors)  # the keyframe's handles are shown
    user_event(app.keyframe_dropdown, str(keys[-1]))
    assert tl.frame == keys[-1] and np.array_equal(shown_pose(app)[1], track.body_pose[keys[-1]])
    user_event(app.window_slider, 7)
    assert tl.window == 7
    user_event(app.frame_slider, FRAMES + 5)  # out of range: one line in the status, nothing moves
    assert tl.frame == keys[-1] and "outside the animation's frames 0..29" in app.status


def test_playback_steps_at_the_source_rate_and_never_holds_the_server(app):
    tl = app.timeline
    track = tl.animation.tracks[0]
    assert tl.frame_time == pytest.approx(1 / 30)
    app.goto(FRAMES - 2)
    assert app.play_step() == FRAMES - 1 and app.play_step() == 0  # wraps at the end
    assert np.array_equal(shown_pose(app)[1], track.body_pose[0])
    assert app.play_step(3) == 3 and app.frame_slider.value == 3  # late ticks skip frames

    user_event(app.play_button)  # Play: a background thread ticks; GUI events are still served
    assert app.playing and app.play_button.label == "Pause"
    thread = app._play_thread
    assert thread.daemon and thread is not threading.current_thread() and thread.is_alive()
    user_event(app.frame_slider, 20)  # served while playing (no assertion on which frame playback reached)
    from editor_helpers import ws_attempt

    port = app.port  # a browser connecting while it plays gets the scene: the server is not held
    assert ws_attempt(f"ws://127.0.0.1:{port}/?token={app.access.token}", f"http://127.0.0.1:{port}") == "open"
    assert app.playing and thread.is_alive()
    user_event(app.play_button)  # Pause
    assert not app.playing and app.play_button.label == "Play"
    thread.join(timeout=60)  # a hang guard only
    assert not thread.is_alive()
    frame = tl.frame
    assert np.array_equal(shown_pose(app)[1], track.body_pose[frame])  # the frame shown is the timeline's


def _drag_left_wrist_at(app, frame: int, lift: float = 0.15) -> np.ndarray:
    """Go to ``frame``, add a left-wrist handle (the Add effector button) and drag it up (as its gizmo does)."""
    app.goto(frame)
    app.joint_dropdown.value = "left_wrist"
    app.type_dropdown.value = "position"
    user_event(app.add_button)
    k = len(app.state.character().effectors) - 1
    start = app.state.view().joints[20].copy()
    for dy in np.linspace(lift / 3, lift, 3):
        app.drag(k, start + [0.0, dy, 0.0], np.array([1.0, 0.0, 0.0, 0.0]))
    app._drag_end()
    return start + [0.0, lift, 0.0]


def test_drag_and_apply_change_only_the_window_and_agree_with_edit_keyframe(app, animation_file, best_solver,
                                                                            monkeypatch, tmp_path):
    from typer.testing import CliRunner

    from smplik.effector_schema import save_effector_file
    from workflows.cli import scene_app

    tl = app.timeline
    original = tl.animation.tracks[0]
    frame = tl.keyframes()[1]
    target = _drag_left_wrist_at(app, frame)
    assert app.pending() == ["person_0"]
    assert np.array_equal(tl.animation.tracks[0].body_pose, original.body_pose)  # not applied yet
    effectors = app.state.character().effectors

    user_event(app.apply_button)
    edited = tl.animation.tracks[0]
    lo, hi = max(0, frame - WINDOW), min(FRAMES, frame + WINDOW + 1)
    for name in ("global_orient", "body_pose", "transl"):
        old, new = getattr(original, name), getattr(edited, name)
        assert np.array_equal(new[:lo], old[:lo]) and np.array_equal(new[hi:], old[hi:]), name  # bit for bit
    assert not np.array_equal(edited.body_pose[frame], original.body_pose[frame])
    assert next(k.effectors for k in edited.keyframes if k.frame == frame) == effectors
    assert np.array_equal(shown_pose(app)[1], edited.body_pose[frame])  # the applied pose is shown
    assert np.linalg.norm(app.state.view().joints[20] - target) < 0.05  # the wrist went where it was dragged
    assert app.pending() == [] and "Applied frame" in app.status

    # the same effectors through `smplik scene edit-keyframe`: the same animation, bit for bit
    saved = app.save()
    assert saved == tmp_path / "animation.json"
    effector_file = save_effector_file(tmp_path / "effectors.json", effectors)
    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    res = CliRunner().invoke(scene_app, ["edit-keyframe", str(animation_file), "--frame", str(frame), "--effectors",
                                         str(effector_file), "--window", str(WINDOW), "--out",
                                         str(tmp_path / "cli.json")])
    assert res.exit_code == 0, res.output
    assert json.loads(saved.read_text()) == json.loads((tmp_path / "cli.json").read_text())
    assert np.array_equal(load_animation(saved).tracks[0].body_pose, edited.body_pose)


def test_undo_takes_back_the_frames_edits_then_the_apply(app):
    tl = app.timeline
    original = tl.animation.tracks[0].body_pose.copy()
    frame = tl.keyframes()[1]
    _drag_left_wrist_at(app, frame)
    app.apply()
    applied = tl.animation.tracks[0].body_pose.copy()
    app.goto(frame)
    _drag_left_wrist_at(app, frame, lift=0.3)  # more edits on the frame, not applied
    assert not app.undo_button.disabled
    user_event(app.undo_button)  # the drag
    user_event(app.undo_button)  # the added handle
    assert not app.state.can_undo and np.array_equal(tl.animation.tracks[0].body_pose, applied)
    user_event(app.undo_button)  # the apply
    assert np.array_equal(tl.animation.tracks[0].body_pose, original)
    assert np.array_equal(shown_pose(app)[1], original[tl.frame])
    user_event(app.redo_button)
    assert np.array_equal(tl.animation.tracks[0].body_pose, applied)


def test_moving_to_another_frame_or_saving_applies_the_edits_and_export_writes_the_motion(app, tmp_path):
    from smplik.data.bvh import read_bvh

    tl = app.timeline
    original = tl.animation.tracks[0].body_pose.copy()
    frame = tl.keyframes()[1]
    _drag_left_wrist_at(app, frame)
    user_event(app.next_key_button)  # leaves the frame: its edits are applied first, never lost
    assert not np.array_equal(tl.animation.tracks[0].body_pose[frame], original[frame])
    assert tl.frame == tl.keyframes()[tl.keyframes().index(frame) + 1]
    app.goto(0)
    _drag_left_wrist_at(app, 0)
    user_event(app.save_button)
    assert "Saved" in app.status, app.status
    saved = load_animation(tmp_path / "animation.json").tracks[0]
    assert not np.array_equal(saved.body_pose[0], original[0]) and np.array_equal(saved.body_pose,
                                                                                  tl.animation.tracks[0].body_pose)
    app.export_text.value = str(tmp_path / "export")
    user_event(app.export_button)
    bvh = read_bvh(tmp_path / "export" / "person_0.bvh")
    assert bvh.positions.shape[0] == FRAMES and bvh.frame_time == pytest.approx(1 / 30)
    assert (tmp_path / "export" / "person_0.glb").is_file()


def test_shape_controls_are_fixed_on_an_animation(app):
    assert app.beta_sliders[0].disabled and app.gender_dropdown.disabled and app.refine_checkbox.disabled


def test_smplik_edit_recognises_animation_files(animation_file, best_solver, monkeypatch, tmp_path):
    from typer.testing import CliRunner

    import workflows.editor.cli as editor_cli
    from smplik.cli.main import app as cli_app
    from workflows.editor.app import EditorApp
    from workflows.editor.timeline import AnimationTimeline
    from workflows.editor.timeline_app import AnimationEditorApp

    assert AnimationTimeline.open_if_animation(animation_file, best_solver).frames == range(FRAMES)
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"format": "smplik-scene", "version": 1, "characters": []}))
    assert AnimationTimeline.open_if_animation(scene, best_solver) is None
    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    served = []

    def serve(editor, host):  # instead of serving until Ctrl+C: record the editor and stop it
        served.append(editor)
        editor.stop()

    monkeypatch.setattr(editor_cli, "_serve", serve)
    res = CliRunner().invoke(cli_app, ["edit", str(animation_file), "--port", "0"])
    assert res.exit_code == 0, res.output
    assert isinstance(served[-1], AnimationEditorApp) and served[-1].timeline.frames == range(FRAMES)
    assert served[-1].timeline.path == animation_file
    res = CliRunner().invoke(cli_app, ["edit", str(tmp_path / "new.json"), "--port", "0"])  # scenes: as before
    assert res.exit_code == 0, res.output
    assert type(served[-1]) is EditorApp and len(served[-1].state.scene.characters) == 1
    res = CliRunner().invoke(cli_app, ["edit", str(animation_file), "--character", str(tmp_path / "x.bvh")])
    assert res.exit_code == 1 and "is an animation: --character applies to scenes" in res.output
    bad = json.loads(animation_file.read_text())
    bad["tracks"][0]["first_frame"] = -3
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    res = CliRunner().invoke(cli_app, ["edit", str(tmp_path / "bad.json")])
    assert res.exit_code == 1 and "tracks[0].first_frame" in res.output and "Traceback" not in res.output


def test_two_tracks_one_starting_later(best_solver, tmp_path, monkeypatch):
    """PHALP tracks 3 (frames 0..11) and 8 (from frame 4): track 8 is hidden before it starts, and an edit of
    track 8 changes only track 8."""
    from typer.testing import CliRunner

    from workflows.cli import scene_app
    from workflows.editor.timeline import AnimationTimeline
    from workflows.editor.timeline_app import AnimationEditorApp

    a, t = video_motion(12, seed=4, fmt="phalp")
    b, u = video_motion(12, seed=5, fmt="phalp", x=0.8)
    frames = [{3: (a[i], t[i]), **({8: (b[i], u[i])} if i >= 4 else {})} for i in range(12)]
    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    res = CliRunner().invoke(scene_app, ["animate", str(write_phalp_video(tmp_path, frames)), "--out", str(tmp_path),
                                         "--fps", "24", "--max-effectors", "2", "--export", ""])
    assert res.exit_code == 0, res.output
    timeline = AnimationTimeline.open(tmp_path / "animation.json", best_solver, window=2)
    app = AnimationEditorApp(timeline, best_solver, host="127.0.0.1", port=0)
    try:
        assert timeline.frames == range(12) and timeline.frame_time == pytest.approx(1 / 24)
        assert app._meshes[0].visible and not app._meshes[1].visible  # track 8 has not started
        app.goto(6)
        assert app._meshes[1].visible
        first, second = (x.body_pose.copy() for x in timeline.animation.tracks)
        user_event(app.character_dropdown, "1: person_1")
        assert app.state.active == 1
        _drag_left_wrist_at(app, 6)
        app.apply()
        after = timeline.animation.tracks
        assert np.array_equal(after[0].body_pose, first)  # the other track: untouched
        assert not np.array_equal(after[1].body_pose[6 - 4], second[6 - 4])  # rows of track 8 start at frame 4
        assert np.array_equal(after[1].body_pose[:6 - 4 - 2], second[:6 - 4 - 2])
        assert app.state.active == 1  # still editing that track
    finally:
        app.stop()


def test_keyframe_dropdown_always_agrees_with_the_header(app):
    """Issue 44: picking "(not a keyframe)" on a keyframe left the dropdown saying so while the header said
    "keyframe, 3 effectors"; the dropdown now always shows what the header says, whatever the user picks."""
    from workflows.editor.timeline_app import NOT_A_KEYFRAME

    def agree() -> bool:
        keyframe = "(keyframe," in app._frame_text()
        return keyframe == (app.keyframe_dropdown.value != NOT_A_KEYFRAME) and (
            not keyframe or app.keyframe_dropdown.value == str(app.timeline.frame))

    tl = app.timeline
    key = tl.keyframes()[1]
    user_event(app.keyframe_dropdown, str(key))
    assert tl.frame == key and agree()
    user_event(app.keyframe_dropdown, NOT_A_KEYFRAME)  # a label, not a frame
    assert tl.frame == key and agree()
    user_event(app.frame_slider, key + 1)
    assert agree() and app.keyframe_dropdown.value == NOT_A_KEYFRAME
    user_event(app.keyframe_dropdown, NOT_A_KEYFRAME)
    assert agree()


@pytest.mark.slow
def test_timeline_controls_in_headless_chromium(app):
    from editor_helpers import CHROMIUM, IN_CI, editor_page, wait_for

    if not IN_CI and not Path(CHROMIUM).is_file():
        pytest.skip("Debian chromium is not installed (apt-get install -y chromium); CI installs it")
    tl = app.timeline
    with editor_page(app.url, height=800) as page:
        for name in ("Play", "Previous keyframe", "Next keyframe", "Apply", "Save"):
            page.get_by_role("button", name=name).wait_for()
        assert page.get_by_text("Blend window").count() >= 1 and page.get_by_text("Keyframe").count() >= 1
        close = page.locator(".mantine-Notification-closeButton")
        if close.count():
            close.first.click()  # the "software WebGL" notice of a GPU-less machine
        page.get_by_role("button", name="Next keyframe").click()
        wait_for(lambda: tl.frame == tl.keyframes()[1], "the next keyframe on the server")
        frame_thumb = page.get_by_role("slider").first  # the Timeline panel comes first
        wait_for(lambda: frame_thumb.get_attribute("aria-valuenow") == str(tl.frame), "the frame slider's value")
        frame_thumb.focus()
        page.keyboard.press("ArrowRight")  # scrub one frame with the slider
        wait_for(lambda: tl.frame == tl.keyframes()[1] + 1, "the scrubbed frame on the server")
        track = tl.animation.tracks[0]
        assert np.array_equal(app.state.scene.characters[0].pose.body_pose, track.body_pose[tl.frame])
        page.get_by_role("button", name="Play").click()
        wait_for(lambda: app.playing, "playback on the server")
        page.get_by_role("button", name="Pause").click()
        wait_for(lambda: not app.playing, "playback paused")
