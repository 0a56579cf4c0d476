"""Live tracking over the VMC protocol (``smplik track --live``): the Unity <-> SMPL conversions, the loop over UDP on
localhost (a known pose's trackers in, the tracker's pose out as VMC bones), record -> replay, SteamVR lines on stdin.

The message layouts follow the protocol's own sender and receiver samples (sh-akira/VirtualMotionCaptureProtocol,
``sample/VRM0/SampleBonesSendBundle.cs``: ``/VMC/Ext/Root/Pos "root" px py pz qx qy qz qw``, then per
``HumanBodyBones`` ``/VMC/Ext/Bone/Pos name localPosition localRotation``, then ``/VMC/Ext/OK 1``;
``SampleTrackerSend.cs`` / the Performer spec: ``/VMC/Ext/{Hmd,Con,Tra}/Pos serial px py pz qx qy qz qw``). No
timing is asserted: every wait polls with a generous hang guard.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pythonosc", reason="python-osc is a dependency of smplik: pip install -e .")

from pythonosc.osc_bundle import OscBundle  # noqa: E402
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder  # noqa: E402
from pythonosc.osc_message_builder import OscMessageBuilder  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from smplik.tracking import vmc  # noqa: E402
from smplik.tracking.config import TRACKER_SETS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
HANG_GUARD_S = 60.0
UNITY_BONES = ("Hips", "LeftUpperLeg", "RightUpperLeg", "Spine", "LeftLowerLeg", "RightLowerLeg", "Chest",
               "LeftFoot", "RightFoot", "UpperChest", "LeftToes", "RightToes", "Neck", "LeftShoulder",
               "RightShoulder", "Head", "LeftUpperArm", "RightUpperArm", "LeftLowerArm", "RightLowerArm", "LeftHand",
               "RightHand")
"""Unity's HumanBodyBones names the issue asks for (written out here, not taken from the module)."""


# ----------------------------------------------------------------------------- a known motion and its trackers


def known_motion(T: int = 60, fps: float = 60.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A walk forward (+z) with swinging legs, arms down and a head turned 20 degrees to the left, on the built-in
    neutral body: R_local (T, 24, 3, 3), transl (T, 3), J_rest (24, 3)."""
    import torch

    from smplik.body_model import BodyModelSet
    from smplik.conventions import Gender

    t = np.arange(T) / fps
    aa = np.zeros((T, 24, 3))
    swing = 0.4 * np.sin(2 * np.pi * t)
    aa[:, 1, 0], aa[:, 2, 0] = swing, -swing
    aa[:, 4, 0], aa[:, 5, 0] = np.maximum(0, -swing), np.maximum(0, swing)
    aa[:, 16, 2], aa[:, 17, 2] = -1.2, 1.2
    aa[:, 18, 1], aa[:, 19, 1] = -0.8, 0.8
    aa[:, 15, 1] = np.deg2rad(20)
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    transl = np.stack([np.zeros(T), np.zeros(T), 1.0 * t], -1)
    J = BodyModelSet.load().rest_joints(torch.zeros(10), torch.tensor(Gender.NEUTRAL.index)).double().numpy()
    return R, transl, J


def smpl_trackers(T: int = 60):
    """The known motion's trackers (head with rotation, wrists, pelvis), SMPL frame."""
    from smplik.tracking.io import signals_from_motion

    R, transl, J = known_motion(T)
    return signals_from_motion(R, transl, J, TRACKER_SETS["4"], 60.0)


def unity_devices(sig, t: int) -> list[tuple[str, str, list[float]]]:
    """Frame t of the trackers as a VMC performer sends them: (address, serial, [px py pz qx qy qz qw]) in Unity's
    frame, the headset worn on the head (hand-written mirror: x negated; quaternion (x, -y, -z, w))."""
    R_head = Rotation.from_quat(sig.rotations[t, 0][[1, 2, 3, 0]]).as_matrix()
    p_hmd, _ = vmc.head_to_hmd(sig.positions[t, 0], R_head)
    qx, qy, qz, qw = Rotation.from_matrix(R_head).as_quat()
    out = [("/VMC/Ext/Hmd/Pos", "HMD-1", [-p_hmd[0], p_hmd[1], p_hmd[2], qx, -qy, -qz, qw])]
    for address, serial, k in (("/VMC/Ext/Con/Pos", "LHR-RIGHT", 2), ("/VMC/Ext/Con/Pos", "LHR-LEFT", 1),
                               ("/VMC/Ext/Tra/Pos", "LHR-WAIST", 3)):
        p = sig.positions[t, k]
        out.append((address, serial, [-p[0], p[1], p[2], 0.0, 0.0, 0.0, 1.0]))
    return out


def device_bundle(devices) -> bytes:
    bundle = OscBundleBuilder(IMMEDIATELY)
    for address, serial, values in devices:
        m = OscMessageBuilder(address)
        m.add_arg(serial)
        for v in values:
            m.add_arg(float(v))
        bundle.add_content(m.build())
    return bundle.build().dgram


def expected_poses(sig, foot_locks: str = "streaming"):
    """The streaming tracker's poses on the known trackers, run here directly (head rotation, positions only for
    the wrists and pelvis, as the live input gives them)."""
    from dataclasses import replace

    from smplik.tracking.config import TrackerRuntimeConfig
    from smplik.tracking.runtime import Tracker

    tracker = Tracker.load(config=TrackerRuntimeConfig())
    tracker.reset(np.array([True, False, False, False]))
    sig = replace(sig, has_rotation=np.array([True, False, False, False]))
    return [tracker.step(sig.positions[t], sig.rotations[t]) for t in range(sig.num_frames)]


class Receiver:
    """A VMC receiver on 127.0.0.1 (any free port) collecting datagrams, parsed with python-osc."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(HANG_GUARD_S)
        self.port = self.sock.getsockname()[1]

    def bundle(self) -> list[tuple[str, list]]:
        data = self.sock.recv(65536)
        assert OscBundle.dgram_is_bundle(data), "the live loop sends one OSC bundle per frame"
        return [(m.address, list(m.params)) for m in OscBundle(data)]

    def close(self) -> None:
        self.sock.close()


def bones_of(messages) -> np.ndarray:
    """The (22, 7) bone values of one bundle, in :data:`UNITY_BONES` order."""
    got = {args[0]: args[1:] for address, args in messages if address == "/VMC/Ext/Bone/Pos"}
    return np.array([got[name] for name in UNITY_BONES], dtype=np.float64)


# ----------------------------------------------------------------------------- pure conversions


def test_unity_conventions_by_hand():
    # a body turned 90 degrees to its left (SMPL yaw +90: +z forward -> +x, the body's left) faces Unity's -x,
    # which Unity writes as Euler y = -90: quaternion (0, -sin 45, 0, cos 45)
    R = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    np.testing.assert_allclose(vmc.smpl_matrix_to_unity_quat(R), [0, -np.sqrt(0.5), 0, np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(vmc.mirror_points([0.3, 1.5, 2.0]), [-0.3, 1.5, 2.0])
    # a device at Unity's identity looks along +z with +x to its right: SMPL's joint frame (+x to the left)
    p, R = vmc.device_to_smpl(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    np.testing.assert_allclose(p, [-1.0, 2.0, 3.0])
    np.testing.assert_allclose(R, np.eye(3), atol=1e-12)
    assert [b for b, _ in vmc.VMC_BONES] == list(UNITY_BONES)


def test_bones_round_trip_and_unity_fk_is_smpl_fk_mirrored():
    from smplik.tracking.fast import fk_np

    R, transl, J = known_motion(20)
    bones = vmc.pose_to_vmc_bones(R, transl, J)
    assert bones.shape == (20, 22, 7)
    R_back, hips = vmc.vmc_bones_to_pose(bones)
    np.testing.assert_allclose(R_back, R[:, vmc.BONE_JOINTS], atol=1e-9)
    G, p = fk_np(R, J, transl)
    np.testing.assert_allclose(hips, p[:, 0], atol=1e-12)
    # what a Unity receiver composes from the local poses is SMPL's world pose in Unity's frame
    p_u, G_u = vmc.unity_fk(bones)
    np.testing.assert_allclose(p_u, vmc.mirror_points(p[:, vmc.BONE_JOINTS]), atol=1e-9)
    np.testing.assert_allclose(G_u, vmc.mirror_rotations(G[:, vmc.BONE_JOINTS]), atol=1e-9)
    # the rest pose: identity local rotations (a normalised VRM T-pose)
    rest = vmc.pose_to_vmc_bones(np.tile(np.eye(3), (24, 1, 1)), np.zeros(3), J)
    np.testing.assert_allclose(rest[:, 3:], np.tile([0, 0, 0, 1.0], (22, 1)), atol=1e-12)


def test_ticks_resample_a_90hz_stream_as_the_recording_reader_does():
    from smplik.tracking.io import TrackerSignals
    from smplik.tracking.runtime import resample_signals
    from workflows.tracking.live import TickResampler

    rng = np.random.default_rng(0)
    P = np.cumsum(rng.normal(0, 0.01, (31, 2, 3)), 0)
    Q = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (31 * 2, 3)), 0)).as_quat()[:, [3, 0, 1, 2]]
    Q = Q.reshape(31, 2, 4)
    ticks = TickResampler(90.0, 60.0)
    out = [tick for t in range(31) for tick in ticks.push(P[t], Q[t])]
    assert len(out) == 21  # ticks at k/60 <= 30/90 s
    ref_P, ref_Q, _ = resample_signals(TrackerSignals(90.0, ("a", "b"), P, Q, np.ones(2, bool)), 60.0)
    np.testing.assert_allclose(np.stack([o[0] for o in out]), ref_P, atol=1e-9)
    got_Q = np.stack([o[1] for o in out])
    np.testing.assert_allclose(np.abs((got_Q * ref_Q).sum(-1)), 1.0, atol=1e-9)
    same = TickResampler(60.0, 60.0)
    for t in range(5):
        (p, q), = same.push(P[t], Q[t])
        assert np.array_equal(p, P[t]) and np.array_equal(q, Q[t])


# ----------------------------------------------------------------------------- the loop over UDP


def run_live_in_thread(config, live):
    from workflows.tracking.live import run_vmc

    ready, result = threading.Event(), {}

    def on_ready(addr):
        result["addr"] = addr
        ready.set()

    def target():
        try:
            result["stats"] = run_vmc(live, config, on_ready=on_ready)
        except BaseException as exc:  # noqa: BLE001 - handed to the test thread
            result["error"] = exc
            ready.set()

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    assert ready.wait(HANG_GUARD_S), "the live loop did not start listening"
    assert "error" not in result, result.get("error")
    return thread, result


def test_known_pose_in_same_pose_out_over_udp_and_record_replays(tmp_path):
    from workflows.tracking.live import LiveConfig, LiveTracker, open_tracker
    from workflows.tracking.run import track_file

    T = 45
    sig = smpl_trackers(T)
    receiver = Receiver()
    record = tmp_path / "session.json"
    config = LiveConfig(vmc_out=("127.0.0.1", receiver.port), vmc_in=("127.0.0.1", 0), waist_serial="LHR-WAIST",
                        max_frames=T, idle_timeout_s=HANG_GUARD_S, record=record)
    live = LiveTracker(open_tracker(TRACKER_SETS["4"], betas=np.zeros(10), gender="neutral"), record=True)
    thread, result = run_live_in_thread(config, live)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    bundles = []
    try:
        for t in range(T):  # one frame, then wait for its bundle: nothing is dropped, whatever the machine's load
            sender.sendto(device_bundle(unity_devices(sig, t)), result["addr"])
            bundles.append(receiver.bundle())
    finally:
        sender.close()
        receiver.close()
    thread.join(HANG_GUARD_S)
    assert not thread.is_alive() and "error" not in result, result.get("error")
    stats = result["stats"]
    assert stats.frames_in == T and stats.bundles_out == T and stats.ignored == 0

    # message names, argument layouts, bundle order: Root, the 22 bones, OK
    for messages in bundles:
        addresses = [a for a, _ in messages]
        assert addresses == ["/VMC/Ext/Root/Pos"] + ["/VMC/Ext/Bone/Pos"] * 22 + ["/VMC/Ext/OK"]
        assert messages[0][1][0] == "root" and len(messages[0][1]) == 8
        assert [args[0] for _, args in messages[1:-1]] == list(UNITY_BONES)
        assert all(len(args) == 8 and all(isinstance(v, float) for v in args[1:]) for _, args in messages[:-1])
        assert messages[-1][1] == [1]
        np.testing.assert_allclose(messages[0][1][1:], [0, 0, 0, 0, 0, 0, 1])

    # the bones, converted back, are the streaming tracker's pose on the known trackers
    received = np.stack([bones_of(m) for m in bundles])  # (T, 22, 7)
    R_got, hips_got = vmc.vmc_bones_to_pose(received)
    poses = expected_poses(sig)
    R_want = np.stack([p.R_local[vmc.BONE_JOINTS] for p in poses])
    from smplik.tracking.fast import fk_np

    _, p_want = fk_np(np.stack([p.R_local for p in poses]), live.tracker.J_rest64, np.stack([p.transl for p in poses]))
    angle = np.linalg.norm(Rotation.from_matrix((np.swapaxes(R_got, -1, -2) @ R_want).reshape(-1, 3, 3)).as_rotvec(),
                           axis=-1)
    assert angle.max() < 2e-3, angle.max()
    np.testing.assert_allclose(hips_got, p_want[:, 0], atol=1e-4)

    # in the sender's own (Unity) coordinates the body stands where its trackers are: head and hands near the
    # headset's head and the controllers (the model's estimate: within 10 cm), the left hand on the left one
    p_u, _ = vmc.unity_fk(received)
    names = list(UNITY_BONES)
    sent = [{serial: np.array(v[:3]) for _, serial, v in unity_devices(sig, t)} for t in range(T)]
    head_u = vmc.mirror_points(sig.positions[:, 0])
    assert np.linalg.norm(p_u[:, names.index("Head")] - head_u, axis=-1).max() < 0.1
    for bone, serial in (("LeftHand", "LHR-LEFT"), ("RightHand", "LHR-RIGHT"), ("Hips", "LHR-WAIST")):
        d = np.linalg.norm(p_u[:, names.index(bone)] - np.stack([s[serial] for s in sent]), axis=-1)
        assert d.max() < 0.1, (bone, d.max())
    assert (p_u[:, names.index("LeftHand"), 0] < p_u[:, names.index("RightHand"), 0]).all()  # Unity +x: right

    # record -> replay: `smplik track FILE --foot-locks streaming` gives the same poses
    doc = json.loads(record.read_text())
    assert doc["format"] == "smplik-trackers" and doc["fps"] == 60.0
    assert list(doc["trackers"]) == list(TRACKER_SETS["4"])
    assert len(doc["trackers"]["head"]["position"]) == T and "rotation" not in doc["trackers"]["left_wrist"]
    outputs = track_file(record, tmp_path / "replay", foot_locks="streaming", formats=[], calibrate=False)
    track = outputs.animation.tracks[0]
    R_replay = Rotation.from_rotvec(np.concatenate([track.global_orient[:, None], track.body_pose], 1).reshape(-1, 3))
    R_replay = R_replay.as_matrix().reshape(T, 24, 3, 3)[:, vmc.BONE_JOINTS]
    angle = np.linalg.norm(Rotation.from_matrix((np.swapaxes(R_got, -1, -2) @ R_replay).reshape(-1, 3, 3))
                           .as_rotvec(), axis=-1)
    assert angle.max() < 2e-3, angle.max()


def test_device_messages_one_by_one_and_named_controllers(tmp_path):
    """A sender without bundles, the right controller first and named by serial: each complete set is one frame."""
    from workflows.tracking.live import LiveConfig, LiveTracker, open_tracker

    T = 6
    sig = smpl_trackers(T)
    receiver = Receiver()
    config = LiveConfig(vmc_out=("127.0.0.1", receiver.port), vmc_in=("127.0.0.1", 0), left_serial="LHR-LEFT",
                        right_serial="LHR-RIGHT", max_frames=T, idle_timeout_s=HANG_GUARD_S)
    live = LiveTracker(open_tracker(TRACKER_SETS["3"], betas=np.zeros(10), gender="neutral"))
    thread, result = run_live_in_thread(config, live)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    bundles = []
    try:
        sender.sendto(b"not osc at all", result["addr"])
        bad = OscMessageBuilder("/VMC/Ext/Con/Pos")
        bad.add_arg("LHR-LEFT")
        bad.add_arg(1.0)
        sender.sendto(bad.build().dgram, result["addr"])  # malformed: counted, ignored
        for t in range(T):
            for address, serial, values in unity_devices(sig, t):
                m = OscMessageBuilder(address)
                m.add_arg(serial)
                for v in values:
                    m.add_arg(float(v))
                sender.sendto(m.build().dgram, result["addr"])
            bundles.append(receiver.bundle())
    finally:
        sender.close()
        receiver.close()
    thread.join(HANG_GUARD_S)
    assert not thread.is_alive() and result["stats"].frames_in == T and result["stats"].ignored == 1
    p_u, _ = vmc.unity_fk(np.stack([bones_of(m) for m in bundles]))
    left, right = UNITY_BONES.index("LeftHand"), UNITY_BONES.index("RightHand")
    assert (p_u[:, left, 0] < p_u[:, right, 0]).all()


# ----------------------------------------------------------------------------- SteamVR JSON lines on stdin


def steamvr_lines(sig) -> list[str]:
    """The known trackers as a SteamVR logger writes them (OpenVR's standing universe: SMPL's frame, the headset
    looking along -z), 60 lines a second."""
    from smplik.tracking.io import HMD_TO_HEAD_M

    half_turn = np.diag([-1.0, 1.0, -1.0])
    lines = []
    for t in range(sig.num_frames):
        R_head = Rotation.from_quat(sig.rotations[t, 0][[1, 2, 3, 0]]).as_matrix()
        R_hmd = R_head @ half_turn
        p_hmd = sig.positions[t, 0] - R_hmd @ HMD_TO_HEAD_M
        devices = []
        for index, cls, p, R in ((0, "HMD", p_hmd, R_hmd), (3, "Controller", sig.positions[t, 2], np.eye(3)),
                                 (4, "Controller", sig.positions[t, 1], np.eye(3)),
                                 (5, "Tracker", sig.positions[t, 3], np.eye(3))):
            x, y, z, w = Rotation.from_matrix(R).as_quat()
            devices.append({"index": index, "class": cls, "pose": {
                "valid": True, "position": dict(zip("xyz", map(float, p), strict=True)),
                "quaternion": {"x": x, "y": y, "z": z, "w": w}}})
        lines.append(json.dumps({"timestamp": t / 60.0, "devices": devices}))
    return lines


def test_steamvr_lines_on_stdin_through_the_command(tmp_path):
    import os

    from smplik.tracking.io import read_steamvr_jsonl
    from workflows.tracking.run import track_file

    T = 20
    sig = smpl_trackers(T)
    lines = steamvr_lines(sig)
    log = tmp_path / "log.jsonl"
    log.write_text("\n".join(lines) + "\n")
    receiver = Receiver()
    record = tmp_path / "rec.json"
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    try:
        with log.open() as stdin:
            proc = subprocess.run([sys.executable, "-m", "smplik.cli", "track", "--live", "--vmc-out",
                                   f"127.0.0.1:{receiver.port}", "--record", str(record)], stdin=stdin,
                                  capture_output=True, text=True, env=env, timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert f"{T} frames in, {T} bundles" in proc.stdout + proc.stderr
        bundles = [receiver.bundle() for _ in range(T)]
    finally:
        receiver.close()
    # the stream is mapped as the file reader maps the same log
    rec = json.loads(record.read_text())
    ref = read_steamvr_jsonl(log)
    for k, name in enumerate(ref.names):
        np.testing.assert_allclose(rec["trackers"][name]["position"], ref.positions[:, k], atol=2e-6)
    # and the bones sent are the replay's poses
    R_got, _ = vmc.vmc_bones_to_pose(np.stack([bones_of(m) for m in bundles]))
    track = track_file(record, tmp_path / "replay", foot_locks="streaming", formats=[],
                       calibrate=False).animation.tracks[0]
    aa = np.concatenate([track.global_orient[:, None], track.body_pose], 1)
    R_replay = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)[:, vmc.BONE_JOINTS]
    angle = np.linalg.norm(Rotation.from_matrix((np.swapaxes(R_got, -1, -2) @ R_replay).reshape(-1, 3, 3))
                           .as_rotvec(), axis=-1)
    assert angle.max() < 2e-3, angle.max()


@pytest.mark.parametrize("args, message", [
    (["--live"], "--vmc-out"),
    (["--live", "--vmc-out", "nohost"], "--vmc-out must be HOST:PORT"),
    (["--live", "--vmc-out", "127.0.0.1:9", "--vmc-in", "70000"], "--vmc-in must be PORT or HOST:PORT"),
    (["--live", "--vmc-out", "127.0.0.1:9", "--samples", "4"], "--samples"),
    (["--record", "x.json"], "--record needs --live"),
    (["--live", "--vmc-out", "127.0.0.1:9", "--left-serial", "A", "--right-serial", "A"], "each controller"),
    (["--live", "--vmc-out", "127.0.0.1:9", "--betas", "0,0,0,0,0,0,0,0,0,0", "--height", "1.7"], "not both"),
])
def test_live_option_errors_are_one_line(args, message):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    res = CliRunner().invoke(app, ["track", *args])
    assert res.exit_code == 1, res.output
    last = res.output.strip().splitlines()[-1]
    assert last.startswith("error: ") and message in last, res.output


def test_height_sets_the_body_stature():
    import torch

    from smplik.body_model import BodyModelSet
    from workflows.tracking.live import LiveError, betas_for_height

    b = betas_for_height(1.85)
    with torch.no_grad():
        verts, _ = BodyModelSet.load()["neutral"].vertices(torch.zeros(1, 3), torch.zeros(1, 23, 3), None,
                                                           torch.as_tensor(b[None], dtype=torch.float32))
    assert abs(float(verts[0, :, 1].max() - verts[0, :, 1].min()) - 1.85) < 0.01
    with pytest.raises(LiveError, match="--height"):
        betas_for_height(0.2)


def test_ctrl_c_stops_with_one_line_and_keeps_the_recording(tmp_path):
    """The command on a VMC port: a few frames, then SIGINT (Ctrl-C): exit 0, one closing line, the recording."""
    import os
    import queue
    import re
    import signal

    T = 5
    sig = smpl_trackers(T)
    receiver = Receiver()
    record = tmp_path / "rec.json"
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", "track", "--live", "--vmc-in", "0",
                             "--vmc-out", f"127.0.0.1:{receiver.port}", "--record", str(record)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp_path)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        first = lines.get(timeout=300)
        match = re.match(r"listening on 127\.0\.0\.1:(\d+) \(head, left_wrist, right_wrist\)", first)
        assert match, first
        for t in range(T):
            sender.sendto(device_bundle(unity_devices(sig, t)[:3]), ("127.0.0.1", int(match.group(1))))
            receiver.bundle()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(HANG_GUARD_S) == 0
    finally:
        sender.close()
        receiver.close()
        if proc.poll() is None:
            proc.kill()
    rest = []
    while not lines.empty():
        rest.append(lines.get())
    assert len(rest) == 1 and rest[0].startswith(f"stopped (Ctrl-C): {T} frames in, {T} bundles"), rest
    assert len(json.loads(record.read_text())["trackers"]["head"]["position"]) == T


def test_a_90hz_stream_steps_the_model_at_60hz_and_sends_a_bundle_per_frame(tmp_path):
    """--fps 90: every input frame gets a bundle (of the newest pose), the model steps at its 60 Hz ticks, and the
    recording holds those ticks, which replay to the poses that were sent."""
    from workflows.tracking.live import LiveConfig, LiveTracker, open_tracker, run_steamvr
    from workflows.tracking.run import track_file

    sig = smpl_trackers(30)
    record = tmp_path / "rec.json"
    sent: list[bytes] = []
    config = LiveConfig(vmc_out=("127.0.0.1", 9), fps=90.0, record=record)
    live = LiveTracker(open_tracker(TRACKER_SETS["4"], betas=np.zeros(10), gender="neutral"), 90.0, record=True)
    stats = run_steamvr(live, config, steamvr_lines(sig), send=sent.append)
    assert stats.frames_in == 30 and len(sent) == 30
    ticks = json.loads(record.read_text())
    assert ticks["fps"] == 60.0 and len(ticks["trackers"]["head"]["position"]) == 20  # k / 60 <= 29 / 90 s
    bones = np.stack([np.array([args[1:] for address, args in
                                [(m.address, list(m.params)) for m in OscBundle(d)]
                                if address == "/VMC/Ext/Bone/Pos"]) for d in sent])
    R_got, _ = vmc.vmc_bones_to_pose(bones)
    track = track_file(record, tmp_path / "replay", foot_locks="streaming", formats=[],
                       calibrate=False).animation.tracks[0]
    aa = np.concatenate([track.global_orient[:, None], track.body_pose], 1)
    R_replay = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(20, 24, 3, 3)[:, vmc.BONE_JOINTS]
    newest_tick = np.floor(np.arange(30) * 60 / 90 + 1e-9).astype(int)  # the last tick at or before each frame
    rel = np.swapaxes(R_got, -1, -2) @ R_replay[newest_tick]
    assert np.linalg.norm(Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec(), axis=-1).max() < 2e-3
