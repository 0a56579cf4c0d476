"""``smplik track --live``: VR trackers in, the body out, frame by frame, over the VMC protocol.

Inputs, one of:

* **VMC** (``vmc_in``): OSC over UDP, ``/VMC/Ext/Hmd/Pos`` (the headset -> SMPL's head),
  ``/VMC/Ext/Con/Pos`` (two controllers -> the wrists, by position), ``/VMC/Ext/Tra/Pos`` (the waist tracker ->
  the pelvis, by position), each ``(string) serial, (float) px, py, pz, qx, qy, qz, qw`` in Unity's frame
  (:mod:`smplik.tracking.vmc`). A datagram (one message or a bundle) ends an input frame when every device the
  model needs has a pose newer than the last frame's, or when a device repeats within the pending frame (a
  device that stopped sending keeps its last pose). Other addresses are ignored; malformed device messages are
  counted and ignored (a live stream keeps running).
* **SteamVR JSON lines** on a text stream (stdin): one line per frame, the records
  :func:`smplik.tracking.io.read_steamvr_jsonl` reads, mapped the same way (headset -> head, two controllers ->
  wrists by position, one generic tracker -> pelvis by position). An invalid device keeps its last pose.

Per input frame, the streaming tracker (:class:`smplik.tracking.runtime.Tracker`, deterministic, causal foot
locks) steps once per model tick (at the model's rate; inputs at another ``fps`` are interpolated to the ticks
by frame count, as :func:`smplik.tracking.runtime.resample_signals` does), and one OSC bundle goes to
``vmc_out``: ``/VMC/Ext/Root/Pos``, ``/VMC/Ext/Bone/Pos`` for each of :data:`smplik.tracking.vmc.VMC_BONES`,
then ``/VMC/Ext/OK 1``. ``record`` keeps the ticks the tracker saw as a ``smplik-trackers`` file (at the model's
rate); ``smplik track FILE --foot-locks streaming`` replays it to the same poses.
"""

from __future__ import annotations

import json
import math
import socket
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from smplik.rotations import matrix_to_quat_wxyz
from smplik.tracking.config import TRACKER_SETS
from workflows.animation.clips import AnimationError

DEVICE_ADDRESSES = {"/VMC/Ext/Hmd/Pos": "hmd", "/VMC/Ext/Con/Pos": "controller", "/VMC/Ext/Tra/Pos": "tracker"}
"""The VMC device messages read, and their kind."""
MAX_DATAGRAM = 65507
"""The largest UDP payload (the receive buffer)."""


class LiveError(AnimationError):
    """A live session cannot start or go on (one line naming the option or the stream)."""


@dataclass(frozen=True)
class LiveConfig:
    """One live session (``smplik track --live``)."""

    vmc_out: tuple[str, int]
    """Where the bundles go (host, port)."""
    vmc_in: tuple[str, int] | None = None
    """Address to receive VMC device messages on (host, port; port 0: any free port); None: SteamVR JSON lines
    from the input stream."""
    left_serial: str | None = None
    """Serial of the left controller (None: the one on the headset's left at the first frame)."""
    right_serial: str | None = None
    """Serial of the right controller."""
    waist_serial: str | None = None
    """Serial of the waist tracker (VMC input): given, the 4-tracker model runs; None: head and hands only."""
    fps: float | None = None
    """Input frame rate (None: the model's, 60): inputs at another rate are interpolated to the model's ticks."""
    max_frames: int | None = None
    """Stop after this many input frames (None: run until stopped)."""
    idle_timeout_s: float | None = None
    """Stop when no input arrives for this long (None: wait for ever)."""
    record: Path | None = None
    """Save the ticks the tracker saw as a ``smplik-trackers`` file here when the session ends."""


@dataclass
class LiveStats:
    """What a session did: input frames, bundles sent, device messages ignored (malformed), and per sent bundle
    the seconds from the datagram that completed its frame (its ``recv`` return) to the ``sendto`` return."""

    frames_in: int = 0
    bundles_out: int = 0
    ignored: int = 0
    latency_s: list[float] = field(default_factory=list)
    stopped: str = ""
    busy: bool = False
    """True while a frame is being processed and sent (a Ctrl-C handler then defers: :attr:`interrupted`)."""
    interrupted: bool = False
    """Set by a deferred Ctrl-C: the loop raises KeyboardInterrupt once the frame is out, so counts stay exact."""

    def frame_done(self) -> None:
        """End of a frame's critical section: raise the Ctrl-C that arrived during it."""
        self.busy = False
        if self.interrupted:
            raise KeyboardInterrupt


def parse_endpoint(text: str, option: str, default_host: str | None = None) -> tuple[str, int]:
    """``HOST:PORT`` (or ``PORT`` when ``default_host``) -> (host, port). Raises LiveError naming ``option``."""
    host, sep, port = str(text).strip().rpartition(":")
    if not sep:
        host = default_host or ""
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        form = "PORT or HOST:PORT" if default_host else "HOST:PORT"
        raise LiveError(f"{option} must be {form} (port 0-65535), got {text!r}.")
    return host, int(port)


# ----------------------------------------------------------------------------- devices -> one frame of trackers


class DeviceFrames:
    """Devices (headset, two controllers, optional waist tracker; SMPL frame) -> frames of the model's trackers
    (:data:`smplik.tracking.config.TRACKER_SETS`: head, left_wrist, right_wrist[, pelvis])."""

    def __init__(self, trackers: tuple[str, ...], left: str | None = None, right: str | None = None,
                 waist: str | None = None) -> None:
        self.trackers, self.left, self.right, self.waist = trackers, left, right, waist
        self.poses: dict[tuple[str, str], tuple[np.ndarray, np.ndarray | None]] = {}
        self.fresh: set[tuple[str, str]] = set()
        self.sides: tuple[tuple[str, str], tuple[str, str]] | None = None
        if left is not None and right is not None:
            self.sides = (("controller", left), ("controller", right))

    def needed(self) -> list[tuple[str, str]] | None:
        """The devices of one frame (head, left, right[, waist]); None until they are known."""
        hmds = [k for k in self.poses if k[0] == "hmd"]
        if not hmds:
            return None
        if self.sides is None:
            sides = self._sides(hmds[0])
            if sides is None:
                return None
            self.sides = sides
        out = [hmds[0], *self.sides]
        if "pelvis" in self.trackers:
            out.append(("tracker", str(self.waist)))
        return out

    def _sides(self, hmd: tuple[str, str]) -> tuple[tuple[str, str], tuple[str, str]] | None:
        ctrls = sorted(k for k in self.poses if k[0] == "controller")
        if self.left is not None or self.right is not None:
            named = ("controller", self.left if self.left is not None else self.right)
            others = [k for k in ctrls if k != named]
            if named not in self.poses or not others:
                return None
            return (named, others[0]) if self.left is not None else (others[0], named)
        if len(ctrls) < 2:
            return None
        (pa, _), (pb, _) = self.poses[ctrls[0]], self.poses[ctrls[1]]
        R_head = self.poses[hmd][1]
        # left = on the headset's left: SMPL's head frame has +x to the body's left (as read_steamvr_jsonl)
        return (ctrls[0], ctrls[1]) if (pa - pb) @ R_head[:, 0] > 0 else (ctrls[1], ctrls[0])

    def update(self, kind: str, serial: str, p: np.ndarray, R: np.ndarray | None
               ) -> tuple[np.ndarray, np.ndarray] | None:
        """One device pose (SMPL frame; R (3, 3) needed for the headset only). Returns the pending frame first when
        this device already updated it (the sender moved on to the next frame), else None."""
        key = (kind, serial)
        out = None
        if key in self.fresh and key in (self.needed() or ()):
            out = self.take()
        self.poses[key] = (p, R)
        self.fresh.add(key)
        return out

    def complete(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The frame, when every needed device has a pose newer than the last frame's; else None."""
        need = self.needed()
        if need is None or any(k not in self.fresh for k in need):
            return None
        return self.take()

    def take(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The current frame from the latest poses: positions (K, 3), quaternions (K, 4) (w, x, y, z)."""
        from smplik.tracking.vmc import hmd_to_head

        need = self.needed()
        if need is None or any(k not in self.poses for k in need):
            return None
        self.fresh.clear()
        p_head, R_head = hmd_to_head(*self.poses[need[0]])
        P = np.stack([p_head, *[self.poses[k][0] for k in need[1:]]])
        Q = np.tile([1.0, 0.0, 0.0, 0.0], (len(need), 1))
        Q[0] = matrix_to_quat_wxyz(R_head)
        return P, Q


def _vmc_device(args: list[Any]) -> tuple[str, np.ndarray, np.ndarray] | None:
    """``serial, px, py, pz, qx, qy, qz, qw`` -> (serial, p (3,), q (4,) x y z w, Unity); None if malformed."""
    if len(args) != 8 or not isinstance(args[0], str):
        return None
    values = args[1:]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return None
    v = np.asarray(values, dtype=np.float64)
    if not np.isfinite(v).all() or np.abs(v[:3]).max() > 1000.0 or np.linalg.norm(v[3:]) < 1e-6:
        return None
    return args[0], v[:3], v[3:]


def vmc_messages(dgram: bytes) -> list[tuple[str, list[Any]]]:
    """An OSC datagram (a message or a bundle, nested bundles flattened) -> [(address, arguments)]; [] if it is
    not OSC."""
    from pythonosc.osc_packet import OscPacket, ParseError

    try:
        return [(m.message.address, list(m.message.params)) for m in OscPacket(dgram).messages]
    except (ParseError, ValueError, IndexError, struct.error):
        return []


def steamvr_devices(line: str, n: int) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """One SteamVR JSON line (:func:`smplik.tracking.io.read_steamvr_jsonl`) -> [(kind, serial, p (3,), R (3, 3))]
    of its valid devices in SMPL's frame (OpenVR's standing universe is right-handed, y up: no mirror; the
    headset's rotation turned half a turn about its y axis, as the file reader does). Raises LiveError naming
    the line."""
    from scipy.spatial.transform import Rotation

    kinds = {"HMD": "hmd", "Controller": "controller", "Tracker": "tracker"}
    out = []
    try:
        frame = json.loads(line)
        for dev in frame["devices"]:
            pose = dev.get("pose")
            kind = kinds.get(str(dev["class"]))
            if kind is None or not pose or not pose.get("valid", False):
                continue
            p = np.array([pose["position"][k] for k in "xyz"], dtype=np.float64)
            q = np.array([pose["quaternion"][k] for k in "xyzw"], dtype=np.float64)
            if not (np.isfinite(p).all() and np.isfinite(q).all()) or np.linalg.norm(q) < 1e-6:
                continue
            R = Rotation.from_quat(q).as_matrix()
            if kind == "hmd":
                R = R @ np.diag([-1.0, 1.0, -1.0])
            out.append((kind, str(dev["index"]), p, R))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise LiveError(f"stdin: line {n}: not a SteamVR log record ({type(exc).__name__}: {exc}).") from None
    return out


# ----------------------------------------------------------------------------- the tracker side


class TickResampler:
    """Input frames at ``fps_in`` -> the model's ticks at ``fps_model`` (frame-count time: input frame i at
    ``i / fps_in``; linear positions, normalised-linear quaternions kept sign-continuous, as
    :func:`smplik.tracking.runtime.resample_signals`). At equal rates every frame is its own tick, unchanged."""

    def __init__(self, fps_in: float, fps_model: float) -> None:
        self.ratio = fps_model / fps_in
        self.i, self.next_tick = -1, 0
        self.prev: tuple[np.ndarray, np.ndarray] | None = None

    def push(self, P: np.ndarray, Q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """One input frame (positions (K, 3), quaternions (K, 4)) -> the ticks (0 or more) it completes."""
        self.i += 1
        if self.ratio == 1.0:
            return [(P, Q)]
        if self.prev is not None:
            Q = Q * np.where((Q * self.prev[1]).sum(-1) < 0, -1.0, 1.0)[:, None]
        out = []
        while self.next_tick <= self.i * self.ratio + 1e-9:
            a = self.next_tick / self.ratio - (self.i - 1)  # 0 at the previous frame, 1 at this one
            if self.prev is None or a >= 1.0 - 1e-9:
                out.append((P, Q))
            else:
                q = (1.0 - a) * self.prev[1] + a * Q
                out.append(((1.0 - a) * self.prev[0] + a * P, q / np.linalg.norm(q, axis=-1, keepdims=True)))
            self.next_tick += 1
        self.prev = (P, Q)
        return out


class BundleEncoder:
    """Poses -> the VMC bundle's bytes. The message layouts come from python-osc's builders once (address, type
    tags ``,sfffffff``, the padded bone name); per frame only the floats are packed."""

    def __init__(self) -> None:
        from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
        from pythonosc.osc_message_builder import OscMessageBuilder

        from smplik.tracking.vmc import VMC_BONES

        def message(address: str, *args: Any) -> bytes:
            b = OscMessageBuilder(address)
            for a in args:
                b.add_arg(a)
            return b.build().dgram

        zeros = (0.0,) * 7
        self.root_prefix = message("/VMC/Ext/Root/Pos", "root", *zeros)[:-28]
        self.bone_prefixes = [message("/VMC/Ext/Bone/Pos", name, *zeros)[:-28] for name, _ in VMC_BONES]
        self.ok = message("/VMC/Ext/OK", 1)
        self.header = OscBundleBuilder(IMMEDIATELY).build().dgram  # "#bundle\0" + the time tag

    def encode(self, root: np.ndarray, bones: np.ndarray) -> bytes:
        """root (7,) and bones (22, 7) (positions, quaternions x y z w; Unity) -> one OSC bundle: Root, Bones, OK."""
        parts = [self.header]
        for prefix, values in zip([self.root_prefix, *self.bone_prefixes], [root, *bones], strict=True):
            content = prefix + struct.pack(">7f", *values)
            parts.append(struct.pack(">i", len(content)) + content)
        parts.append(struct.pack(">i", len(self.ok)) + self.ok)
        return b"".join(parts)


class LiveTracker:
    """A :class:`~smplik.tracking.runtime.Tracker` fed input frames: :meth:`frame` -> the bundle to send."""

    def __init__(self, tracker: Any, fps_in: float | None = None, record: bool = False) -> None:
        from smplik.tracking.vmc import ROOT_POSE

        self.tracker = tracker
        self.ticks = TickResampler(fps_in or tracker.fps, tracker.fps)
        self.encoder = BundleEncoder()
        self.root = ROOT_POSE
        self.last: Any = None
        self.recorded: list[tuple[np.ndarray, np.ndarray]] | None = [] if record else None

    def frame(self, P: np.ndarray, Q: np.ndarray) -> bytes | None:
        """One input frame (positions (K, 3), quaternions (K, 4) w x y z; SMPL frame, model order) -> the
        bundle of the newest pose (the previous one again when the frame completes no tick)."""
        from smplik.tracking.vmc import pose_to_vmc_bones

        for p, q in self.ticks.push(P, Q):
            self.last = self.tracker.step(p, q)
            if self.recorded is not None:
                self.recorded.append((p, q))
        if self.last is None:
            return None
        return self.encoder.encode(self.root, pose_to_vmc_bones(self.last.R_local, self.last.transl,
                                                                self.tracker.J_rest64))

    def save(self, path: Path, has_rotation: np.ndarray) -> Path:
        """The recorded ticks as a ``smplik-trackers`` file (atomic)."""
        from smplik.atomic import write_json_atomic
        from smplik.tracking.io import TrackerSignals

        rows = self.recorded or []
        if not rows:
            raise LiveError(f"--record {path}: no frame was received; nothing recorded.")
        signals = TrackerSignals(float(self.tracker.fps), tuple(self.tracker.trackers), np.stack([r[0] for r in rows]),
                                 np.stack([r[1] for r in rows]), np.asarray(has_rotation, bool), str(path))
        return write_json_atomic(path, signals.to_dict())


def betas_for_height(height_m: float, gender: Any = "neutral") -> np.ndarray:
    """Betas (10,) whose first component gives a rest body of stature ``height_m`` (max - min vertex height),
    the others zero. Raises LiveError outside the body model's reach (first component in [-4, 4])."""
    import torch

    from smplik.body_model import BodyModelSet

    if not math.isfinite(height_m) or not 0.5 <= height_m <= 2.6:
        raise LiveError(f"--height must be a stature in metres in [0.5, 2.6], got {height_m}.")
    grid = np.linspace(-4.0, 4.0, 33)
    betas = torch.zeros(len(grid), 10)
    betas[:, 0] = torch.as_tensor(grid, dtype=torch.float32)
    z = torch.zeros(len(grid), 3)
    with torch.no_grad():
        verts, _ = BodyModelSet.load()[gender].vertices(z, torch.zeros(len(grid), 23, 3), z, betas)
    stature = (verts[..., 1].max(-1).values - verts[..., 1].min(-1).values).double().numpy()
    order = np.argsort(stature)
    if not np.all(np.diff(stature[order]) > 0) or not stature.min() <= height_m <= stature.max():
        raise LiveError(f"--height {height_m} m is outside this body model's range "
                        f"({stature.min():.2f}-{stature.max():.2f} m); give --betas instead.")
    out = np.zeros(10)
    out[0] = float(np.interp(height_m, stature[order], grid[order]))
    return out


# ----------------------------------------------------------------------------- the loops


def _finish(live: LiveTracker, config: LiveConfig, has_rotation: np.ndarray, stats: LiveStats) -> None:
    if config.record is not None and live.recorded:
        live.save(config.record, has_rotation)


def run_vmc(live: LiveTracker, config: LiveConfig, *, on_ready: Callable[[tuple[str, int]], None] | None = None,
            stats: LiveStats | None = None) -> LiveStats:
    """Receive VMC device messages on ``config.vmc_in``, send a bundle per input frame to ``config.vmc_out``,
    until ``max_frames``, ``idle_timeout_s`` or Ctrl-C (KeyboardInterrupt, re-raised after the recording is
    saved). ``on_ready`` gets the bound (host, port) once the socket listens (port 0 picks a free one)."""
    from smplik.tracking.vmc import device_to_smpl, mirror_points

    assert config.vmc_in is not None
    stats = LiveStats() if stats is None else stats
    devices = DeviceFrames(live.tracker.trackers, config.left_serial, config.right_serial, config.waist_serial)
    has_rotation = np.zeros(len(live.tracker.trackers), bool)
    has_rotation[0] = True
    live.tracker.reset(has_rotation)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        try:
            sock.bind(config.vmc_in)
        except OSError as exc:
            host, port = config.vmc_in
            raise LiveError(f"--vmc-in {host}:{port}: cannot listen ({exc.strerror}).") from None
        sock.settimeout(0.25)
        if on_ready is not None:
            on_ready(sock.getsockname()[:2])
        out = _resolve(config.vmc_out)
        last_input = time.monotonic()
        while config.max_frames is None or stats.frames_in < config.max_frames:
            try:
                dgram = sock.recv(MAX_DATAGRAM)
            except TimeoutError:
                if config.idle_timeout_s is not None and time.monotonic() - last_input > config.idle_timeout_s:
                    stats.stopped = f"no input for {config.idle_timeout_s:g} s"
                    break
                continue
            t_recv = time.perf_counter()
            stats.busy = True
            last_input = time.monotonic()
            frames = []
            for address, args in vmc_messages(dgram):
                kind = DEVICE_ADDRESSES.get(address)
                if kind is None:
                    continue
                device = _vmc_device(args)
                if device is None:
                    stats.ignored += 1
                    continue
                serial, p_u, q_u = device
                if kind == "tracker" and serial != config.waist_serial:
                    continue
                if kind == "hmd":
                    p, R = device_to_smpl(p_u, q_u)
                else:  # controllers and the waist tracker give positions only (their frames are not the joints')
                    p, R = mirror_points(p_u), None
                frame = devices.update(kind, serial, p, R)
                if frame is not None:
                    frames.append(frame)
            frame = devices.complete()
            if frame is not None:
                frames.append(frame)
            for P, Q in frames:
                stats.frames_in += 1
                bundle = live.frame(P, Q)
                if bundle is not None:
                    sock.sendto(bundle, out)
                    stats.bundles_out += 1
                    stats.latency_s.append(time.perf_counter() - t_recv)
            stats.frame_done()
        if not stats.stopped:
            stats.stopped = f"{stats.frames_in} frames"
    finally:
        sock.close()
        _finish(live, config, has_rotation, stats)
    return stats


def run_steamvr(live: LiveTracker, config: LiveConfig, lines: Iterable[str] | TextIO,
                send: Callable[[bytes], None] | None = None, stats: LiveStats | None = None) -> LiveStats:
    """SteamVR JSON lines (a text stream, e.g. stdin) -> a bundle per line to ``config.vmc_out`` (or ``send``),
    until the stream ends or ``max_frames``. Raises LiveError on a line that is not a record."""
    stats = LiveStats() if stats is None else stats
    has_rotation = np.zeros(len(live.tracker.trackers), bool)
    has_rotation[0] = True
    live.tracker.reset(has_rotation)
    waist = None
    devices = DeviceFrames(live.tracker.trackers, config.left_serial, config.right_serial, None)
    sock = None
    if send is None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        out = _resolve(config.vmc_out)

        def send(data: bytes) -> None:
            sock.sendto(data, out)
    try:
        for n, line in enumerate(lines, 1):
            if config.max_frames is not None and stats.frames_in >= config.max_frames:
                break
            if not line.strip():
                continue
            t_recv = time.perf_counter()
            stats.busy = True
            for kind, serial, p, R in steamvr_devices(line, n):
                if kind == "tracker":
                    waist = serial if waist is None else waist
                    devices.waist = waist
                    if serial != waist:
                        continue
                devices.poses[(kind, serial)] = (p, R)
            frame = devices.take()
            if frame is not None:
                stats.frames_in += 1
                bundle = live.frame(*frame)
                if bundle is not None:
                    send(bundle)
                    stats.bundles_out += 1
                    stats.latency_s.append(time.perf_counter() - t_recv)
            stats.frame_done()
        stats.stopped = f"{stats.frames_in} frames"
    finally:
        if sock is not None:
            sock.close()
        _finish(live, config, has_rotation, stats)
    return stats


def _resolve(endpoint: tuple[str, int]) -> tuple[str, int]:
    try:
        return socket.getaddrinfo(endpoint[0], endpoint[1], socket.AF_INET, socket.SOCK_DGRAM)[0][4][:2]
    except OSError as exc:
        raise LiveError(f"--vmc-out {endpoint[0]}:{endpoint[1]}: cannot resolve the host ({exc}).") from None


def first_line_trackers(line: str) -> tuple[str, ...]:
    """The model's trackers for a SteamVR stream, from its first line: with one generic tracker, the 4-tracker
    set (head, wrists, pelvis); else head and wrists."""
    n = sum(1 for kind, *_ in steamvr_devices(line, 1) if kind == "tracker")
    return TRACKER_SETS["4"] if n == 1 else TRACKER_SETS["3"]


def open_tracker(trackers: tuple[str, ...], *, betas: np.ndarray, gender: Any, checkpoint: Path | None = None,
                 fit_trackers: bool = False) -> Any:
    """The streaming tracker for ``trackers`` (the shipped model unless ``checkpoint``), warmed up (the numba
    kernels compile on the first step) and reset."""
    from smplik.tracking.config import TrackerRuntimeConfig
    from smplik.tracking.model_io import shipped_checkpoint
    from smplik.tracking.runtime import Tracker

    path = checkpoint if checkpoint is not None else shipped_checkpoint(trackers)
    tracker = Tracker.load(path, betas=betas, gender=gender, config=TrackerRuntimeConfig(tracker_fit=fit_trackers))
    if tuple(tracker.trackers) != tuple(trackers):
        raise LiveError(f"--checkpoint {path}: the model reads trackers {', '.join(tracker.trackers)}; the live "
                        f"input gives {', '.join(trackers)}.")
    K = len(trackers)
    P = np.tile([0.0, 1.0, 0.0], (K, 1))
    P[0, 1] = 1.6
    Q = np.tile([1.0, 0.0, 0.0, 0.0], (K, 1))
    for _ in range(2):
        tracker.step(P, Q)
    tracker.reset()
    return tracker
