"""Retargeting BVH motion onto SMPL, and the bone-direction quality metric.

Method (per SMPL joint ``j`` mapped to source joint ``s``, all frames at once):

1. The source is brought to metres and y-up (preset ``units``, ``up``). Its rest pose is the
   zero-rotation OFFSET pose or frame 0 (``rest``: ``"offsets"``, ``"frame0"``, or ``"auto"``,
   which takes whichever is closer to SMPL's T-pose; cgspeed CMU files store an A-ish OFFSET
   pose and a T-pose-like frame 0, the Isaac CMU files a T-pose in both).
2. A yaw ``Y`` turns SMPL's rest facing (+z, left at +x) onto the source rest facing, so the
   motion keeps its world heading.
3. Rest alignment: ``G_smpl[j](t) = G_src[s](t) · G_src_rest[s]^T · Y · S_j``, where ``S_j`` is the
   minimal rotation taking the SMPL rest direction of ``j``'s *aim* bone onto the source's rest
   direction of the same bone. This carries the source's twist over.
4. Direction fit: per frame, the minimal rotation ``W(t)`` that takes the aim bone as posed in
   step 3 onto the source bone direction is applied on the left, ``G_smpl[j] = W · G_smpl[j]``.
   When the source bone is rigid in ``s``'s frame ``W`` is the identity; when the source bone
   spans extra joints (CMU's ``Spine1 -> Neck -> Neck1``) ``W`` absorbs them.
5. Unmapped SMPL joints copy their parent's global rotation (identity local rotation); a
   mapped joint's default aim is its nearest mapped descendant through unmapped joints, so
   e.g. an unmapped ``spine2`` is spanned by ``spine1``'s aim. The pelvis aims along the hip
   line (``right_hip -> left_hip``), which both rigs share, rather than at a hip.
6. Local rotations are ``R_parent_joint = G_parent^T G_joint`` (:func:`smplik.kinematics.global_to_local`).
   The root position puts the SMPL mid-hip point on the source mid-hip point, scaled by the
   leg-length ratio (SMPL / source) about the origin and the floor: ``y_smpl = floor_smpl +
   k (y_src - floor_src)``, where ``floor_smpl`` is the lowest rest vertex of the body.

Preset files (JSON; ``smplik/data/presets/<name>.json`` or any path)::

    {
      "name": "my_rig",                  optional, for messages
      "units": 0.01 | "m" | "cm" | "cmu" | ...,  metres per source unit or a name of smplik.units (default 1)
      "up": "y" | "z",                   source up axis (z-up: (x, y, z) -> (x, z, -y); default "y")
      "floor": 0.0,                      source floor height along "up", source units (default 0)
      "rest": "auto" | "frame0" | "offsets",           source rest pose (default "auto")
      "motion_start": 1,                 first motion frame; earlier frames are rest frames (default 0)
      "joints": {"pelvis": "Hips", "left_hip": "LeftUpLeg", ...},   SMPL joint -> source joint
      "aim": {"pelvis": ["right_hip", "left_hip"]}                  optional aim overrides
    }

Only ``joints`` is required and ``pelvis`` must be in it. An aim ``[a, b]`` names two SMPL
joints whose rest vector is rigid in the joint's frame (the joint itself and descendants
reached through unmapped joints), both mapped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_BETAS, NUM_JOINTS, PARENTS, Gender, unknown_joint
from smplik.data.bvh import BVHMotion, read_bvh
from smplik.kinematics import global_to_local
from smplik.rotations import matrix_to_axis_angle, quaternion_to_matrix_np
from smplik.units import UNIT_NAMES
from smplik.validation import check_betas

PRESET_DIR = Path(__file__).resolve().parent / "presets"
RestMode = Literal["auto", "frame0", "offsets"]


class RetargetError(ValueError):
    """A preset is invalid or does not fit the source skeleton."""


# ----------------------------------------------------------------------------- presets


@dataclass(frozen=True)
class RetargetPreset:
    """How a source rig maps onto SMPL (see the module docstring for the JSON format)."""

    name: str
    """Name used in messages."""
    joints: dict[str, str]
    """SMPL joint name -> source joint name."""
    units: float = 1.0
    """Metres per source unit."""
    up: Literal["y", "z"] = "y"
    """Source up axis."""
    floor: float = 0.0
    """Source floor height along ``up``, source units."""
    rest: RestMode = "auto"
    """Source rest pose: zero-rotation OFFSETs, frame 0, or whichever is closer to a T-pose."""
    motion_start: int = 0
    """First motion frame (CMU: 1, frame 0 is a rest pose)."""
    aim: dict[str, tuple[str, str]] = field(default_factory=dict)
    """SMPL joint -> (SMPL joint a, SMPL joint b) whose vector b - a the joint aims along."""

    @classmethod
    def from_dict(cls, data: dict[str, Any], origin: str = "<dict>") -> RetargetPreset:
        """Validate a preset dict (the JSON format of the module docstring)."""
        def bad(msg: str) -> RetargetError:
            return RetargetError(f"retarget preset {origin}: {msg}")

        if not isinstance(data, dict) or not isinstance(data.get("joints"), dict):
            raise bad("expected an object with a 'joints' object mapping SMPL joint names to source joint names")
        unknown = set(data) - {"name", "description", "units", "up", "floor", "rest", "motion_start", "joints", "aim"}
        if unknown:
            raise bad(f"unknown keys {sorted(unknown)}")
        joints = {str(k): str(v) for k, v in data["joints"].items()}
        for k in joints:
            if k not in JOINT_INDEX:
                raise bad(f"'joints': {unknown_joint(k).rstrip('.')}")
        if "pelvis" not in joints:
            raise bad("'joints' must map 'pelvis' (the root)")
        units = data.get("units", 1.0)
        if isinstance(units, str):
            if units.lower() not in UNIT_NAMES:
                raise bad(f"unknown units {units!r} (a number of metres per unit, or one of {', '.join(UNIT_NAMES)})")
            units = UNIT_NAMES[units.lower()]
        if not isinstance(units, (int, float)) or not units > 0:
            raise bad(f"'units' must be a positive number of metres per source unit, got {units!r}")
        up = str(data.get("up", "y")).lower()
        if up not in ("y", "z"):
            raise bad(f"'up' must be 'y' or 'z', got {up!r}")
        rest = str(data.get("rest", "auto")).lower()
        if rest not in ("auto", "frame0", "offsets"):
            raise bad(f"'rest' must be 'auto', 'frame0' or 'offsets', got {rest!r}")
        aim: dict[str, tuple[str, str]] = {}
        for k, v in (data.get("aim") or {}).items():
            if k not in JOINT_INDEX or not (isinstance(v, (list, tuple)) and len(v) == 2
                                            and all(x in JOINT_INDEX for x in v)):
                raise bad(f"'aim' entry {k!r}: {v!r} must map an SMPL joint to a pair of SMPL joint names")
            aim[k] = (str(v[0]), str(v[1]))
        return cls(name=str(data.get("name", origin)), joints=joints, units=float(units), up=up,  # type: ignore[arg-type]
                   floor=float(data.get("floor", 0.0)), rest=rest, motion_start=int(data.get("motion_start", 0)),  # type: ignore[arg-type]
                   aim=aim)


def preset_names() -> tuple[str, ...]:
    """Built-in rig presets (``presets/*.json`` stems, sorted; ``*_example`` templates left out).

    The one registry of both packages: ``smplik data build --preset`` and ``smplik invert-shape --rig``.
    """
    return tuple(sorted(p.stem for p in PRESET_DIR.glob("*.json") if not p.stem.endswith("_example")))


def resolve_joint_names(wanted: dict[str, str], names: tuple[str, ...]) -> dict[str, int]:
    """SMPL joint -> index into ``names`` for each ``wanted`` source name: exact, else case-insensitive with
    any ``namespace:`` / ``path|`` prefix dropped (``mixamorig1:Hips`` matches ``mixamorig:Hips``)."""
    def norm(n: str) -> str:
        return n.rsplit("|", 1)[-1].rsplit(":", 1)[-1].strip().lower()

    exact = {n: i for i, n in enumerate(names)}
    loose: dict[str, int] = {}
    for i, n in enumerate(names):
        loose.setdefault(norm(n), i)
    out = {}
    for smpl, src in wanted.items():
        if src in exact:
            out[smpl] = exact[src]
        elif norm(src) in loose:
            out[smpl] = loose[norm(src)]
    return out


RigMapper = Callable[[BVHMotion], "RetargetPreset"]
"""A rig mapper: a parsed BVH clip -> the preset that retargets it (``preset="auto"``).

The mapper (topology, geometry and names) is shape_inversion's, above this package: the caller passes it
(``rig_mapper=shape_inversion.auto_preset.auto_preset``); nothing is installed globally."""


def resolve_preset(motion: BVHMotion, preset: str | Path | dict[str, Any] | RetargetPreset,
                   rig_mapper: RigMapper | None = None) -> RetargetPreset:
    """The preset of ``motion``: ``"auto"`` asks ``rig_mapper``; anything else is :func:`load_preset`'s.

    Raises :class:`RetargetError` naming the clip when ``preset="auto"`` and no mapper is given.
    """
    if not (isinstance(preset, str) and preset == "auto"):
        return load_preset(preset)
    if rig_mapper is None:
        raise RetargetError(f"{motion.name}: preset 'auto' needs a rig mapper (rig_mapper="
                            "shape_inversion.auto_preset.auto_preset, as the smplik data commands pass), "
                            "or give a preset name or JSON file.")
    return rig_mapper(motion)


MOTION_SUFFIXES = (".bvh", ".fbx")
"""Motion files read by :func:`read_motion` (and ``smplik data build --bvh`` / ``data preview``)."""


def read_motion(path: str | Path) -> BVHMotion:
    """A BVH file, or an FBX file's skeleton and animation take (:func:`smplik.data.fbx.read_fbx`: metres, y up,
    its OFFSETs the bind pose), as a :class:`BVHMotion`. Raises :class:`BVHError` (FBX: its subclass)."""
    if Path(path).suffix.lower() == ".fbx":
        from smplik.data.fbx import read_fbx

        return read_fbx(path)
    return read_bvh(path)


def load_preset(preset: str | Path | dict[str, Any] | RetargetPreset) -> RetargetPreset:
    """A preset by built-in name (``"cmu"``), JSON file path, dict, or as is."""
    if isinstance(preset, RetargetPreset):
        return preset
    if isinstance(preset, dict):
        return RetargetPreset.from_dict(preset)
    path = Path(preset)
    if not path.suffix and path.parent == Path("."):
        path = PRESET_DIR / f"{preset}.json"
        if not path.is_file():
            names = ", ".join(preset_names())
            raise RetargetError(f"Unknown retarget preset {str(preset)!r}; built-in presets: {names}, or a JSON path.")
    from smplik.validation import read_json

    data = read_json(path, RetargetError, what="retarget preset")  # bounded read (smplik.limits.JSON_BYTES)
    return RetargetPreset.from_dict(data, origin=str(path))


# ----------------------------------------------------------------------------- result


@dataclass(frozen=True)
class RetargetedClip:
    """SMPL motion retargeted from a source clip (T frames, S source joints).

    The pose is in smplx's convention: the posed pelvis is at ``J0(betas) + transl``.

    Attributes:
        global_orient: (T, 3) float32 axis-angle.
        body_pose: (T, 23, 3) float32 axis-angle.
        transl: (T, 3) float32 metres.
        betas: (10,) float32 shape used for the rest skeleton.
        gender: body model gender.
        fps: frames per second.
        source: where the motion came from.
        motion_start: first motion frame (earlier frames are the source's rest frames).
        rest_mode: the source rest pose used (``"offsets"`` or ``"frame0"``).
        source_joint_names: (S,) source joint names.
        source_joints: (T, S, 3) float32 source joint positions, metres, y-up, unscaled.
        smpl_to_source: (24,) source joint index per SMPL joint, -1 where unmapped.
        root_scale: leg-length ratio applied to the root trajectory.
    """

    global_orient: np.ndarray
    body_pose: np.ndarray
    transl: np.ndarray
    betas: np.ndarray
    gender: Gender
    fps: float
    source: str
    motion_start: int
    rest_mode: str
    source_joint_names: tuple[str, ...]
    source_joints: np.ndarray = field(repr=False)
    smpl_to_source: tuple[int, ...] = ()
    root_scale: float = 1.0

    @property
    def num_frames(self) -> int:
        return int(self.transl.shape[0])


# ----------------------------------------------------------------------------- small math (numpy)


def _normalize(v: np.ndarray, eps: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) -> unit vectors (..., 3) and a validity mask (...) (False where the norm is ~0)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n[..., 0] > eps
    return v / np.where(n > eps, n, 1.0), ok


def swing_rotation(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Minimal rotation taking direction ``u`` onto ``v``. (..., 3), (..., 3) -> (..., 3, 3).

    Zero vectors give the identity; opposite vectors a half turn about an axis normal to ``u``.
    """
    u, v = np.broadcast_arrays(u, v)
    u, ok_u = _normalize(u)
    v, ok_v = _normalize(v)
    c = (u * v).sum(-1)
    axis = np.cross(u, v)
    w = 1.0 + c
    opposite = w < 1e-8
    if opposite.any():
        alt = np.cross(u, np.array([1.0, 0.0, 0.0]))
        alt = np.where((np.linalg.norm(alt, axis=-1) < 1e-6)[..., None], np.cross(u, np.array([0.0, 1.0, 0.0])), alt)
        axis = np.where(opposite[..., None], _normalize(alt)[0], axis)
        w = np.where(opposite, 0.0, w)
    q = np.concatenate([w[..., None], axis], axis=-1)
    q = np.where((ok_u & ok_v)[..., None], q, np.array([1.0, 0.0, 0.0, 0.0]))
    return quaternion_to_matrix_np(q)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors in degrees, (..., 3), (..., 3) -> (...)."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1)))


def _up_matrix(up: str) -> np.ndarray:
    """Rotation taking source world coordinates to y-up ones."""
    if up == "y":
        return np.eye(3)
    return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z-up: (x, y, z) -> (x, z, -y)


def _yaw_to(direction: np.ndarray) -> np.ndarray:
    """Rotation about +y taking +x onto the horizontal part of ``direction`` (identity if vertical)."""
    d = np.array([direction[0], 0.0, direction[2]])
    if np.linalg.norm(d) < 1e-9:
        return np.eye(3)
    return swing_rotation(np.array([1.0, 0.0, 0.0]), d)


# ----------------------------------------------------------------------------- retargeting


@dataclass(frozen=True)
class _Aim:
    joint: int
    a: int
    b: int


def _rigid_set(j: int, mapped: set[int]) -> set[int]:
    """``j`` and its descendants reached through unmapped joints only (their rest vectors are rigid in j)."""
    out = {j}
    for k in range(j + 1, NUM_JOINTS):
        p = PARENTS[k]
        if p in out and (p == j or p not in mapped):
            out.add(k)
    return out


def _aims(preset: RetargetPreset, mapped: set[int]) -> dict[int, _Aim]:
    aims: dict[int, _Aim] = {}
    for j in sorted(mapped):
        rigid = _rigid_set(j, mapped)
        name = JOINT_NAMES[j]
        if name in preset.aim:
            a, b = (JOINT_INDEX[x] for x in preset.aim[name])
            if a not in rigid or b not in rigid or a not in mapped or b not in mapped or a == b:
                raise RetargetError(f"retarget preset {preset.name}: aim {name} -> {preset.aim[name]} must name two "
                                    f"different mapped joints among {sorted(JOINT_NAMES[k] for k in rigid)}")
            aims[j] = _Aim(j, a, b)
        elif name == "pelvis" and {JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]} <= mapped:
            aims[j] = _Aim(j, JOINT_INDEX["right_hip"], JOINT_INDEX["left_hip"])
        else:
            targets = sorted(k for k in rigid if k != j and k in mapped)
            if targets:
                aims[j] = _Aim(j, j, targets[0])
    return aims


def _resample(G: np.ndarray, p: np.ndarray, src_fps: float, fps: float, start: int) -> tuple[np.ndarray, np.ndarray]:
    """Resample frames ``start:`` of global rotations (T, J, 3, 3) and positions (T, J, 3) to ``fps``."""
    Tm = G.shape[0] - start
    ratio = src_fps / fps
    if Tm <= 1 or abs(ratio - 1) < 1e-9:
        return G, p
    f = np.arange(0.0, Tm - 1 + 1e-9, ratio)
    if abs(ratio - round(ratio)) < 1e-3:  # BVH frame times are rounded (.0083333 s -> 120.0005 fps)
        idx = start + np.round(f).astype(np.int64)
        return np.concatenate([G[:start], G[idx]]), np.concatenate([p[:start], p[idx]])
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, Tm - 1)
    w = (f - i0)[:, None]
    G0, G1 = G[start + i0], G[start + i1]
    rel = Rotation.from_matrix((G0.swapaxes(-1, -2) @ G1).reshape(-1, 3, 3)).as_rotvec().reshape(G0.shape[:-1])
    Gi = G0 @ Rotation.from_rotvec((rel * w[..., None]).reshape(-1, 3)).as_matrix().reshape(G0.shape)
    pi = p[start + i0] * (1 - w[..., None]) + p[start + i1] * w[..., None]
    return np.concatenate([G[:start], Gi]), np.concatenate([p[:start], pi])


def retarget_bvh(
    path_or_motion: str | Path | BVHMotion,
    preset: str | Path | dict[str, Any] | RetargetPreset = "cmu",
    *,
    gender: Gender | str = Gender.NEUTRAL,
    betas: np.ndarray | torch.Tensor | None = None,
    fps: float | None = None,
    rest: RestMode | None = None,
    scale_root: bool = True,
    fit_directions: bool = True,
    model_dir: str | Path | None = None,
    rig_mapper: RigMapper | None = None,
) -> RetargetedClip:
    """Retarget a BVH clip onto SMPL (method in the module docstring).

    Args:
        path_or_motion: a BVH path or a parsed :class:`BVHMotion`.
        preset: ``"auto"`` (``rig_mapper`` picks it), a built-in preset name, JSON path, dict,
            or :class:`RetargetPreset`.
        gender: body model whose rest skeleton ``J(betas)`` receives the motion.
        betas: (10,) shape; zeros by default.
        fps: output frame rate (resampled; the source's rest frames are kept); None keeps the source's.
        rest: override the preset's rest-pose choice.
        scale_root: scale the root trajectory by the SMPL/source leg-length ratio.
        fit_directions: apply the per-frame direction fit (step 4); False gives rest alignment only
            (an ablation for the quality benchmark).
        model_dir: real SMPL files (default: ``$SMPLIK_MODEL_DIR`` or the built-in model).
        rig_mapper: the :data:`RigMapper` behind ``preset="auto"``
            (:func:`shape_inversion.auto_preset.auto_preset`).

    Returns:
        A :class:`RetargetedClip` with T frames (all source frames, or resampled).
    """
    from smplik.body_model import load_body_model

    motion = path_or_motion if isinstance(path_or_motion, BVHMotion) else read_motion(path_or_motion)
    preset = resolve_preset(motion, preset, rig_mapper)
    gender = Gender.parse(gender)
    model = load_body_model(gender, model_dir)
    betas_np = check_betas(betas)
    J_rest = model.rest_joints(torch.from_numpy(betas_np).float()).double().numpy()  # (24, 3)
    shapedirs = model.arrays["shapedirs"][:, :, :NUM_BETAS].astype(np.float64)
    floor_smpl = float((model.arrays["v_template"] + shapedirs @ betas_np)[:, 1].min())

    resolved = resolve_joint_names(preset.joints, motion.joint_names)
    missing = [f"{k} -> {v}" for k, v in preset.joints.items() if k not in resolved]
    if missing:
        joints = ", ".join(motion.joint_names[:40]) + (", ..." if motion.num_joints > 40 else "")
        raise RetargetError(f"{motion.name}: preset {preset.name!r} names source joints the file does not have: "
                            f"{', '.join(missing)} (file joints: {joints})")
    src = np.full(NUM_JOINTS, -1, dtype=np.int64)
    for k, i in resolved.items():
        src[JOINT_INDEX[k]] = i
    mapped = {int(j) for j in np.nonzero(src >= 0)[0]}
    aims = _aims(preset, mapped)

    # Source in metres, y-up: G = C G_file, p = units * C p_file.
    C = _up_matrix(preset.up)
    G_src = C @ motion.global_rotations
    p_src = preset.units * np.einsum("ij,tkj->tki", C, motion.positions)
    start = min(max(preset.motion_start, 0), max(motion.num_frames - 1, 0))
    out_fps = motion.fps if fps is None else float(fps)
    if fps is not None:
        from smplik.limits import check_rate, check_resampled_frames

        out_fps = check_rate(fps, f"{motion.name}: the resampling rate (fps)")
        # what the resampling makes, before it is made (a 1000 s Frame Time at 30 frames/s is 30,000 frames a frame)
        check_resampled_frames(max(motion.num_frames - 1 - start, 0) / motion.fps, out_fps, motion.name)
        G_src, p_src = _resample(G_src, p_src, motion.fps, out_fps, start)

    # Source rest pose candidates and the choice.
    R_off, p_off = motion.rest_pose()
    candidates = {"offsets": (C @ R_off, preset.units * p_off @ C.T)}
    if motion.num_frames > 0:
        candidates["frame0"] = (C @ motion.global_rotations[0], preset.units * motion.positions[0] @ C.T)
    mode = rest or preset.rest
    if mode == "auto":
        scores = {m: _rest_score(candidates[m][1], aims, src, J_rest) for m in candidates}
        mode = min(scores, key=scores.get)  # type: ignore[arg-type]
    if mode not in candidates:
        raise RetargetError(f"{motion.name}: rest pose {mode!r} unavailable (the file has no frames)")
    G_rest, p_rest = candidates[mode]
    Y = _facing_yaw(p_rest, src)

    # Global SMPL rotations, joint by joint (parents first), batched over frames.
    T = G_src.shape[0]
    G = np.empty((T, NUM_JOINTS, 3, 3))
    for j in range(NUM_JOINTS):
        s = src[j]
        if s < 0:
            G[:, j] = G[:, PARENTS[j]]
            continue
        A = G_rest[s].T @ Y
        aim = aims.get(j)
        d = e = None
        if aim is not None:
            d, ok_d = _normalize(J_rest[aim.b] - J_rest[aim.a])
            e, ok_e = _normalize(Y.T @ (p_rest[src[aim.b]] - p_rest[src[aim.a]]))
            if ok_d and ok_e:
                A = A @ swing_rotation(d, e)
            else:
                aim = None
        G_j = G_src[:, s] @ A
        if aim is not None and fit_directions:
            posed = G_j @ d
            target = p_src[:, src[aim.b]] - p_src[:, src[aim.a]]
            G_j = swing_rotation(posed, target) @ G_j
        G[:, j] = G_j

    # Root: SMPL mid-hip onto the (scaled) source mid-hip.
    hips = [JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]]
    anchor = hips if all(src[h] >= 0 for h in hips) else [0]
    scale = _leg_ratio(J_rest, p_rest, src) if scale_root else 1.0
    a_src = p_src[:, src[anchor]].mean(axis=1)
    floor_src = preset.floor * preset.units
    target = np.stack([scale * a_src[:, 0], floor_smpl + scale * (a_src[:, 1] - floor_src), scale * a_src[:, 2]], -1)
    pelvis = target - G[:, 0] @ (J_rest[anchor].mean(axis=0) - J_rest[0])
    transl = pelvis - J_rest[0]

    R_local = global_to_local(torch.from_numpy(G))
    aa = matrix_to_axis_angle(R_local).numpy().astype(np.float32)
    return RetargetedClip(
        global_orient=aa[:, 0].copy(),
        body_pose=aa[:, 1:].copy(),
        transl=transl.astype(np.float32),
        betas=betas_np.astype(np.float32),
        gender=gender,
        fps=out_fps,
        source=motion.name,
        motion_start=start,
        rest_mode=mode,
        source_joint_names=motion.joint_names,
        source_joints=p_src.astype(np.float32),
        smpl_to_source=tuple(int(x) for x in src),
        root_scale=float(scale),
    )


def _facing_yaw(p_rest: np.ndarray, src: np.ndarray) -> np.ndarray:
    """Yaw taking SMPL's rest left (+x) onto the source rest left (hip line, else shoulder line)."""
    for left, right in (("left_hip", "right_hip"), ("left_shoulder", "right_shoulder")):
        lj, rj = src[JOINT_INDEX[left]], src[JOINT_INDEX[right]]
        if lj >= 0 and rj >= 0:
            return _yaw_to(p_rest[lj] - p_rest[rj])
    return np.eye(3)


def _rest_score(p_rest: np.ndarray, aims: dict[int, _Aim], src: np.ndarray, J_rest: np.ndarray) -> float:
    """Mean angle (deg) between SMPL T-pose aim bones and the source rest pose's, after the facing yaw."""
    Y = _facing_yaw(p_rest, src)
    angles = []
    for aim in aims.values():
        d = J_rest[aim.b] - J_rest[aim.a]
        e = Y.T @ (p_rest[src[aim.b]] - p_rest[src[aim.a]])
        if np.linalg.norm(d) > 1e-9 and np.linalg.norm(e) > 1e-9:
            angles.append(_angle_deg(d, e))
    return float(np.mean(angles)) if angles else 0.0


def _leg_ratio(J_rest: np.ndarray, p_rest: np.ndarray, src: np.ndarray) -> float:
    """SMPL / source leg length (hip-knee-ankle, both sides), or 1 if the legs are not mapped."""
    ratios = []
    for side in ("left", "right"):
        chain = [JOINT_INDEX[f"{side}_{n}"] for n in ("hip", "knee", "ankle")]
        if all(src[j] >= 0 for j in chain):
            bones = list(zip(chain[:-1], chain[1:], strict=True))
            smpl = sum(np.linalg.norm(J_rest[b] - J_rest[a]) for a, b in bones)
            source = sum(np.linalg.norm(p_rest[src[b]] - p_rest[src[a]]) for a, b in bones)
            if source > 1e-9:
                ratios.append(smpl / source)
    return float(np.mean(ratios)) if ratios else 1.0


# ----------------------------------------------------------------------------- quality metric

QUALITY_BONES: tuple[tuple[str, str, str, str], ...] = (
    ("left_thigh", "thighs", "left_hip", "left_knee"),
    ("right_thigh", "thighs", "right_hip", "right_knee"),
    ("left_shin", "shins", "left_knee", "left_ankle"),
    ("right_shin", "shins", "right_knee", "right_ankle"),
    ("left_foot", "feet", "left_ankle", "left_foot"),
    ("right_foot", "feet", "right_ankle", "right_foot"),
    ("lower_spine", "spine", "spine1", "spine2"),
    ("upper_spine", "spine", "spine2", "spine3"),
    ("lower_neck", "neck", "spine3", "neck"),
    ("upper_neck", "neck", "neck", "head"),
    ("left_upper_arm", "upper_arms", "left_shoulder", "left_elbow"),
    ("right_upper_arm", "upper_arms", "right_shoulder", "right_elbow"),
    ("left_forearm", "forearms", "left_elbow", "left_wrist"),
    ("right_forearm", "forearms", "right_elbow", "right_wrist"),
)
"""(bone, group, SMPL start joint, SMPL end joint): the bones the retarget quality metric scores."""

DIAGNOSTIC_BONES: tuple[tuple[str, str, str, str], ...] = (
    ("hip_line", "diagnostic", "right_hip", "left_hip"),
    ("shoulder_line", "diagnostic", "right_shoulder", "left_shoulder"),
    ("left_clavicle", "diagnostic", "left_collar", "left_shoulder"),
    ("right_clavicle", "diagnostic", "right_collar", "right_shoulder"),
    ("left_hand", "diagnostic", "left_wrist", "left_hand"),
    ("right_hand", "diagnostic", "right_wrist", "right_hand"),
)
"""Extra bones, reported but not part of the score (lines across the body depend on rig proportions)."""


@dataclass(frozen=True)
class BoneDirectionErrors:
    """Angles between retargeted SMPL bones and their source bones.

    Attributes:
        bones: (B,) bone names; groups: (B,) group names.
        degrees: (T, B) angle in degrees per frame and bone.
    """

    bones: tuple[str, ...]
    groups: tuple[str, ...]
    degrees: np.ndarray

    def group_means(self) -> dict[str, float]:
        """Mean angle per group over frames and the group's bones."""
        return {g: float(self.degrees[:, [i for i, x in enumerate(self.groups) if x == g]].mean())
                for g in dict.fromkeys(self.groups)}

    def mean(self) -> float:
        return float(self.degrees.mean())


def bone_direction_errors(
    clip: RetargetedClip,
    *,
    frames: np.ndarray | slice | None = None,
    bones: tuple[tuple[str, str, str, str], ...] = QUALITY_BONES,
    model_dir: str | Path | None = None,
) -> BoneDirectionErrors:
    """Angle (deg) between each retargeted bone (our FK on ``J(betas)``) and its source bone.

    ``frames`` selects frames (default: all from ``clip.motion_start``). Bones whose two joints
    are not both mapped are left out.
    """
    from smplik.body_model import load_body_model

    idx = np.arange(clip.num_frames)[slice(clip.motion_start, None) if frames is None else frames]
    model = load_body_model(clip.gender, model_dir)
    joints = model.joints(torch.from_numpy(clip.global_orient[idx]).double(),
                          torch.from_numpy(clip.body_pose[idx]).double(),
                          torch.from_numpy(clip.transl[idx]).double(),
                          torch.from_numpy(clip.betas).double().expand(len(idx), NUM_BETAS)).numpy()
    src = np.asarray(clip.smpl_to_source)
    src_joints = clip.source_joints[idx].astype(np.float64)
    kept = [b for b in bones if src[JOINT_INDEX[b[2]]] >= 0 and src[JOINT_INDEX[b[3]]] >= 0]
    a = np.array([JOINT_INDEX[b[2]] for b in kept], dtype=np.int64)
    b = np.array([JOINT_INDEX[b[3]] for b in kept], dtype=np.int64)
    deg = _angle_deg(joints[:, b] - joints[:, a], src_joints[:, src[b]] - src_joints[:, src[a]])
    return BoneDirectionErrors(tuple(x[0] for x in kept), tuple(x[1] for x in kept), deg.reshape(len(idx), len(kept)))
