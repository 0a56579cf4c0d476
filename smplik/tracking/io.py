"""Tracker recordings: the ``smplik-trackers`` JSON format (version 1) and a SteamVR JSON-lines log reader.

``smplik-trackers`` version 1 (see docs/formats.md)::

    {"format": "smplik-trackers", "version": 1, "fps": 60,
     "trackers": {"<smpl joint name>": {"position": [[x, y, z], ...], "rotation": [[w, x, y, z], ...]}}}

Metres, y up, world frame (the floor at y = 0), one row per frame, every tracker the same number of rows;
``rotation`` (unit quaternions, scalar first, the joint's world rotation in SMPL's frame: +z forward, +y up)
is optional per tracker. Errors are one line naming the file and the JSON path (:class:`TrackerFileError`).

SteamVR log (:func:`read_steamvr_jsonl`): the JSON lines written by a SteamVR logger polling OpenVR
(``{"timestamp": s, "devices": [{"index": i, "class": "HMD" | "Controller" | "Tracker", "pose": {"valid": b,
"position": {"x", "y", "z"}, "quaternion": {"x", "y", "z", "w"}} | null, ...}]}`` per line, OpenVR's
standing universe: metres, y up, -z forward, floor at y = 0).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import JOINT_NAMES, unknown_joint
from smplik.limits import LimitError, check_rate, check_resampled_frames
from smplik.rotations import axis_angle_to_matrix_np, matrix_to_quat_wxyz, quat_wxyz_to_matrix
from smplik.validation import JSONPathError, finite_array, read_text, short_repr

MAX_ABS_TIMESTAMP_S = 1e10
"""Largest |timestamp| of a SteamVR log line (seconds: Unix time until the year 2286; beyond it a double cannot
resolve a frame)."""
MAX_DEVICE_INDEX = 63
"""Largest OpenVR device index (``k_unMaxTrackedDeviceCount`` is 64)."""
TRACKERS_FORMAT = "smplik-trackers"
TRACKERS_VERSION = 1
MAX_FRAMES = 1_000_000
_ROOT_KEYS = {"format", "version", "fps", "trackers"}
_TRACKER_KEYS = {"position", "rotation"}


class TrackerFileError(ValueError):
    """A tracker file is invalid (one line naming the file and the JSON path)."""


@dataclass(frozen=True)
class TrackerSignals:
    """A tracker recording. T frames, K trackers.

    Attributes: fps; names (K,) SMPL joint names; positions (T, K, 3) metres, y up; rotations (T, K, 4) unit
    quaternions (w, x, y, z), identity where ``has_rotation`` is False; has_rotation (K,) bool; source.
    """

    fps: float
    names: tuple[str, ...]
    positions: np.ndarray
    rotations: np.ndarray
    has_rotation: np.ndarray
    source: str = ""

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])

    def select(self, names: tuple[str, ...]) -> TrackerSignals:
        """The trackers ``names`` in that order. Raises TrackerFileError naming the first missing one."""
        missing = [n for n in names if n not in self.names]
        if missing:
            raise TrackerFileError(f"{self.source}: trackers.{missing[0]}: missing; the model needs trackers "
                                   f"{', '.join(names)} (found {', '.join(self.names)}).")
        idx = [self.names.index(n) for n in names]
        return TrackerSignals(self.fps, tuple(names), self.positions[:, idx], self.rotations[:, idx],
                              self.has_rotation[idx], self.source)

    def to_dict(self) -> dict[str, Any]:
        """The ``smplik-trackers`` document."""
        trackers: dict[str, Any] = {}
        for k, name in enumerate(self.names):
            entry: dict[str, Any] = {"position": np.round(self.positions[:, k], 6).tolist()}
            if self.has_rotation[k]:
                entry["rotation"] = np.round(self.rotations[:, k], 7).tolist()
            trackers[name] = entry
        return {"format": TRACKERS_FORMAT, "version": TRACKERS_VERSION, "fps": self.fps, "trackers": trackers}


def signals_from_dict(data: Any, source: str = "trackers") -> TrackerSignals:
    """Validate a ``smplik-trackers`` document (module docstring). Raises TrackerFileError."""
    err = JSONPathError(source, TrackerFileError)
    if not isinstance(data, dict):
        raise err("", f"expected a JSON object, got {short_repr(data)}.")
    unknown = sorted(set(data) - _ROOT_KEYS)
    if unknown:
        raise err(unknown[0], f"unknown key (expected {', '.join(sorted(_ROOT_KEYS))}).")
    for key in ("format", "version", "fps", "trackers"):
        if key not in data:
            raise err(key, "missing.")
    if data["format"] != TRACKERS_FORMAT:
        raise err("format", f"is {short_repr(data['format'])}; expected {TRACKERS_FORMAT!r}.")
    if data["version"] != TRACKERS_VERSION or isinstance(data["version"], bool):
        raise err("version", f"is {short_repr(data['version'])}; this smplik reads version {TRACKERS_VERSION}.")
    try:
        fps = check_rate(data["fps"], f"{source}: fps")
    except LimitError as exc:
        raise TrackerFileError(str(exc)) from None
    trackers = data["trackers"]
    if not isinstance(trackers, dict) or not trackers:
        raise err("trackers", f"must be a non-empty object of SMPL joint names, got {short_repr(trackers)}.")
    names, positions, rotations, has = [], [], [], []
    T: int | None = None
    for name, entry in trackers.items():
        path = f"trackers.{name}"
        if name not in JOINT_NAMES:
            raise err(path, unknown_joint(name))
        if not isinstance(entry, dict):
            raise err(path, f"expected an object with 'position' (and 'rotation'), got {short_repr(entry)}.")
        bad = sorted(set(entry) - _TRACKER_KEYS)
        if bad:
            raise err(f"{path}.{bad[0]}", "unknown key (expected position, rotation).")
        if "position" not in entry:
            raise err(f"{path}.position", "missing.")
        rows = entry["position"]
        if not isinstance(rows, list) or not rows:
            raise err(f"{path}.position", f"must be a non-empty list of [x, y, z] rows, got {short_repr(rows)}.")
        if len(rows) > MAX_FRAMES:
            raise err(f"{path}.position", f"{len(rows)} frames; at most {MAX_FRAMES} are read.")
        if T is None:
            T = len(rows)
        if len(rows) != T:
            raise err(f"{path}.position", f"has {len(rows)} rows; the first tracker has {T} (one row per frame).")
        p = finite_array(rows, (T, 3), f"{source}: {path}.position", TrackerFileError, max_abs=1000.0)
        if "rotation" in entry:
            q = finite_array(entry["rotation"], (T, 4), f"{source}: {path}.rotation", TrackerFileError)
            rotations.append(_unit_quaternions(q, err, f"{path}.rotation"))
            has.append(True)
        else:
            rotations.append(np.tile([1.0, 0.0, 0.0, 0.0], (T, 1)))
            has.append(False)
        names.append(name)
        positions.append(p)
    return TrackerSignals(float(fps), tuple(names), np.stack(positions, 1), np.stack(rotations, 1),
                          np.asarray(has), source)


def _unit_quaternions(q: np.ndarray, err: JSONPathError, path: str) -> np.ndarray:
    """(T, 4) finite quaternions -> unit quaternions, normalised first by their largest component (so that
    ``[1e300, 0, 0, 0]`` or ``[1e-300, 0, 0, 0]`` is the identity, not an overflow to inf or an underflow to 0),
    then by their norm (in [1, 2] after the first step). Only an all-zero row is refused, naming its row."""
    scale = np.abs(q).max(axis=-1, keepdims=True)
    zero = scale[:, 0] == 0.0
    if zero.any():
        raise err(f"{path}[{int(np.argmax(zero))}]", "is a zero quaternion (no rotation).")
    q = q / scale
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def signals_from_motion(R_local: np.ndarray, transl: np.ndarray, J_rest: np.ndarray, names: tuple[str, ...],
                        fps: float, *, noise_m: float = 0.0, noise_deg: float = 0.0,
                        rng: np.random.Generator | None = None) -> TrackerSignals:
    """Synthetic trackers of a motion: the joints ``names``' world positions and rotations (SMPL's joint frames),
    with optional Gaussian noise (position sigma ``noise_m``, rotation angle sigma ``noise_deg`` about a random
    axis). R_local (T, 24, 3, 3), transl (T, 3), J_rest (24, 3)."""
    import torch

    from smplik.conventions import JOINT_INDEX
    from smplik.kinematics import forward_kinematics

    f64 = torch.float64
    R_w, p = forward_kinematics(torch.as_tensor(R_local, dtype=f64), torch.as_tensor(J_rest, dtype=f64),
                                torch.as_tensor(transl, dtype=f64))
    idx = [JOINT_INDEX[n] for n in names]
    P, R = p[:, idx].numpy(), R_w[:, idx].numpy()
    if noise_m > 0 or noise_deg > 0:
        rng = np.random.default_rng(0) if rng is None else rng
        P = P + rng.normal(0.0, noise_m, P.shape)
        v = rng.normal(0.0, np.deg2rad(noise_deg), P.shape)
        R = axis_angle_to_matrix_np(v) @ R
    return TrackerSignals(float(fps), tuple(names), P, matrix_to_quat_wxyz(R), np.ones(len(names), bool), "synthetic")


# ----------------------------------------------------------------------------- SteamVR JSON lines

HMD_TO_HEAD_M = np.array([0.0, -0.07, 0.09])
"""The SMPL head joint relative to the headset, in the headset's OpenVR frame (-z forward): 7 cm down,
9 cm behind the eyes (an average adult; a calibration would measure it)."""


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def _number(value: Any, where: str, err: JSONPathError, max_abs: float) -> float:
    """A JSON number (not a bool, not a string such as ``"1.5"``) within ``|x| <= max_abs``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise err(where, f"must be a number, got {short_repr(value)}.")
    x = float(value) if abs(value) <= max_abs else float("inf")
    if not np.isfinite(x):
        raise err(where, f"{short_repr(value)} is outside [-{max_abs:g}, {max_abs:g}].")
    return x


def _steamvr_record(frame: Any, where: str, err: JSONPathError
                    ) -> list[tuple[tuple[str, int], tuple[np.ndarray, np.ndarray]]]:
    """The valid device poses of one log line, each checked for JSON types: ``((class, index), (position (3,),
    unit quaternion (4,) w first))``. Raises ``err`` naming the line and key of the first wrong value."""
    if not isinstance(frame, dict):
        raise err(where, f"expected a JSON object, got {short_repr(frame)}.")
    for key in ("timestamp", "devices"):
        if key not in frame:
            raise err(f"{where}.{key}", "missing.")
    devices = frame["devices"]
    if not isinstance(devices, list):
        raise err(f"{where}.devices", f"expected a list of device objects, got {short_repr(devices)}.")
    if len(devices) > MAX_DEVICE_INDEX + 1:
        raise err(f"{where}.devices", f"{len(devices)} devices; OpenVR tracks at most {MAX_DEVICE_INDEX + 1}.")
    out = []
    for i, dev in enumerate(devices):
        at = f"{where}.devices[{i}]"
        if not isinstance(dev, dict):
            raise err(at, f"expected a device object, got {short_repr(dev)}.")
        cls, index = dev.get("class"), dev.get("index")
        if not isinstance(cls, str) or not 0 < len(cls) <= 64:
            raise err(f"{at}.class", f"expected a device class name (HMD, Controller, Tracker, ...), got "
                      f"{short_repr(cls)}.")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index <= MAX_DEVICE_INDEX:
            raise err(f"{at}.index", f"expected a device index in 0..{MAX_DEVICE_INDEX}, got {short_repr(index)}.")
        pose = dev.get("pose")
        if pose is None:
            continue
        if not isinstance(pose, dict):
            raise err(f"{at}.pose", f"expected an object or null, got {short_repr(pose)}.")
        valid = pose.get("valid", False)
        if not isinstance(valid, bool):
            raise err(f"{at}.pose.valid", f"expected true or false, got {short_repr(valid)}.")
        if not valid:
            continue
        vec = {}
        for key, names in (("position", "xyz"), ("quaternion", "wxyz")):
            d = pose.get(key)
            if not isinstance(d, dict):
                raise err(f"{at}.pose.{key}", f"expected an object with {', '.join(names)}, got {short_repr(d)}.")
            vec[key] = np.array([_number(d.get(c), f"{at}.pose.{key}.{c}", err, 1e3 if key == "position" else 1e300)
                                 for c in names])
        q = vec["quaternion"]
        scale = np.abs(q).max()
        if scale == 0.0:
            continue  # no rotation: this device's frame is treated as invalid
        q = q / scale
        out.append(((cls, index), (vec["position"], q / np.linalg.norm(q))))
    return out


def read_steamvr_jsonl(path: str | Path, fps: float = 60.0, controller: str = "none") -> TrackerSignals:
    """Read a SteamVR JSON-lines log (module docstring) into ``head``, ``left_wrist``, ``right_wrist`` (and
    ``pelvis`` when one generic tracker is present), resampled to ``fps`` by linear interpolation over the
    timestamps.

    Mapping: the HMD gives the head (its rotation turned half a turn about its y axis, so that +z is forward as
    for SMPL's head; its position moved by :data:`HMD_TO_HEAD_M`); the two controllers give the wrists by
    position only (their rotations are in the device's own frame, not the wrist's: left out), left being the
    one on the headset's left at the first frame where both are valid; a single generic tracker gives the
    pelvis by position. Frames where a device's pose is invalid are interpolated from its valid neighbours.
    ``controller``: the controllers' kind (:data:`smplik.tracking.calibrate.CONTROLLERS`): each wrist is put at
    its controller's wrist point (``none``: the controller's position).
    """
    path = Path(path)
    err = JSONPathError(str(path), TrackerFileError)
    try:
        fps = check_rate(fps, f"{path}: the resampling rate")
    except LimitError as exc:
        raise TrackerFileError(str(exc)) from None
    text = read_text(path, TrackerFileError, what="tracker file")
    times: list[float] = []
    tracks: dict[tuple[str, int], dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for n, line in enumerate(text.splitlines()):
        if not line.strip():
            continue
        where = f"line {n + 1}"
        try:
            frame = json.loads(line, parse_constant=_refuse_constant)
        except (json.JSONDecodeError, ValueError, RecursionError) as exc:
            raise err(where, f"not a SteamVR log record ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})."
                      ) from None
        row = len(times)
        if row >= MAX_FRAMES:
            raise err(where, f"more than {MAX_FRAMES} records; at most {MAX_FRAMES} are read.")
        for key, (p, q) in _steamvr_record(frame, where, err):
            tracks.setdefault(key, {})[row] = (p, q)
        times.append(_number(frame["timestamp"], f"{where}.timestamp", err, MAX_ABS_TIMESTAMP_S))
    if len(times) < 2:
        raise err("", "fewer than 2 frames.")
    stamps = np.asarray(times)
    if not (np.diff(stamps) > 0).all():
        raise err("timestamp", "timestamps must increase from line to line.")
    try:  # what the resampling makes, before it is made: frames = span x rate
        check_resampled_frames(float(stamps[-1] - stamps[0]), fps, f"{path}: timestamps {stamps[0]:g}..{stamps[-1]:g}")
    except LimitError as exc:
        raise TrackerFileError(str(exc)) from None
    hmds = [k for k in tracks if k[0] == "HMD"]
    ctrls = sorted(k for k in tracks if k[0] == "Controller")
    generic = [k for k in tracks if k[0] == "Tracker"]
    if not hmds:
        raise err("devices", "no HMD with a valid pose.")
    if len(ctrls) != 2:
        raise err("devices", f"expected 2 controllers with valid poses, found {len(ctrls)}.")
    out_t = stamps[0] + np.arange(check_resampled_frames(float(stamps[-1] - stamps[0]), fps, str(path))) / fps

    def resample(key: tuple[str, int]) -> tuple[np.ndarray, np.ndarray]:
        rows = sorted(tracks[key])
        t = stamps[rows]
        P = np.stack([tracks[key][r][0] for r in rows])
        Q = np.stack([tracks[key][r][1] for r in rows])
        for i in range(1, len(Q)):  # sign-continuous before interpolating
            if Q[i] @ Q[i - 1] < 0:
                Q[i] = -Q[i]
        p = np.stack([np.interp(out_t, t, P[:, i]) for i in range(3)], -1)
        q = np.stack([np.interp(out_t, t, Q[:, i]) for i in range(4)], -1)
        return p, q / np.linalg.norm(q, axis=-1, keepdims=True)

    p_hmd, q_hmd = resample(hmds[0])
    R_hmd = quat_wxyz_to_matrix(q_hmd)
    half_turn = np.diag([-1.0, 1.0, -1.0])
    R_head = R_hmd @ half_turn
    p_head = p_hmd + (R_hmd @ HMD_TO_HEAD_M[:, None])[..., 0]
    (pa, qa), (pb, qb) = resample(ctrls[0]), resample(ctrls[1])
    # left = on the headset's left: SMPL's head frame has +x to the body's left
    side = ((pa[0] - pb[0]) @ R_head[0][:, 0])
    if controller != "none":
        from smplik.tracking.controllers import ControllerError, controller_offset

        try:
            offsets = (controller_offset(controller, "left"), controller_offset(controller, "right"))
        except ControllerError as exc:
            raise TrackerFileError(f"{path}: {exc}") from None
        oa, ob = offsets if side > 0 else offsets[::-1]
        pa = pa + (quat_wxyz_to_matrix(qa) @ oa[:, None])[..., 0]
        pb = pb + (quat_wxyz_to_matrix(qb) @ ob[:, None])[..., 0]
    left, right = (pa, pb) if side > 0 else (pb, pa)
    names = ["head", "left_wrist", "right_wrist"]
    P = [p_head, left, right]
    ident = np.tile([1.0, 0, 0, 0], (len(out_t), 1))
    Q = [matrix_to_quat_wxyz(R_head), ident, ident.copy()]
    has = [True, False, False]
    if len(generic) == 1:
        names.append("pelvis")
        P.append(resample(generic[0])[0])
        Q.append(np.tile([1.0, 0, 0, 0], (len(out_t), 1)))
        has.append(False)
    return TrackerSignals(float(fps), tuple(names), np.stack(P, 1), np.stack(Q, 1), np.asarray(has), str(path))
