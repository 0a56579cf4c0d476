"""``smplik track --from-motion CLIP``: a trackers file made from any motion file, and VR CSV recordings of it.

:func:`motion_signals` reads a motion (BVH, FBX: retargeted onto SMPL by the rig mapper, preset ``auto``;
``animation.json``: its first track) on a body (``betas``, ``gender``; an animation keeps its own), resamples it
to ``fps`` and returns the trackers a VR user wearing that body would produce (the SMPL head and wrist joints,
and the pelvis), exact: what ``smplik track`` takes, and what tests and benchmarks use as recordings with a
known truth. :func:`write_device_csv` writes such trackers as a headset + controllers CSV in a producer's exact
layout (:data:`smplik.tracking.csv_io.PRODUCERS`), units, time unit and axes, at irregular sample times.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import Gender


class MotionFileError(ValueError):
    """A motion file cannot be made into trackers (one line naming the file)."""


@dataclass(frozen=True)
class MotionTruth:
    """The motion behind :func:`motion_signals`: R_local (T, 24, 3, 3), transl (T, 3) smplx, J_rest (24, 3),
    betas (10,), gender, fps."""

    R_local: np.ndarray
    transl: np.ndarray
    J_rest: np.ndarray
    betas: np.ndarray
    gender: Gender
    fps: float


def _resample(R: np.ndarray, transl: np.ndarray, fps_in: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (T, 24, 3, 3) by slerp and transl (T, 3) linearly, from ``fps_in`` to ``fps``."""
    from scipy.spatial.transform import Rotation, Slerp

    T = R.shape[0]
    if T < 2 or abs(fps_in - fps) < 1e-9:
        return R, transl
    t = np.arange(T) / fps_in
    out_t = np.arange(int(np.floor(t[-1] * fps + 1e-9)) + 1) / fps
    Ro = np.stack([Slerp(t, Rotation.from_matrix(R[:, j]))(out_t).as_matrix() for j in range(R.shape[1])], 1)
    return Ro, np.stack([np.interp(out_t, t, transl[:, i]) for i in range(3)], -1)


def motion_truth(path: str | Path, *, fps: float = 60.0, betas: Sequence[float] | None = None,
                 gender: Gender | str = Gender.NEUTRAL) -> MotionTruth:
    """The motion of ``path`` on SMPL at ``fps`` (module docstring). Raises MotionFileError (one line)."""
    from smplik.rotations import axis_angle_to_matrix
    from workflows.animation.clips import rest_joints

    path = Path(path)
    if not path.is_file():
        raise MotionFileError(f"{path}: motion file not found.")
    suffix = path.suffix.lower()
    if suffix == ".json":
        import torch

        from workflows.animation.files import load_animation

        anim = load_animation(path)
        track = anim.tracks[0]
        aa = np.concatenate([track.global_orient[:, None], track.body_pose], 1).astype(np.float64)
        R = axis_angle_to_matrix(torch.as_tensor(aa)).numpy()
        body, g = np.asarray(track.betas, dtype=np.float64), track.gender
        R, transl = _resample(R, np.asarray(track.transl, dtype=np.float64), float(anim.fps), fps)
    elif suffix in (".bvh", ".fbx"):
        import torch

        from shape_inversion.auto_preset import auto_preset
        from smplik.data.retarget import retarget_bvh

        g = Gender.parse(gender)
        body = np.zeros(10) if betas is None else np.asarray(betas, dtype=np.float64)
        try:
            clip = retarget_bvh(path, "auto", gender=g, betas=body, fps=fps, rig_mapper=auto_preset)
        except (ValueError, KeyError) as exc:
            raise MotionFileError(f"{path}: {' '.join(str(exc).split())[:300]}") from None
        start = clip.motion_start  # earlier frames are the source's rest pose
        aa = np.concatenate([clip.global_orient[start:, None], clip.body_pose[start:]], 1).astype(np.float64)
        R = axis_angle_to_matrix(torch.as_tensor(aa)).numpy()
        transl = clip.transl[start:].astype(np.float64)
    else:
        raise MotionFileError(f"{path}: not a motion file this command reads (BVH, FBX or animation.json).")
    if R.shape[0] < 2:
        raise MotionFileError(f"{path}: fewer than 2 frames of motion.")
    transl = transl - np.array([0.0, _sole_height(R, transl, body, g), 0.0])
    return MotionTruth(R, transl, rest_joints(body, g), body, g, float(fps))


def _sole_height(R: np.ndarray, transl: np.ndarray, betas: np.ndarray, gender: Gender) -> float:
    """The median over (up to 60 evenly spaced) frames of the mesh's lowest point: the floor the motion stands
    on (a retargeted clip's feet are 1-3 cm off the source's floor)."""
    import torch

    from smplik.body_model import BodyModelSet
    from smplik.rotations import matrix_to_axis_angle

    idx = np.unique(np.linspace(0, R.shape[0] - 1, min(60, R.shape[0])).astype(int))
    aa = matrix_to_axis_angle(torch.as_tensor(R[idx])).float()
    with torch.no_grad():
        verts, _ = BodyModelSet.load()[gender].vertices(aa[:, 0], aa[:, 1:], torch.as_tensor(transl[idx]).float(),
                                                       torch.as_tensor(betas, dtype=torch.float32).expand(len(idx), 10))
    return float(np.median(verts[..., 1].min(-1).values.numpy()))


def motion_signals(path: str | Path, *, fps: float = 60.0, betas: Sequence[float] | None = None,
                   gender: Gender | str = Gender.NEUTRAL, trackers: Sequence[str] | None = None
                   ) -> tuple[Any, MotionTruth]:
    """(exact trackers :class:`smplik.tracking.io.TrackerSignals`, the motion behind them) of a motion file;
    ``trackers`` default: head, both wrists and the pelvis."""
    from smplik.tracking.config import TRACKER_SETS
    from smplik.tracking.io import signals_from_motion

    truth = motion_truth(path, fps=fps, betas=betas, gender=gender)
    names = tuple(TRACKER_SETS["4"] if trackers is None else trackers)
    sig = signals_from_motion(truth.R_local, truth.transl, truth.J_rest, names, fps)
    from dataclasses import replace

    return replace(sig, source=str(path)), truth


def write_trackers_from_motion(path: str | Path, out: str | Path, *, fps: float = 60.0,
                               betas: Sequence[float] | None = None, gender: Gender | str = Gender.NEUTRAL,
                               trackers: Sequence[str] | None = None) -> Path:
    """``smplik track --from-motion CLIP --out FILE``: the motion's trackers as a ``smplik-trackers`` file
    (written atomically). Returns the file."""
    import json

    from smplik.atomic import write_text_atomic

    sig, _ = motion_signals(path, fps=fps, betas=betas, gender=gender, trackers=trackers)
    out = Path(out)
    write_text_atomic(out, json.dumps(sig.to_dict(), separators=(",", ":")))
    return out


# ----------------------------------------------------------------------------- CSV recordings in a producer's layout

_DEVICE_PREFIX = {
    "who-is-alyx": ("hmd_{k}_{a}", "left_controller_{k}_{a}", "right_controller_{k}_{a}"),
    "unity-hmd-recorder": ("hmd_{k}_{a}", "left_{k}_{a}", "right_{k}_{a}"),
    "omnicept": ("head_{k}_{a}", "lefthand_{k}_{a}", "righthand_{k}_{a}"),
    "magic-xroom": ("head_{k}{A}", "lcontroller_{k}{A}", "rcontroller_{k}{A}"),
}
_GRIP = {"left": np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
         "right": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])}
"""The controller's frame (columns: its +x, +y, +z) in the SMPL wrist joint's: held pointing along the hand (its
-z along the hand, away from the forearm), its +y up with the hand's back."""


def write_device_csv(signals: Any, path: str | Path, producer: str, *, units: str = "m", time_unit: str | None = None,
                     axes: str | None = None, controller: str | None = None, rate: float | None = None,
                     jitter: float = 0.2, seed: int = 0) -> Path:
    """``signals`` (head, left_wrist, right_wrist with rotations; pelvis ignored) as the CSV a headset and two
    controllers would have made: in ``producer``'s exact column layout (:data:`_DEVICE_PREFIX`), positions in
    ``units``, times in ``time_unit`` (default: the producer's), ``axes`` (default: the producer's), the
    controllers' tracked frames those of ``controller`` (default: the producer's), sampled at ``rate`` Hz
    (default: 15 for Who Is Alyx, whose recordings fall to 10-15 frames/s, else 90) with each interval varied by up
    to ``jitter`` of itself."""
    from scipy.spatial.transform import Rotation

    from smplik.rotations import matrix_to_quat_wxyz, quat_wxyz_to_xyzw
    from smplik.tracking.calibrate import controller_offset
    from smplik.tracking.csv_io import GENERIC, PRODUCERS, TIME_UNITS, UNITS
    from smplik.tracking.io import HMD_TO_HEAD_M

    prod = next((p for p in PRODUCERS if p.name == producer), None)
    if prod is None or producer not in _DEVICE_PREFIX:
        raise ValueError(f"unknown CSV producer {producer!r}; choose from {', '.join(_DEVICE_PREFIX)}.")
    axes = axes or prod.axes
    controller = prod.controller if controller is None else controller
    rate = (15.0 if producer == "who-is-alyx" else 90.0) if rate is None else float(rate)
    rng = np.random.default_rng(seed)
    span = (signals.num_frames - 1) / signals.fps
    dt = (1.0 + rng.uniform(-jitter, jitter, int(span * rate * 1.5) + 2)) / rate
    t = np.concatenate([[0.0], np.cumsum(dt)])
    t = np.r_[t[t < span - 0.5 / rate], span]  # the last sample at the motion's end: the same span
    src_t = np.arange(signals.num_frames) / signals.fps

    def at(name: str) -> tuple[np.ndarray, np.ndarray]:
        k = signals.names.index(name)
        p = np.stack([np.interp(t, src_t, signals.positions[:, k, i]) for i in range(3)], -1)
        from scipy.spatial.transform import Slerp

        R = Slerp(src_t, Rotation.from_quat(quat_wxyz_to_xyzw(signals.rotations[:, k])))(t).as_matrix()
        return p, R

    p_head, R_head = at("head")
    R_hmd = R_head @ np.diag([-1.0, 1.0, -1.0])
    devices = [(p_head - (R_hmd @ HMD_TO_HEAD_M[:, None])[..., 0], R_hmd)]
    for side in ("left", "right"):
        p_w, R_w = at(f"{side}_wrist")
        R_c = R_w @ _GRIP[side]
        devices.append((p_w - (R_c @ controller_offset(controller, side)[:, None])[..., 0], R_c))
    flip = np.array([1.0, 1.0, -1.0]) if axes == "unity" else np.ones(3)
    qflip = np.array([1.0, -1.0, -1.0, 1.0]) if axes == "unity" else np.ones(4)
    header, cols = [], []
    for fmt, (p, R) in zip(_DEVICE_PREFIX[producer], devices, strict=True):
        p = p * flip / UNITS[units]
        q = matrix_to_quat_wxyz(R) * qflip
        for a, i in zip("xyz", range(3), strict=True):
            header.append(fmt.format(k="pos", a=a, A=a.upper()))
            cols.append(p[:, i])
        for a, i in zip("xyzw", (1, 2, 3, 0), strict=True):
            header.append(fmt.format(k="rot", a=a, A=a.upper()))
            cols.append(q[:, i])
    if producer == "magic-xroom":  # version 1.0 of Magic XRoom spells the controllers' y position "pposY"
        header = [h.replace("controller_posY", "controller_pposY") for h in header]
    n = len(t)
    buttons: dict[str, np.ndarray] = {}
    if producer == "who-is-alyx":
        tu = time_unit or "ms"
        time_cols = {"timestamp": np.full(n, np.nan), "delta_time_ms": t / TIME_UNITS[tu]}
        for side in ("left", "right"):
            for b in ("grip_button", "menu_button", "trackpad_pressed", "trackpad_touched", "trackpad_x",
                      "trackpad_y", "trigger", "ul_button_pressed", "ul_button_touched"):
                buttons[f"{side}_controller_{b}"] = np.zeros(n)
    elif producer == "unity-hmd-recorder":
        tu = time_unit or "ms"
        time_cols = {"timestamp_ms": np.round(1.7e12 * 1e-3 / TIME_UNITS[tu] + t / TIME_UNITS[tu], 3),
                     "frame": np.arange(n, dtype=float) + 1000, "unity_time": 12.5 + t}
    elif producer == "omnicept":
        tu = time_unit or "ms"
        time_cols = {"time_stamp": np.round(1.7e12 * 1e-3 / TIME_UNITS[tu] + t / TIME_UNITS[tu])}
    else:
        tu = time_unit or "s"
        time_cols = {"timestamp": 3.25 + t / TIME_UNITS[tu]}
    del GENERIC
    header = list(time_cols) + header + list(buttons)
    table = np.stack(list(time_cols.values()) + cols + list(buttons.values()), 1)
    lines = [",".join(header)]
    start = np.datetime64("2022-01-17T10:32:05.000000")
    for i, row in enumerate(table):
        cells = [f"{v:.6f}".rstrip("0").rstrip(".") if abs(v) < 1e9 else f"{v:.0f}" for v in row]
        if producer == "who-is-alyx":  # a wall-clock time of day (the dataset's own scripts drop this column)
            cells[0] = str(start + np.timedelta64(int(round(t[i] * 1e6)), "us")).replace("T", " ")
        lines.append(",".join(cells))
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path
