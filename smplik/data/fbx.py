"""FBX skeletons and animations (Mixamo, Unity, Unreal, Maya, Blender, MotionBuilder...), read as a BVH motion.

The file is parsed by the ``ufbx`` C library through its Python bindings (``pip install "smplik[fbx]"``;
MIT / public domain; binary FBX 2.x-7.7 and ASCII 6.x/7.x). ufbx is asked to bring the scene into
**metres, y up, right-handed** (``target_axes``, ``target_unit_meters``: it reads ``UnitScaleFactor``,
``UpAxis``/``FrontAxis``/``CoordAxis`` and their signs from the file's global settings and adds one root
transform), so everything here is in metres and smplik's axes before any joint is mapped.

What becomes a :class:`~smplik.data.bvh.BVHMotion`:

* **Joints**: the skeleton nodes (``LimbNode`` / bone attributes) and every node a skin cluster deforms
  with (Softimage and 3ds Max skin on ``Null`` nodes); listed parents first, each joint's parent being
  its nearest ancestor among the joints (an ``Armature`` null above Blender's bones is not a joint).
  A file with neither keeps every node without geometry, camera or light.
* **Rest pose** = the BVH OFFSETs: the **bind pose** (the skin clusters' ``TransformLink``), else the
  nodes' default transforms (the file's rest). OFFSETs are world-aligned:
  ``offset_j = p_j - p_parent`` in the rest pose, so the zero-rotation pose *is* the bind pose.
* **Frames**: one animation take (``AnimStack``) sampled at the file's frame rate from its start to
  its end. Each frame's rotations are the world rotations relative to the rest:
  ``R_world_joint(t) = rot(T_world_joint(t)) rot(T_world_joint(rest))^T``, local ones
  ``R_parent^T R_joint``; roots, and joints whose local translation is animated, get position
  channels (``t_parent_joint = R_world_parent^T (p_joint - p_parent)``). Scale animation is dropped.
  A file without a take (a character with no clip) has one frame: the default pose.

Which take (:func:`fbx_takes`, :func:`read_fbx`): ``take=None`` picks the take that animates the most
properties (Mixamo files carry an empty ``Take 001`` beside ``mixamo.com``), the longest on a tie.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smplik.data.bvh import BVHError, BVHMotion, bvh_forward_kinematics
from smplik.limits import DEFAULT_MAX_JOINTS, LimitError, check_input_file
from smplik.rotations import matrix_to_euler_deg_np

MAX_FBX_BYTES = 1 << 30
"""Largest FBX file read (bytes)."""

ROTATION_ORDER = "ZYX"
"""Euler order of the rotation channels of the BVH an FBX becomes (``Zrotation Yrotation Xrotation``)."""


class FbxError(BVHError):
    """An FBX file cannot be read (or ``ufbx`` is missing); the message names the file and the problem."""


@dataclass(frozen=True)
class FbxTake:
    """One animation take of an FBX file.

    Attributes:
        name: the AnimStack name (``mixamo.com``, ``Take 001``, ``Armature|idle``).
        start, end: seconds.
        animated: how many properties the take animates.
    """

    name: str
    start: float
    end: float
    animated: int


def _worker_env() -> dict[str, str]:
    """The child's environment: the caller's, with this smplik first on its path (an uninstalled checkout too)."""
    import os

    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "1")
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root, *(p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p)])
    return env


def _run_worker(path: Path, take: str | int | None, max_joints: int, max_frames: int | None,
                frames: bool = True, mesh: bool = False) -> tuple[dict, dict[str, np.ndarray]]:
    """Run :mod:`smplik.data.fbx_worker` on ``path`` in a child process; returns its JSON header and arrays.

    ufbx is a C parser with Python bindings whose object wrappers (0.0.5) do not own their references:
    it runs in a child process, so that neither a hostile file nor a binding fault can take the caller down.
    """
    import json
    import subprocess
    import sys
    import tempfile

    try:
        size = check_input_file(path, "FBX file")
    except LimitError as exc:
        raise FbxError(str(exc)) from None
    except OSError as exc:
        raise FbxError(f"{path}: cannot read FBX file: {exc.strerror or exc}") from None
    if size > MAX_FBX_BYTES:
        raise FbxError(f"{path}: {size} bytes exceeds the FBX size limit {MAX_FBX_BYTES}")
    with tempfile.TemporaryDirectory(prefix="smplik-fbx-") as tmp:
        out = Path(tmp) / "out.npz"
        request = json.dumps({"path": str(path), "take": take, "max_joints": int(max_joints),
                              "max_frames": None if max_frames is None else int(max_frames), "frames": frames,
                              "mesh": mesh,
                              "max_fbx_bytes": MAX_FBX_BYTES, "out": str(out)})
        try:
            done = subprocess.run([sys.executable, "-m", "smplik.data.fbx_worker"], input=request.encode(),
                                  capture_output=True, env=_worker_env(), timeout=3600, check=False)
        except subprocess.TimeoutExpired:
            raise FbxError(f"{path}: reading the FBX file took over an hour; refused") from None
        lines = done.stdout.decode("utf-8", "replace").strip().splitlines()
        try:
            header = json.loads(lines[-1]) if lines else None
        except ValueError:
            header = None
        if done.returncode != 0 or not isinstance(header, dict):
            err = done.stderr.decode("utf-8", "replace").strip().splitlines()
            why = err[-1][:200] if err else f"exit status {done.returncode}"
            raise FbxError(f"{path}: the FBX reader (ufbx) failed on this file ({why})")
        if "error" in header:
            raise FbxError(str(header["error"]))
        arrays: dict[str, np.ndarray] = {}
        if out.exists():
            with np.load(out, allow_pickle=False) as data:
                arrays = {k: np.asarray(data[k]) for k in data.files}
    return header, arrays


def read_fbx_takes(path: str | Path) -> list[FbxTake]:
    """The animation takes of an FBX file (no frame is evaluated)."""
    header, _ = _run_worker(Path(path), None, DEFAULT_MAX_JOINTS, 1, frames=False)
    return [FbxTake(t["name"], float(t["start"]), float(t["end"]), int(t["animated"])) for t in header["takes"]]


@dataclass(frozen=True, eq=False)
class FbxInfo:
    """What an FBX file said about itself, for messages.

    Attributes:
        unit_m: metres per file unit (``UnitScaleFactor`` / 100).
        up: the file's up axis (``y``, ``z``, ``-z``...).
        rest: where the rest pose came from.
        take: the take read (None: none).
        takes: every take of the file.
        creator: the exporting tool (``FBX SDK/FBX Plugins version 2020.3``, ``Blender (stable FBX IO)``).
        version: FBX version (7400, 7700...); ``ascii``: an ASCII file.
    """

    unit_m: float
    up: str
    rest: str
    take: str | None
    takes: tuple[FbxTake, ...]
    creator: str
    version: int
    ascii: bool

    def summary(self, rest: str | None = None) -> str:
        """One line: ``<rest> (FBX 7700 binary from FBX SDK ..., units cm, y up, take 'mixamo.com')``; ``rest``
        replaces the file's rest pose when another was used."""
        unit = {1.0: "m", 0.01: "cm", 0.001: "mm", 0.1: "dm", 0.0254: "in"}.get(round(self.unit_m, 6),
                                                                                 f"{self.unit_m:g} m")
        take = f", take {self.take!r}" if self.take is not None else ", no animation take"
        if len(self.takes) > 1:
            take += f" (of {len(self.takes)}: {', '.join(repr(t.name) for t in self.takes)})"
        return (f"{rest or self.rest} (FBX {self.version} {'ASCII' if self.ascii else 'binary'} from "
                f"{self.creator or 'an unknown tool'}, units {unit}, {self.up} up{take})")


def read_fbx_info(path: str | Path, *, take: str | int | None = None, max_joints: int = DEFAULT_MAX_JOINTS,
                  max_frames: int | None = None) -> tuple[BVHMotion, FbxInfo]:
    """:func:`read_fbx` and what the file said about itself (:class:`FbxInfo`)."""
    path = Path(path)
    header, arrays = _run_worker(path, take, max_joints, max_frames)
    info = FbxInfo(float(header["unit_m"]), str(header["up"]), str(header["rest"]), header["take"],
                   tuple(FbxTake(t["name"], float(t["start"]), float(t["end"]), int(t["animated"]))
                         for t in header["takes"]), str(header["creator"]), int(header["version"]),
                   bool(header["ascii"]))
    rest, world = arrays.get("rest"), arrays.get("world")
    names, parents = list(header["names"]), tuple(int(p) for p in header["parents"])
    J = len(names)
    if rest is None or world is None or rest.shape != (J, 4, 4) or world.ndim != 4 or world.shape[1:] != (J, 4, 4) \
            or not np.isfinite(rest).all() or not np.isfinite(world).all():
        raise FbxError(f"{path}: the FBX reader returned no usable transforms")
    return motion_from_world(str(path), names, parents, rest, world, 1.0 / float(header["fps"])), info


@dataclass(frozen=True, eq=False)
class FbxMesh:
    """An FBX file's skinned meshes in the bind pose (V vertices, F triangles), metres, y up.

    Attributes:
        vertices: (V, 3) bind-pose positions, world.
        faces: (F, 3) vertex indices (polygons fanned).
        joints: (V, 4) indices into ``joint_names`` (the four largest influences).
        weights: (V, 4) weights summing to 1.
        joint_names, parents: the file's joints as :func:`read_fbx` lists them.
    """

    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]


def read_fbx_mesh(path: str | Path, *, max_joints: int = DEFAULT_MAX_JOINTS) -> FbxMesh | None:
    """The skinned meshes of an FBX file in its bind pose, or None when it has none (an animation-only clip)."""
    header, arrays = _run_worker(Path(path), None, max_joints, 1, frames=False, mesh=True)
    if "mesh_vertices" not in arrays:
        return None
    names = tuple(str(n) for n in header["names"])
    joints = arrays["mesh_joints"].astype(np.int64)
    V, F = arrays["mesh_vertices"], arrays["mesh_faces"].astype(np.int64)
    if joints.min(initial=0) < 0 or joints.max(initial=0) >= len(names) or F.min(initial=0) < 0 \
            or F.max(initial=0) >= len(V) or not np.isfinite(V).all():
        raise FbxError(f"{path}: the FBX reader returned an inconsistent skinned mesh")
    return FbxMesh(V, F, joints, arrays["mesh_weights"], names, tuple(int(p) for p in header["parents"]))


def read_fbx(path: str | Path, *, take: str | int | None = None, max_joints: int = DEFAULT_MAX_JOINTS,
             max_frames: int | None = None) -> BVHMotion:
    """Read an FBX skeleton and one animation take as a :class:`BVHMotion` in metres, y up (module docstring).

    Args:
        path: the ``.fbx`` file (binary or ASCII).
        take: a take name or index; None: the take animating the most properties.
        max_joints: refuse files with more joints.
        max_frames: keep at most this many frames (the first ones); None: all (bounded by ``BVH_FRAMES``).

    Returns: the motion; ``rest_pose()`` (its OFFSETs) is the bind pose. Raises :class:`FbxError`.
    """
    return read_fbx_info(path, take=take, max_joints=max_joints, max_frames=max_frames)[0]


def _rotation(T: np.ndarray) -> np.ndarray:
    """The rotation of (..., 4, 4) transforms with scale (and shear) removed: (..., 3, 3) (polar decomposition)."""
    u, _, vt = np.linalg.svd(T[..., :3, :3])
    flip = np.linalg.det(u @ vt) < 0  # a mirrored joint: keep a proper rotation
    u = u.copy()
    u[flip, :, -1] *= -1
    return u @ vt


def motion_from_world(name: str, joint_names: list[str], parents: tuple[int, ...], T_world_rest: np.ndarray,
                      T_world: np.ndarray, frame_time: float) -> BVHMotion:
    """A world-aligned BVH motion from joint world transforms.

    Args:
        T_world_rest: (J, 4, 4) the rest pose (becomes the OFFSETs).
        T_world: (T, J, 4, 4) every frame.

    Returns: a :class:`BVHMotion` whose zero-rotation pose is the rest pose, reproducing every frame's joint
    positions (rotations with scale removed). Roots and joints with an animated local translation get
    ``Xposition Yposition Zposition`` channels.
    """
    T, J = T_world.shape[:2]
    p_rest = T_world_rest[:, :3, 3]
    offsets = np.array([p_rest[j] if p < 0 else p_rest[j] - p_rest[p] for j, p in enumerate(parents)])
    R_rest = _rotation(T_world_rest)
    G = _rotation(T_world) @ np.swapaxes(R_rest, -1, -2)[None]  # (T, J, 3, 3) world rotation relative to rest
    p = T_world[..., :3, 3]
    P = np.asarray(parents)
    has_parent = P >= 0
    R_local = G.copy()
    R_local[:, has_parent] = np.swapaxes(G[:, P[has_parent]], -1, -2) @ G[:, has_parent]
    t_local = np.broadcast_to(offsets, (T, J, 3)).copy()
    t_local[:, ~has_parent] = p[:, ~has_parent]
    delta = np.einsum("tjba,tjb->tja", G[:, P[has_parent]], p[:, has_parent] - p[:, P[has_parent]])
    scale = max(float(np.ptp(p_rest, axis=0).max()), 1e-9)
    moved = (np.abs(delta - offsets[has_parent]).max(axis=0).max(axis=-1) > 1e-7 * scale if T
             else np.zeros(int(has_parent.sum()), bool))
    translated = ~has_parent
    translated[np.flatnonzero(has_parent)[moved]] = True
    t_local[:, has_parent] = np.where(moved[None, :, None], delta, offsets[has_parent])
    euler = matrix_to_euler_deg_np(R_local, ROTATION_ORDER)  # (T, J, 3) Z, Y, X degrees
    rot = tuple(f"{a}rotation" for a in ROTATION_ORDER)
    channels = tuple(("Xposition", "Yposition", "Zposition") + rot if translated[j] else rot for j in range(J))
    columns = [np.concatenate([t_local[:, j], euler[:, j]], axis=1) if translated[j] else euler[:, j]
               for j in range(J)]
    values = np.concatenate(columns, axis=1)
    # the motion as a BVH reader would see it (Euler angles round trip): FK from the channels
    from smplik.rotations import euler_deg_to_matrix_np

    R_local = euler_deg_to_matrix_np(euler, ROTATION_ORDER)
    R_world, positions = bvh_forward_kinematics(R_local, t_local, parents)
    leaves = [j for j in range(J) if j not in set(parents)]
    return BVHMotion(name=name, joint_names=tuple(joint_names), parents=tuple(parents), offsets=offsets,
                     channels=channels, end_site_parents=tuple(leaves), end_site_offsets=np.zeros((len(leaves), 3)),
                     frame_time=float(frame_time), values=values, local_translations=t_local,
                     local_rotations=R_local, global_rotations=R_world, positions=positions,
                     position_mode="replace")
