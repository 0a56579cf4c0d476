"""Journey: sequences read as sequences, through ``scene from-estimate`` and ``scene animate``.

* A plain SMPL-parameter ``.npz`` of a video (a ROMP run refined by InstantAvatar: ``global_orient (T, 3)``,
  ``body_pose (T, 69)``, ``transl (T, 3)``, one ``betas (1, 10)``) is one person over T frames.
* SMPLer-X's per-frame outputs (``main/inference.py``: ``smplx/{frame:05}_{bbox_id}.npz``,
  ``meta/{frame:05}_{bbox_id}.json``, ``img/{frame:06d}.jpg`` for every processed frame; written by
  ``tests/estimator_fixtures.py`` ``write_smplerx``) are one clip whose tracks follow the people.
* GVHMR (``hmr4d_results.pt``, no frame rate stored) animates without ``--fps``, at 30 frames/s.
* PHALP's named frames: the numbers the tracks are given are those of the range errors.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from animation_fixtures import video_motion, write_gvhmr_video, write_phalp_video
from estimator_fixtures import write_smplerx

T = 41


@pytest.fixture()
def scene(monkeypatch, best_solver):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    return lambda *args: CliRunner().invoke(scene_app, list(map(str, args)))


def _lines(result) -> list[str]:
    return [ln for ln in result.output.splitlines() if ln.strip()]


def _one_error_line(result) -> str:
    lines = _lines(result)
    assert result.exit_code == 1 and len(lines) == 1 and "Traceback" not in result.output, result.output
    return lines[0]


def write_smpl_sequence(path, aa: np.ndarray, transl: np.ndarray) -> None:
    """InstantAvatar's ``poses.npz`` of a refined ROMP run: per-frame ``global_orient``, ``body_pose``,
    ``transl`` and ONE ``betas (1, 10)``."""
    n = aa.shape[0]
    np.savez(path, betas=np.full((1, 10), 0.3, np.float32), global_orient=aa[:, 0].astype(np.float32),
             body_pose=aa[:, 1:].reshape(n, 69).astype(np.float32), transl=transl.astype(np.float32))


def test_a_plain_smpl_sequence_is_one_person_over_its_frames(tmp_path, scene):
    from workflows.animation.files import load_animation
    from workflows.estimators import read_estimate

    aa, transl = video_motion(T, seed=31)
    path = tmp_path / "poses.npz"
    write_smpl_sequence(path, aa, transl)
    from workflows.estimators.pose_array import EstimateNote

    with pytest.warns(EstimateNote, match=f"one person over {T} frames"):
        (person,) = read_estimate(path, frame=7)  # one person: frame 7's pose, not 41 people
    assert np.allclose(person.global_orient, aa[7, 0], atol=1e-5) and np.allclose(person.body_pose, aa[7, 1:],
                                                                                 atol=1e-5)
    res = scene("from-estimate", path, "--out", tmp_path / "fe", "--frame", 7, "--max-effectors", 2,
                "--no-previews")
    assert res.exit_code == 0, res.output
    assert sum(f"one person over {T} frames" in ln for ln in _lines(res)) == 1, res.output
    assert len(json.loads((tmp_path / "fe" / "scene.json").read_text())["characters"]) == 1
    assert f"(0..{T - 1})" in _one_error_line(scene("from-estimate", path, "--out", tmp_path / "x", "--frame", T))
    res = scene("animate", path, "--out", tmp_path / "anim", "--fps", 30, "--max-effectors", 2, "--export", "")
    assert res.exit_code == 0, res.output
    (track,) = load_animation(tmp_path / "anim" / "animation.json").tracks
    assert track.num_frames == T and track.first_frame == 0


def _in_box_camera(transl: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """A SMPL-X ``transl`` (3,) seen by the video's camera (focal = image diagonal, centred principal point),
    re-expressed in SMPLer-X's camera of the person's ``box`` (``main/inference.py``: ``cfg.focal`` and
    ``cfg.princpt`` scaled to the box): the pelvis keeps its pixel and apparent size."""
    from estimator_fixtures import IMAGE_H, IMAGE_W, SMPLERX_FOCAL, SMPLERX_INPUT

    from workflows.estimators.base import SMPLX_NEUTRAL_REST_PELVIS
    from workflows.estimators.smplerx import move_to_camera

    x, y, w, h = box
    f_box = np.array([SMPLERX_FOCAL[0] / SMPLERX_INPUT[1] * w, SMPLERX_FOCAL[1] / SMPLERX_INPUT[0] * h])
    c_box = np.array([w / 2 + x, h / 2 + y])
    video = (np.full(2, np.hypot(IMAGE_W, IMAGE_H)), np.array([IMAGE_W / 2, IMAGE_H / 2]))
    pelvis = move_to_camera(transl + SMPLX_NEUTRAL_REST_PELVIS, video, (f_box, c_box))
    return pelvis - SMPLX_NEUTRAL_REST_PELVIS


def _smplerx_clip(folder, frames: int = 8) -> None:
    """SMPLer-X over ``frames`` images 000001.jpg..: nobody detected in the first; two people after, whose
    detection order (``bbox_id``) swaps every other frame, each ``transl`` in its own box's camera."""
    a, t = video_motion(frames, seed=32)
    b, u = video_motion(frames, seed=33, x=1.2)
    (folder / "img").mkdir(parents=True)
    for k in range(frames):
        (folder / "img" / f"{k + 1:06d}.jpg").write_bytes(b"")  # every processed frame's render
        if k == 0:
            continue
        w0, w1 = 210.0 + 2 * k, 200.0 - 3 * k  # process_bbox keeps cfg.input_body_shape's aspect: w / h = 3 / 4
        boxes = [(100.0, 50.0, w0, w0 * 4 / 3), (420.0, 60.0, w1, w1 * 4 / 3)]
        aa = np.stack([a[k], b[k]])
        tt = np.stack([_in_box_camera(t[k], boxes[0]), _in_box_camera(u[k], boxes[1])])
        if k % 2:  # detection order is not identity
            aa, tt, boxes = aa[::-1], tt[::-1], boxes[::-1]
        write_smplerx(folder, aa, tt, np.zeros((2, 10)), boxes, frame=k + 1)


def test_smplerx_per_frame_files_are_one_clip_with_tracks_across_frames(tmp_path, scene):
    from workflows.animation.files import load_animation

    out = tmp_path / "smplerx_out"
    _smplerx_clip(out)
    res = scene("animate", out, "--out", tmp_path / "anim", "--fps", 30, "--max-effectors", 2, "--export", "")
    assert res.exit_code == 0, res.output
    assert any("8 per-frame smplerx outputs (frames 0..7 = its frame numbers 1..8)" in ln for ln in _lines(res))
    anim = load_animation(tmp_path / "anim" / "animation.json")
    assert [(t.first_frame, t.num_frames) for t in anim.tracks] == [(1, 7), (1, 7)]
    for t in anim.tracks:  # each track follows one person: no jump where the detection order swaps
        assert np.linalg.norm(np.diff(t.transl, axis=0), axis=1).max() < 0.25  # a swap: 1.3 m
    from workflows.animation.clips import read_clip

    for rows in read_clip(out).tracks.values():  # as read, before any cleaning could hide a swap
        pelvis = np.array([p.transl for _, p in rows])
        assert len(rows) == 7 and np.linalg.norm(np.diff(pelvis, axis=0), axis=1).max() < 0.25  # swap: 1.3 m
    xs = sorted(float(t.transl[:, 0].mean()) for t in anim.tracks)
    assert xs[1] - xs[0] > 0.5  # two people side by side, not two halves of each
    res = scene("from-estimate", out / "smplx", "--out", tmp_path / "fe", "--frame", 3, "--max-effectors", 2,
                "--no-previews")
    assert res.exit_code == 0, res.output
    assert any("frame 3: 00004_0.npz, 00004_1.npz" in ln for ln in _lines(res)), res.output
    assert len(json.loads((tmp_path / "fe" / "scene.json").read_text())["characters"]) == 2
    line = _one_error_line(scene("from-estimate", out, "--out", tmp_path / "x", "--frame", 0))
    assert "frame 0" in line and "no people" in line
    line = _one_error_line(scene("animate", tmp_path / "missing", "--out", tmp_path / "y", "--fps", 30))
    assert "not found" in line
    (tmp_path / "empty").mkdir()
    assert "no estimator files" in _one_error_line(scene("animate", tmp_path / "empty", "--out", tmp_path / "z",
                                                         "--fps", 30))


def test_gvhmr_animates_without_fps_at_30_and_says_so(tmp_path, scene):
    from workflows.animation.files import load_animation

    aa, transl = video_motion(12, seed=34)
    path = write_gvhmr_video(tmp_path, aa, transl)
    res = scene("animate", path, "--out", tmp_path / "anim", "--max-effectors", 2, "--export", "")
    assert res.exit_code == 0, res.output
    assert sum("30 frames/s assumed" in ln for ln in _lines(res)) == 1
    assert load_animation(tmp_path / "anim" / "animation.json").fps == 30
    res = scene("animate", path, "--out", tmp_path / "anim24", "--fps", 24, "--max-effectors", 2, "--export", "")
    assert res.exit_code == 0 and "assumed" not in res.output
    assert load_animation(tmp_path / "anim24" / "animation.json").fps == 24


def test_phalp_frame_numbers_are_the_range_errors_numbers(tmp_path, scene):
    a, t = video_motion(4, seed=35, fmt="phalp")
    path = write_phalp_video(tmp_path, [{}] + [{3: (a[i], t[i])} for i in range(1, 4)])
    res = scene("animate", path, "--out", tmp_path / "anim", "--fps", 24, "--max-effectors", 2, "--export", "")
    assert res.exit_code == 0, res.output
    lines = _lines(res)
    assert any("4 frames, numbered 0..3 in name order (frame 0 is 'img/000001.jpg'" in ln for ln in lines)
    assert any(ln.startswith("person_3: frames 1..3 ") for ln in lines)
    line = _one_error_line(scene("animate", path, "--out", tmp_path / "x", "--fps", 24, "--frames", "0:9"))
    assert "(frames 0..3)" in line
