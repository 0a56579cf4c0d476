"""Journey: ``scene animate`` of a GVHMR clip -> GIF and MP4 previews (whole clip, 3D view facing the body's front,
a floor) -> the animated BVH read back. Also: an unwritable preview fails before the work, one renderer for all
frames.

The clip is GVHMR's ``hmr4d_results.pt`` (``tools/demo/demo.py``) written by ``tests/animation_fixtures.py``; the
body is turned 120 degrees about the vertical so that it does not face the camera's +z side (a view fixed "from
+z" shows its back).
"""

from __future__ import annotations

import numpy as np
import pytest
from animation_fixtures import video_motion, write_gvhmr_video
from helpers import needs_gl
from scipy.spatial.transform import Rotation

T = 24




@pytest.fixture()
def animate(monkeypatch, best_solver):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    return lambda *args: CliRunner().invoke(scene_app, ["animate", *map(str, args)])


@pytest.fixture()
def turned_clip(tmp_path):
    """A GVHMR clip of T frames whose body faces away from +z (turned 120 degrees about the vertical)."""
    aa, transl = video_motion(T, seed=21)
    turn = Rotation.from_euler("y", 120, degrees=True)  # a yaw in the camera's axes too (y down)
    aa[:, 0] = (turn * Rotation.from_rotvec(aa[:, 0])).as_rotvec()
    return write_gvhmr_video(tmp_path, aa, transl)


def _lines(result) -> list[str]:
    return [ln for ln in result.output.splitlines() if ln.strip()]


def _forward_of_feet(anim) -> np.ndarray:
    """(3,) unit horizontal direction the body faces, from its feet (ankle -> foot joints), over the clip."""
    from workflows.animation.clips import axis_angle_to_local, joints_of, rest_joints

    (t,) = anim.tracks
    p = joints_of(axis_angle_to_local(t.global_orient, t.body_pose), t.transl, rest_joints(t.betas, t.gender))
    d = (p[:, 10] - p[:, 7] + p[:, 11] - p[:, 8]).mean(0)
    d[1] = 0.0
    return d / np.linalg.norm(d)


@needs_gl
def test_gif_and_mp4_cover_the_clip_face_the_front_show_a_floor_and_the_bvh_reads_back(tmp_path, animate,
                                                                                       turned_clip):
    import imageio.v2 as imageio

    from smplik.data.bvh import read_bvh
    from smplik.render import camera_pose
    from workflows.animation.files import load_animation, scene_of
    from workflows.animation.preview import shown_frames, world_view
    from workflows.scene.previews import scene_items

    out = tmp_path / "anim"
    res = animate(turned_clip, "--out", out, "--max-effectors", 2, "--export", "bvh", "--preview", out / "p.gif")
    assert res.exit_code == 0, res.output
    lines = _lines(res)
    assert f"preview: every 2nd frame of 0..{T - 2} ({T // 2} frames)" in lines, res.output  # said, not silent
    gif = imageio.mimread(out / "p.gif")
    assert len(gif) == T // 2 and gif[0].shape[:2] == (360, 480)
    assert imageio.get_reader(out / "p.gif").get_meta_data()["duration"] == pytest.approx(1000 / 15, abs=10)
    res = animate(turned_clip, "--out", tmp_path / "anim_mp4", "--max-effectors", 2, "--preview", out / "p.mp4")
    assert res.exit_code == 0, res.output
    assert f"preview: frames 0..{T - 1} ({T} frames, all of them)" in _lines(res)
    assert imageio.get_reader(out / "p.mp4").count_frames() == T  # the whole clip

    anim = load_animation(out / "animation.json")
    frames, _ = shown_frames(anim)
    world = world_view(anim, frames)
    forward = _forward_of_feet(anim)
    assert np.degrees(np.arccos(np.clip(forward @ [0.0, 0.0, 1.0], -1, 1))) > 90  # +z would show its back
    # the renderer's camera sits on the side the body faces (in front of the feet, not behind)
    points = np.concatenate([m.vertices for m in scene_items(scene_of(anim, 0), markers=False)[0]])
    eye = camera_pose(points, world.view, (480, 360))[:3, 3]
    to_camera = eye - points.mean(0)
    to_camera[1] = 0.0
    assert to_camera @ forward / np.linalg.norm(to_camera) > 0.9
    # a floor at the clip's lowest point: the lowest mesh vertex over every frame
    lowest = min(float(m.vertices[:, 1].min()) for f in range(T) for m in scene_items(scene_of(anim, f),
                                                                                       markers=False)[0])
    assert world.floor_y == pytest.approx(lowest, abs=0.01)
    assert world.floor and all(abs(m.vertices[:, 1] - world.floor_y).max() < 0.005 for m in world.floor)
    # ... drawn: the image's bottom band is checkered floor (two greys), not the white background
    band = np.asarray(gif[0])[-40:, :, :3].astype(int).reshape(-1, 3)
    grey = (np.abs(band - band.mean(1, keepdims=True)).max(1) < 12) & (band.mean(1) < 235)
    assert grey.mean() > 0.5
    # light and dark tiles: along each row of the band the brightness crosses the middle of its greys again and
    # again (a shaded plain floor drifts across it at most once)
    values = band[grey].mean(1)
    lo, hi = np.percentile(values, 10), np.percentile(values, 90)
    assert hi - lo > 8
    rows = np.asarray(gif[0])[-40::8, :, :3].astype(float).mean(2)  # 5 rows of the band
    crossings = [np.count_nonzero(np.diff(row > (lo + hi) / 2)) for row in rows]
    assert np.median(crossings) >= 4, crossings
    # the animation's BVH export reads back with the whole clip at GVHMR's assumed 30 frames/s
    bvh = read_bvh(out / "person_0.bvh")
    assert bvh.num_frames == T and bvh.frame_time == pytest.approx(1 / 30, abs=1e-6)


@needs_gl
def test_one_renderer_draws_every_frame(tmp_path, animate, turned_clip, monkeypatch):
    import smplik.render as render_module
    from workflows.animation.files import load_animation
    from workflows.animation.preview import write_preview

    res = animate(turned_clip, "--out", tmp_path / "a", "--max-effectors", 2, "--export", "")
    assert res.exit_code == 0, res.output
    anim = load_animation(tmp_path / "a" / "animation.json")
    made = []
    real_init = render_module.Renderer.__init__

    def counting_init(self, *args, **kwargs):
        made.append(1)
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(render_module.Renderer, "__init__", counting_init)
    result = write_preview(anim, tmp_path / "p.mp4")
    assert len(result.frames) == T and len(made) == 1


def test_an_unwritable_mp4_preview_fails_before_the_work(tmp_path, animate, turned_clip, monkeypatch):
    import imageio_ffmpeg

    def missing():
        raise RuntimeError("No ffmpeg exe could be found.")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", missing)
    res = animate(turned_clip, "--out", tmp_path / "a", "--preview", tmp_path / "a" / "p.mp4")
    lines = _lines(res)
    assert res.exit_code == 1 and len(lines) == 1 and "Traceback" not in res.output, res.output
    assert lines[0].startswith("error: --preview") and "imageio-ffmpeg" in lines[0]
    assert not (tmp_path / "a" / "animation.json").exists()  # nothing done
    res = animate(turned_clip, "--out", tmp_path / "b", "--preview", tmp_path / "b" / "p.avi")
    assert res.exit_code == 1 and ".gif or .mp4" in res.output and not (tmp_path / "b").exists()


def test_a_long_clip_is_shown_whole_and_the_frames_are_said():
    from smplik.conventions import Gender
    from workflows.animation.clips import Animation, AnimationTrack
    from workflows.animation.preview import describe_frames, shown_frames

    n = 537  # issue 32's GVHMR clip, whose GIF stopped at frame 299
    track = AnimationTrack("person_0", "0", Gender.NEUTRAL, np.zeros(10), 1.0, None, 0, np.zeros((n, 3)),
                           np.zeros((n, 23, 3)), np.zeros((n, 3)))
    anim = Animation((track,), 30.0)
    frames, step = shown_frames(anim)  # MP4: every frame
    assert frames == list(range(n)) and step == 1
    frames, step = shown_frames(anim, max_fps=15.0)  # GIF: every 2nd, to the end
    assert step == 2 and frames[0] == 0 and frames[-1] >= n - 2 and len(frames) == (n + 1) // 2
    assert describe_frames(frames, step) == f"preview: every 2nd frame of 0..536 ({len(frames)} frames)"
    frames, step = shown_frames(anim, 1, max_frames=100)  # a cap widens the step, still to the end
    assert step == 6 and frames[-1] >= n - 6 and len(frames) <= 100
