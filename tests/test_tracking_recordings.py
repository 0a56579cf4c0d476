"""Real VR recordings into `smplik track`: the CSV layouts published by VR studies and tools (fixtures in each
producer's exact column layout, smplik.tracking.csv_io), the floor, the user's stature and β, controller wrist
offsets and a recording whose origin is not the floor (smplik.tracking.calibrate), trackers made from a motion
file (workflows.tracking.from_motion, `smplik track --from-motion`)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from smplik.tracking.calibrate import (
    CONTROLLERS,
    CalibrationError,
    apply_floor,
    body_heights,
    calibrate,
    signals_from_devices,
)
from smplik.tracking.csv_io import read_csv_devices, read_csv_trackers
from smplik.tracking.io import TrackerFileError, signals_from_motion
from smplik.tracking.recordings import read_trackers
from workflows.tracking.from_motion import _sole_height, motion_signals, write_device_csv

CMU = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "cmu"
needs_cmu = pytest.mark.skipif(not (CMU / "split.json").is_file(), reason="needs ../shared/data/cmu (held-out clips)")

# each producer's header, as its code writes it (the fixture writer must reproduce it exactly)
HEADERS = {
    "who-is-alyx": "timestamp,delta_time_ms," + ",".join(
        f"{d}_{k}_{a}" for d in ("hmd", "left_controller", "right_controller")
        for k, axes in (("pos", "xyz"), ("rot", "xyzw")) for a in axes) + "," + ",".join(
        f"{s}_controller_{b}" for s in ("left", "right") for b in (
            "grip_button", "menu_button", "trackpad_pressed", "trackpad_touched", "trackpad_x", "trackpad_y",
            "trigger", "ul_button_pressed", "ul_button_touched")),
    "unity-hmd-recorder": "timestamp_ms,frame,unity_time," + ",".join(
        f"{d}_{k}_{a}" for d in ("hmd", "left", "right")
        for k, axes in (("pos", "xyz"), ("rot", "xyzw")) for a in axes),
    "omnicept": "time_stamp," + ",".join(f"{d}_{k}_{a}" for d in ("head", "lefthand", "righthand")
                                         for k, axes in (("pos", "xyz"), ("rot", "xyzw")) for a in axes),
    "magic-xroom": "timestamp," + ",".join(
        f"{d}_{'ppos' if d != 'head' and k == 'pos' and a == 'Y' else k}{a}"
        for d in ("head", "lcontroller", "rcontroller") for k, axes in (("pos", "XYZ"), ("rot", "XYZW")) for a in axes),
}


def walk(T: int = 150, fps: float = 60.0, beta0: float = 0.0, speed: float = 1.0):
    """Exact trackers (head, wrists with rotations, pelvis) of a synthetic walk forward (+z, SMPL's forward) on
    the body beta0, arms down, the head turning +-20 degrees, the soles on y = 0; and the rest joints."""
    from scipy.spatial.transform import Rotation

    from workflows.animation.clips import rest_joints

    betas = np.zeros(10)
    betas[0] = beta0
    t = np.arange(T) / fps
    R = np.tile(np.eye(3), (T, 24, 1, 1))
    R[:, 16] = Rotation.from_euler("z", -70, degrees=True).as_matrix()
    R[:, 17] = Rotation.from_euler("z", 70, degrees=True).as_matrix()
    R[:, 15] = Rotation.from_euler("y", 20 * np.sin(2 * np.pi * 0.5 * t)[:, None], degrees=True).as_matrix()
    transl = np.stack([0.0 * t, 0.0 * t, speed * t], -1)
    transl[:, 1] -= _sole_height(R, transl, betas, "neutral")
    J = rest_joints(betas, "neutral")
    return signals_from_motion(R, transl, J, ("head", "left_wrist", "right_wrist", "pelvis"), fps), betas


@pytest.fixture(scope="module")
def walk_signals():
    return walk()[0]


LAYOUTS = [("who-is-alyx", {}), ("unity-hmd-recorder", {}), ("omnicept", {}), ("magic-xroom", {}),
           # the HTC Vive Pro recordings: OpenVR axes, centimetres, milliseconds, irregular sampling
           ("who-is-alyx", {"units": "cm", "rate": 90.0}),
           ("magic-xroom", {"axes": "openvr", "units": "mm"})]
DEFAULT_AXES = {"who-is-alyx": "openvr", "unity-hmd-recorder": "unity", "omnicept": "unity", "magic-xroom": "unity"}


@pytest.mark.parametrize("producer,options", LAYOUTS, ids=[f"{p}-{o.get('units', 'm')}" for p, o in LAYOUTS])
def test_each_csv_layout_is_read_with_no_options(walk_signals, tmp_path, producer, options):
    path = write_device_csv(walk_signals, tmp_path / "rec.csv", producer, **options)
    assert path.read_text().splitlines()[0] == HEADERS[producer]  # the producer's exact column layout
    rec = read_csv_devices(path)
    assert rec.producer == producer
    assert f"positions in {options.get('units', 'm')}" in rec.notes
    assert f"{options.get('axes', DEFAULT_AXES[producer])} axes (detected)" in rec.notes
    assert np.ptp(np.diff(rec.times)) > 0.2 * np.median(np.diff(rec.times))  # irregular sampling
    sig = read_trackers(path)  # what `smplik track` does: by the suffix, no options
    assert sig.names == ("head", "left_wrist", "right_wrist") and sig.fps == 60.0
    assert sig.num_frames == walk_signals.num_frames  # frames in = frames out (the same span at 60 Hz)
    err = np.linalg.norm(sig.positions - walk_signals.positions[:, :3], axis=-1)
    assert err.mean() < 0.002 and err.max() < 0.01, (err.mean(), err.max())  # wrists: the controllers' wrist points
    # the head's rotation comes through the headset's (and the handedness conversion)
    dots = np.abs(np.einsum("ti,ti->t", sig.rotations[:, 0], walk_signals.rotations[:, 0]))
    assert dots.min() > 0.999


def test_controller_offsets_put_the_wrist_at_the_wrist_point(walk_signals, tmp_path):
    path = write_device_csv(walk_signals, tmp_path / "vive.csv", "who-is-alyx", controller="vive")
    exact = read_csv_trackers(path)  # who-is-alyx: HTC Vive wands by default
    raw = read_csv_trackers(path, controller="none")  # the controllers' own origins
    gap = np.linalg.norm(raw.positions[:, 1:] - exact.positions[:, 1:], axis=-1)
    np.testing.assert_allclose(gap, np.linalg.norm(CONTROLLERS["vive"]), atol=1e-6)
    touch = read_csv_trackers(write_device_csv(walk_signals, tmp_path / "q.csv", "who-is-alyx", controller="touch"),
                              controller="touch")
    assert np.linalg.norm(touch.positions - walk_signals.positions[:, :3], axis=-1).max() < 0.01
    with pytest.raises(TrackerFileError, match="unknown controller 'wand'"):
        read_csv_trackers(path, controller="wand")


def test_overrides_and_irregular_time_columns(walk_signals, tmp_path):
    path = write_device_csv(walk_signals, tmp_path / "cm.csv", "omnicept", units="cm")
    assert np.allclose(read_csv_trackers(path, units="cm").positions, read_csv_trackers(path).positions)
    wrong = read_csv_trackers(path, units="m", axes="unity")  # told metres: a 100 times larger world
    assert np.abs(wrong.positions[:, 0, 1]).max() > 50
    secs = write_device_csv(walk_signals, tmp_path / "s.csv", "magic-xroom")  # seconds, detected from the rate
    assert "times in s" in read_csv_devices(secs).notes
    as_ms = read_csv_trackers(secs, time_unit="ms")  # told ms: a 1000 times shorter recording
    assert as_ms.num_frames < 3
    for option, value in (("units", "inch"), ("time_unit", "min"), ("axes", "zup")):
        with pytest.raises(TrackerFileError, match=f"--csv-{option.replace('_', '-')} must be one of"):
            read_csv_trackers(path, **{option: value})
    # repeated timestamps (a logger writing twice a frame) are dropped, a lost pose (empty cells) interpolated
    lines = path.read_text().splitlines()
    cells = lines[5].split(",")
    cells[8:15] = [""] * 7  # the left controller lost on one row
    lines[5] = ",".join(cells)
    lines.insert(8, lines[7])
    (tmp_path / "gaps.csv").write_text("\n".join(lines) + "\n")
    gaps = read_csv_trackers(tmp_path / "gaps.csv")
    assert gaps.num_frames == walk_signals.num_frames
    assert np.linalg.norm(gaps.positions - walk_signals.positions[:, :3], axis=-1).max() < 0.01


@pytest.mark.parametrize("edit,message", [
    (lambda h: h.replace("right_controller", "gun"), "no right controller position columns"),
    (lambda h: h.replace("delta_time_ms", "sample"), "no time column"),
    (lambda h: h.replace("hmd_rot_w", "hmd_rot_v"), "no headset rotation quaternion columns"),
    (lambda h: "x,y,z", "not a CSV header naming device columns"),
])
def test_anything_else_is_refused_with_one_line(walk_signals, tmp_path, edit, message):
    path = write_device_csv(walk_signals, tmp_path / "rec.csv", "who-is-alyx")
    lines = path.read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([edit(lines[0]), *lines[1:]]) + "\n")
    with pytest.raises(TrackerFileError, match=message) as info:
        read_trackers(bad)
    assert str(bad) in str(info.value) and "\n" not in str(info.value)


def test_track_accepts_a_csv_with_no_options(walk_signals, tmp_path):
    from smplik.cli.main import app

    path = write_device_csv(walk_signals, tmp_path / "session.csv", "unity-hmd-recorder")
    res = CliRunner().invoke(app, ["track", str(path), "--out", str(tmp_path / "out"), "--export", ""])
    assert res.exit_code == 0, res.output
    found = re.search(r"stature (\d\.\d\d) m \(estimated from the headset\)", res.output)
    assert found and abs(float(found[1]) - 1.70) <= 0.02, res.output  # the walk's body: beta 0, 1.70 m
    anim = json.loads((tmp_path / "out" / "animation.json").read_text())
    assert len(anim["tracks"][0]["transl"]) == walk_signals.num_frames
    (tmp_path / "bad.csv").write_text("time,a,b\n0,1,2\n")
    res = CliRunner().invoke(app, ["track", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "o2")])
    assert res.exit_code == 1 and "bad.csv" in res.output and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) == 1


@pytest.mark.parametrize("beta0", [-2.0, 0.0, 2.5])
def test_stature_and_beta_from_the_headset(beta0):
    sig, betas = walk(beta0=beta0)
    cal = calibrate(sig)
    truth = body_heights(betas)[1]
    assert abs(cal.stature_m - truth) < 0.02 and cal.stature_from == "recording" and cal.floor_y == 0.0
    assert abs(cal.betas[0] - beta0) < 0.2 and not cal.betas[1:].any()
    given = calibrate(sig, height=1.80)  # a stature given wins (within 15 cm of the headset's)
    assert given.stature_from == "--height" and abs(given.stature_m - 1.80) < 0.005
    assert calibrate(sig, betas=betas).stature_from == "--betas"


def test_wrong_origin_is_never_silent(walk_signals, tmp_path):
    from dataclasses import replace

    at_head = replace(walk_signals, positions=walk_signals.positions - [0.0, 1.52, 0.0], source="eye-level.json")
    cal = calibrate(at_head)  # the headset at y ~ 0: moved, with one line
    assert cal.message.startswith("eye-level.json: the standing headset is 0.0")
    assert "m above the origin: the origin is not the floor; moved the floor to -1.5" in cal.message
    assert "give --height" in cal.message and "\n" not in cal.message
    fixed = apply_floor(at_head, cal)
    assert abs(fixed.positions[:, 0, 1].max() - walk_signals.positions[:, 0, 1].max()) < 0.02
    above = replace(walk_signals, positions=walk_signals.positions - [0.0, 0.7, 0.0], source="low.json")
    with pytest.raises(CalibrationError, match="low.json: the standing headset is 0.8. m above the origin"):
        calibrate(above)  # ambiguous: a short user, a seated one or an origin 70 cm up; refused
    cal = calibrate(above, height=1.70)  # with the stature: corrected, said
    assert re.search(r"moved the floor to -0\.(69|70|71) m \(a 1.70 m user, --height\)$", cal.message), cal.message
    # through `smplik track`: the line is printed and the body stands on the floor
    from smplik.cli.main import app

    (tmp_path / "eye.json").write_text(json.dumps(at_head.to_dict()))
    res = CliRunner().invoke(app, ["track", str(tmp_path / "eye.json"), "--out", str(tmp_path / "o"), "--export", ""])
    assert res.exit_code == 0 and "the origin is not the floor" in res.output
    (tmp_path / "low.json").write_text(json.dumps(above.to_dict()))
    res = CliRunner().invoke(app, ["track", str(tmp_path / "low.json"), "--out", str(tmp_path / "o2")])
    assert res.exit_code == 1 and "give --height" in res.output and "Traceback" not in res.output


def _lowest_points(anim_file: Path) -> np.ndarray:
    """(T,) the output mesh's lowest point per frame, metres."""
    import torch

    from smplik.body_model import BodyModelSet
    from workflows.animation.files import load_animation

    track = load_animation(anim_file).tracks[0]
    with torch.no_grad():
        v, _ = BodyModelSet.load()[track.gender].vertices(
            torch.as_tensor(track.global_orient).float(), torch.as_tensor(track.body_pose).float(),
            torch.as_tensor(track.transl).float(), torch.as_tensor(track.betas).float().expand(track.num_frames, 10))
    return v[..., 1].min(-1).values.numpy()


@needs_cmu
@pytest.mark.parametrize("clip,beta0", [("02_01.bvh", 1.5), ("32_01.bvh", -1.0)])
def test_feet_on_the_floor_of_a_tall_or_short_user(tmp_path, clip, beta0):
    """A held-out clip on a body other than the default one, recorded as a Who Is Alyx CSV (headset at the body's
    head height): `smplik track` with no options estimates the body, and the feet reach the floor."""
    from workflows.tracking.run import track_file

    betas = np.zeros(10)
    betas[0] = beta0
    sig, _ = motion_signals(CMU / clip, betas=betas)
    path = write_device_csv(sig, tmp_path / "rec.csv", "who-is-alyx")
    out = track_file(path, tmp_path / "out", formats=[])
    assert out.animation.tracks[0].num_frames == sig.num_frames
    low = _lowest_points(out.animation_file)
    on_floor = np.abs(low) < 0.03
    assert on_floor.mean() > 0.6, (np.median(low), on_floor.mean())
    plain = track_file(path, tmp_path / "plain", formats=[], calibrate=False)  # the default body: floats or sinks
    assert np.abs(np.median(_lowest_points(plain.animation_file))) > np.abs(np.median(low))


@needs_cmu
def test_stature_within_2cm_on_held_out_clips_made_with_from_motion(tmp_path):
    from smplik.cli.main import app

    split = json.loads((CMU / "split.json").read_text())
    clips = split["test"]["files"][::4]
    made = tmp_path / "t.json"
    res = CliRunner().invoke(app, ["track", "--from-motion", str(CMU / clips[0]), "--out", str(made)])
    assert res.exit_code == 0 and made.is_file(), res.output
    errors = []
    for clip in clips:
        for beta0, gender in ((-1.5, "female"), (0.0, "neutral"), (1.5, "male")):
            betas = np.zeros(10)
            betas[0] = beta0
            sig, truth = motion_signals(CMU / clip, betas=betas, gender=gender)
            cal = calibrate(sig, gender=gender)
            errors.append(cal.stature_m - body_heights(truth.betas, gender)[1])
    assert np.abs(errors).max() < 0.02, errors
    doc = read_trackers(made)  # the file --from-motion wrote is a smplik-trackers file of the clip
    assert doc.names == ("head", "left_wrist", "right_wrist", "pelvis") and doc.fps == 60.0
    assert abs(calibrate(doc).stature_m - 1.70) < 0.02


def test_from_motion_reads_an_animation_file(tmp_path, walk_signals):
    """animation.json (what `smplik track` writes) -> trackers again: the same head and pelvis path."""
    from workflows.tracking.run import track_file

    (tmp_path / "w.json").write_text(json.dumps(walk_signals.to_dict()))
    out = track_file(tmp_path / "w.json", tmp_path / "o", formats=[])
    again, truth = motion_signals(out.animation_file)
    assert again.num_frames == walk_signals.num_frames
    assert np.linalg.norm(again.positions[:, 0] - walk_signals.positions[:, 0], axis=-1).mean() < 0.05
    (tmp_path / "notes.txt").write_text("walk")
    with pytest.raises(ValueError, match="notes.txt: not a motion file"):
        motion_signals(tmp_path / "notes.txt")


def test_devices_need_a_pose_each(walk_signals, tmp_path):
    rec = read_csv_devices(write_device_csv(walk_signals, tmp_path / "r.csv", "omnicept"))
    from dataclasses import replace

    lost = replace(rec, right=(rec.right[0], rec.right[1], np.zeros_like(rec.right[2])))
    with pytest.raises(CalibrationError, match="the right controller has no valid pose"):
        signals_from_devices(lost)


def test_options_apply_to_their_files_and_a_misnamed_csv_is_read(walk_signals, tmp_path):
    path = write_device_csv(walk_signals, tmp_path / "rec.csv", "omnicept")
    (tmp_path / "rec.txt").write_text(path.read_text())  # not named .csv: not JSON, read as CSV
    assert np.allclose(read_trackers(tmp_path / "rec.txt").positions, read_trackers(path).positions)
    (tmp_path / "w.json").write_text(json.dumps(walk_signals.to_dict()))
    with pytest.raises(TrackerFileError, match="w.json: --csv-units is for CSV recordings"):
        read_trackers(tmp_path / "w.json", units="cm")
    with pytest.raises(TrackerFileError, match="w.json: --controller is for device recordings"):
        read_trackers(tmp_path / "w.json", controller="vive")
    (tmp_path / "junk.txt").write_text("a,b\n1,2\n")
    with pytest.raises(TrackerFileError, match="It is not a VR CSV recording either: .*junk.txt"):
        read_trackers(tmp_path / "junk.txt")


def test_steamvr_log_takes_the_controller_offsets(walk_signals, tmp_path):
    """A SteamVR JSON-lines log keeps the controllers' rotations for their wrist points (--controller)."""
    rec = read_csv_devices(write_device_csv(walk_signals, tmp_path / "r.csv", "who-is-alyx", controller="vive"))
    lines = []
    for i, t in enumerate(rec.times):
        devs = [{"index": k, "class": c, "pose": {"valid": True, "position": dict(zip("xyz", d[0][i], strict=True)),
                                                   "quaternion": dict(zip("wxyz", d[1][i], strict=True))}}
                for k, (c, d) in enumerate((("HMD", rec.hmd), ("Controller", rec.left), ("Controller", rec.right)))]
        lines.append(json.dumps({"timestamp": float(t), "devices": devs}))
    (tmp_path / "log.jsonl").write_text("\n".join(lines) + "\n")
    vive = read_trackers(tmp_path / "log.jsonl", controller="vive")
    n = vive.num_frames  # the JSON-lines reader counts whole frames of the span (the last may fall short)
    assert n >= walk_signals.num_frames - 1
    assert np.linalg.norm(vive.positions - walk_signals.positions[:n, :3], axis=-1).max() < 0.01
    plain = read_trackers(tmp_path / "log.jsonl")  # the default: the controllers' positions (as --live)
    np.testing.assert_allclose(np.linalg.norm(plain.positions[:, 1:] - vive.positions[:, 1:], axis=-1),
                               np.linalg.norm(CONTROLLERS["vive"]), atol=1e-6)


def test_from_motion_reads_an_fbx_file(tmp_path):
    """A real FBX (Maya HumanIK, tests/data/fbx) through `smplik track --from-motion`: a trackers file at 60 Hz
    whose head stands at the default body's head height and which `smplik track` reads back."""
    from smplik.cli.main import app
    from smplik.data.fbx import read_fbx

    fbx = Path(__file__).resolve().parent / "data" / "fbx" / "maya_human_ik_7400_binary.fbx"
    res = CliRunner().invoke(app, ["track", "--from-motion", str(fbx), "--out", str(tmp_path / "t.json")])
    assert res.exit_code == 0, res.output
    sig = read_trackers(tmp_path / "t.json")
    motion = read_fbx(fbx)
    assert sig.fps == 60.0 and sig.num_frames == int(np.floor((motion.num_frames - 1) / motion.fps * 60 + 1e-9)) + 1
    # the default body; this clip's head stands 2 cm higher than a walk's (the 1 cm allowance is for walks)
    assert abs(calibrate(sig).stature_m - body_heights(np.zeros(10))[1]) < 0.05
    res = CliRunner().invoke(app, ["track", "--from-motion", str(tmp_path / "t.json"), "--out", str(tmp_path / "x")])
    assert res.exit_code == 1 and "t.json" in res.output and "Traceback" not in res.output
