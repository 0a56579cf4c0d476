"""The project's own SMPL-format body model, generated deterministically.

Real SMPL files cannot be redistributed, so smplik ships this generator. It builds a human-like
body in SMPL's exact array layout (``v_template``, ``shapedirs``, ``posedirs``, ``J_regressor``,
``weights``, ``kintree_table``, ``f``) for the neutral, male and female genders, and
:func:`builtin_model_path` writes it as ``SMPL_{NEUTRAL,MALE,FEMALE}.npz`` so that it is loaded
through the same code path as real SMPL files (plain smplx loads it too).

How the body is made (all steps are deterministic, there is no random number anywhere):

1. A smooth signed-distance field (smooth-min union of ellipsoids, tapered capsules and rounded
   boxes along SMPL's bones) is sampled on a grid symmetric about x = 0, made exactly
   mirror-symmetric, and extracted with marching cubes into a closed (watertight) mesh of a few
   thousand vertices, then lightly Taubin-smoothed. Neutral, male and female share this topology.
2. Every vertex has a mirror partner (exact on the symmetric grid); positions, skinning weights,
   ``J_regressor`` and ``shapedirs`` are symmetrised with that permutation, so rest joints
   ``J(beta)`` are exactly mirror-symmetric for every beta.
3. Skinning weights are a softmax of the distance to each joint's body parts, then smoothed over
   the mesh graph. ``J_regressor`` rows are convex vertex averages (a spread of vertices around
   the joint plus a non-negative least-squares correction) that reproduce SMPL-like joint
   locations to well under a millimetre.
4. Male and female are smooth, mirror-symmetric displacement fields of the neutral vertices
   (stature, shoulder and hip width, chest, waist...), rescaled to their stature.

Conventions (see :mod:`smplik.conventions`): metres, y-up, the body faces +z, its left is at +x,
T-pose at rest (arms along +-x, palms down, legs straight), soles on the floor at y = 0.
Rest statures: neutral 1.70 m, male 1.78 m, female 1.64 m.

The built-in model has **no pose correctives**: ``posedirs`` is all zeros (SMPL's layout is kept
so that every loader works unchanged).

Shape components (``shapedirs[..., k]``, linear, each mirror-symmetric; +-3 spans realistic
adults):

0. stature: uniform scale about the floor point under the body, +0.07 m of stature per unit.
1. mass / girth: every body part grows radially away from its bone axis (+6 % per unit).
2. leg-to-torso ratio: legs +2 cm per unit, torso and neck shortened by as much (stature kept).
3. arm length: upper arm, forearm and hand lengthen together (+4 % per unit).
4. shoulder width: shoulders and arms move outwards (+1.2 cm per side per unit).
5. hip width: hips widen and the legs move outwards (+1 cm per side per unit).
6. chest depth: the chest grows front-to-back (+6 % per unit).
7. waist girth: the waist grows radially (+7 % per unit at the waist).
8. head size: the head scales about the head joint (+5 % per unit).
9. neck length: the neck lengthens and the head moves up (+1 cm per unit).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

from smplik.atomic import write_npz_deterministic
from smplik.conventions import JOINT_INDEX, LEFT_RIGHT, NUM_BETAS, NUM_JOINTS, PARENTS, Gender
from smplik.paths import cache_dir as default_cache_dir

BUILTIN_VERSION = "1"
"""Version of the generator; bump it whenever the generated arrays change (it is part of the cache path)."""

STATURE_BETA = 0
"""Index of the stature shape component."""

BETA_DESCRIPTIONS: tuple[str, ...] = (
    "stature: uniform scale about the floor point under the body, +0.07 m of stature per unit",
    "mass / girth: every body part grows radially away from its bone axis, +6 % per unit",
    "leg-to-torso ratio: legs +2 cm per unit, torso and neck shortened by as much (stature kept)",
    "arm length: upper arm, forearm and hand lengthen together, +4 % per unit",
    "shoulder width: shoulders and arms move outwards, +1.2 cm per side per unit",
    "hip width: hips widen and the legs move outwards, +1 cm per side per unit",
    "chest depth: the chest grows front-to-back, +6 % per unit",
    "waist girth: the waist grows radially, +7 % per unit at the waist",
    "head size: the head scales about the head joint, +5 % per unit",
    "neck length: the neck lengthens and the head moves up, +1 cm per unit",
)
assert len(BETA_DESCRIPTIONS) == NUM_BETAS

STATURE_M: dict[Gender, float] = {Gender.NEUTRAL: 1.70, Gender.MALE: 1.78, Gender.FEMALE: 1.64}
"""Rest stature (max y - min y of the vertices at beta = 0) per gender, metres."""

_FILE_NAMES = {
    Gender.NEUTRAL: "SMPL_NEUTRAL.npz",
    Gender.MALE: "SMPL_MALE.npz",
    Gender.FEMALE: "SMPL_FEMALE.npz",
}
_ROOT_PARENT = 4294967295  # SMPL files store the root's parent as uint32(-1)
_MIRROR = np.array([-1.0, 1.0, 1.0])

# ----------------------------------------------------------------------------------------------
# Design of the neutral body, before scaling: metres, relative to the pelvis, left side (+x).
# Joint targets follow real SMPL's neutral template.
# ----------------------------------------------------------------------------------------------

_LEFT_JOINTS: dict[str, tuple[float, float, float]] = {
    "pelvis": (0.0, 0.0, 0.0),
    "left_hip": (0.07, -0.09, 0.0),
    "spine1": (0.0, 0.11, -0.02),
    "left_knee": (0.105, -0.47, 0.0),
    "spine2": (0.0, 0.25, -0.01),
    "left_ankle": (0.09, -0.88, -0.04),
    "spine3": (0.0, 0.31, 0.0),
    "left_foot": (0.12, -0.94, 0.08),
    "neck": (0.0, 0.52, -0.03),
    "left_collar": (0.08, 0.43, -0.01),
    "head": (0.0, 0.61, 0.02),
    "left_shoulder": (0.17, 0.46, -0.02),
    "left_elbow": (0.43, 0.44, -0.04),
    "left_wrist": (0.68, 0.45, -0.04),
    "left_hand": (0.77, 0.44, -0.05),
}


def _design_joints() -> np.ndarray:
    """Target joint locations of the neutral design, (24, 3), relative to the pelvis."""
    out = np.zeros((NUM_JOINTS, 3))
    for name, xyz in _LEFT_JOINTS.items():
        out[JOINT_INDEX[name]] = xyz
        if name.startswith("left_"):
            out[JOINT_INDEX["right_" + name[5:]]] = (-xyz[0], xyz[1], xyz[2])
    return out


@dataclass(frozen=True)
class _Primitive:
    """One solid of the body's signed-distance field, owned by one joint (for skinning)."""

    kind: str  # "ellipsoid" (a = centre, r = radii), "capsule" (a -> b, radii r[0] -> r[1]), "box"
    joint: str
    a: tuple[float, float, float]
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    r: tuple[float, float, float] = (0.0, 0.0, 0.0)
    round_: float = 0.0  # rounding radius of a box (a = centre, r = half extents)


def _left_primitives() -> list[_Primitive]:
    """Solids of the neutral design; those with x > 0 are mirrored to the right side."""
    E, C, B = "ellipsoid", "capsule", "box"
    return [
        # torso
        _Primitive(E, "pelvis", (0.0, -0.03, -0.01), r=(0.168, 0.125, 0.11)),
        _Primitive(E, "pelvis", (0.065, -0.07, -0.045), r=(0.085, 0.095, 0.075)),  # buttock
        _Primitive(E, "spine1", (0.0, 0.12, -0.005), r=(0.145, 0.15, 0.1)),
        _Primitive(E, "spine2", (0.0, 0.27, 0.0), r=(0.16, 0.15, 0.11)),
        _Primitive(E, "spine3", (0.0, 0.37, -0.01), r=(0.155, 0.1, 0.1)),
        _Primitive(C, "left_collar", (0.03, 0.43, -0.025), (0.15, 0.455, -0.025), r=(0.06, 0.055, 0.0)),
        _Primitive(C, "neck", (0.0, 0.44, -0.03), (0.0, 0.62, -0.005), r=(0.056, 0.05, 0.0)),
        _Primitive(E, "head", (0.0, 0.69, 0.02), r=(0.077, 0.105, 0.095)),
        _Primitive(E, "head", (0.0, 0.635, 0.045), r=(0.055, 0.05, 0.07)),  # jaw
        _Primitive(E, "head", (0.0, 0.685, 0.115), r=(0.014, 0.026, 0.022)),  # nose
        # legs
        _Primitive(C, "left_hip", (0.075, -0.08, 0.0), (0.105, -0.47, 0.0), r=(0.09, 0.057, 0.0)),
        _Primitive(C, "left_knee", (0.105, -0.47, 0.0), (0.09, -0.88, -0.035), r=(0.054, 0.036, 0.0)),
        _Primitive(E, "left_knee", (0.103, -0.61, -0.03), r=(0.048, 0.11, 0.05)),  # calf
        _Primitive(B, "left_ankle", (0.094, -0.937, -0.005), r=(0.02, 0.008, 0.07), round_=0.025),
        _Primitive(B, "left_foot", (0.112, -0.947, 0.105), r=(0.02, 0.004, 0.055), round_=0.017),
        # arms, palms down
        _Primitive(E, "left_shoulder", (0.18, 0.455, -0.022), r=(0.07, 0.058, 0.058)),  # deltoid
        _Primitive(C, "left_shoulder", (0.17, 0.46, -0.02), (0.43, 0.44, -0.04), r=(0.052, 0.039, 0.0)),
        _Primitive(C, "left_elbow", (0.43, 0.44, -0.04), (0.68, 0.45, -0.04), r=(0.039, 0.028, 0.0)),
        _Primitive(B, "left_wrist", (0.735, 0.445, -0.043), r=(0.04, 0.006, 0.026), round_=0.012),
        _Primitive(B, "left_hand", (0.825, 0.44, -0.05), r=(0.04, 0.003, 0.026), round_=0.01),
    ]


def _all_primitives() -> list[_Primitive]:
    """Left primitives plus their mirror images, (x -> -x, left_ -> right_)."""
    out = []
    for p in _left_primitives():
        out.append(p)
        if p.a[0] > 0.0 or p.b[0] > 0.0:
            out.append(
                _Primitive(
                    p.kind,
                    p.joint.replace("left_", "right_"),
                    (-p.a[0], p.a[1], p.a[2]),
                    (-p.b[0], p.b[1], p.b[2]),
                    p.r,
                    p.round_,
                )
            )
    return out


def _primitive_sdf(p: _Primitive, x: np.ndarray) -> np.ndarray:
    """Approximate signed distance of points ``x`` (N, 3) to one primitive, (N,)."""
    a = np.asarray(p.a)
    r = np.asarray(p.r)
    if p.kind == "ellipsoid":
        q = x - a
        k0 = np.linalg.norm(q / r, axis=-1)
        k1 = np.linalg.norm(q / (r * r), axis=-1)
        return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)
    if p.kind == "capsule":
        b = np.asarray(p.b)
        ab = b - a
        t = np.clip((x - a) @ ab / (ab @ ab), 0.0, 1.0)
        radius = r[0] + (r[1] - r[0]) * t
        return np.linalg.norm(x - (a + t[:, None] * ab), axis=-1) - radius
    if p.kind == "box":
        q = np.abs(x - a) - r
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        inside = np.minimum(q.max(axis=-1), 0.0)
        return outside + inside - p.round_
    raise AssertionError(p.kind)


def _smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum of two distance fields with blend radius ``k`` (metres)."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * k * 0.25


# ----------------------------------------------------------------------------------------------
# Mesh
# ----------------------------------------------------------------------------------------------

_GRID_STEP = 0.019  # metres; sets the vertex count (about 5,000)
_BLEND = 0.04  # smooth-min blend radius, metres


def _symmetric_axis(lo: float, hi: float, step: float) -> np.ndarray:
    """Grid coordinates covering [lo, hi] with spacing ``step``."""
    n = int(np.ceil((hi - lo) / step)) + 1
    return lo + step * np.arange(n)


def _build_neutral_mesh() -> tuple[np.ndarray, np.ndarray]:
    """Marching-cubes mesh of the design SDF, before smoothing.

    Returns:
        vertices (V, 3) float64 in design coordinates, faces (F, 3) int64 with outward winding.
    """
    from skimage.measure import marching_cubes

    prims = _all_primitives()
    half = int(np.ceil(0.95 / _GRID_STEP))
    xs = _GRID_STEP * np.arange(-half, half + 1)  # exactly symmetric about x = 0
    ys = _symmetric_axis(-1.02, 0.84, _GRID_STEP)
    zs = _symmetric_axis(-0.2, 0.24, _GRID_STEP)
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    sdf = _primitive_sdf(prims[0], grid)
    for p in prims[1:]:
        sdf = _smooth_min(sdf, _primitive_sdf(p, grid), _BLEND)
    vol = sdf.reshape(len(xs), len(ys), len(zs))
    vol = 0.5 * (vol + vol[::-1])  # exact mirror symmetry of the sampled field
    # Keep samples off the iso-level so that marching cubes never emits coincident vertices.
    vol = np.where(np.abs(vol) < 1e-4, 1e-4, vol)
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(_GRID_STEP,) * 3, method="lorensen")
    verts = verts.astype(np.float64) + np.array([xs[0], ys[0], zs[0]])
    faces = faces.astype(np.int64)
    # Make the winding outward (positive signed volume).
    tri = verts[faces]
    signed_volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    if signed_volume < 0:
        faces = faces[:, ::-1].copy()
    return verts, faces


def _mirror_permutation(verts: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Index of each vertex's mirror partner (x -> -x), (V,) int64; raises if the mesh is not symmetric."""
    tree = cKDTree(verts)
    dist, idx = tree.query(verts * _MIRROR)
    if dist.max() > tol or not np.array_equal(idx[idx], np.arange(len(verts))):
        raise RuntimeError("Built-in body mesh is not mirror-symmetric; the generator is broken.")
    return idx.astype(np.int64)


def _symmetrize_vertices(v: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Exactly mirror-symmetric copy of per-vertex vectors ``v`` (V, 3, ...): v[perm] * (-1, 1, 1) == v."""
    m = _MIRROR.reshape((1, 3) + (1,) * (v.ndim - 2))
    return 0.5 * (v + v[perm] * m)


def _adjacency(faces: np.ndarray, n: int) -> scipy.sparse.csr_matrix:
    """Row-normalised vertex adjacency of a triangle mesh, (n, n) sparse."""
    i = faces[:, [0, 1, 2, 1, 2, 0]].ravel()
    j = faces[:, [1, 2, 0, 0, 1, 2]].ravel()
    adj = scipy.sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    adj.data[:] = 1.0
    deg = np.asarray(adj.sum(axis=1)).ravel()
    return scipy.sparse.diags(1.0 / deg) @ adj


# ----------------------------------------------------------------------------------------------
# Skinning weights and joint regressor
# ----------------------------------------------------------------------------------------------


def _skinning_weights(
    verts_design: np.ndarray, faces: np.ndarray, perm: np.ndarray, temperature: float = 0.012, iters: int = 12
) -> np.ndarray:
    """Smooth skinning weights, (V, 24), rows convex, mirror-symmetric.

    Softmax over joints of minus the signed distance to the joint's solids (a vertex is dominated by
    the part it lies on), then ``iters`` steps of Laplacian smoothing over the mesh graph.
    """
    n = len(verts_design)
    dist = np.full((n, NUM_JOINTS), np.inf)
    for p in _all_primitives():
        j = JOINT_INDEX[p.joint]
        dist[:, j] = np.minimum(dist[:, j], _primitive_sdf(p, verts_design))
    logits = -(dist - dist.min(axis=1, keepdims=True)) / temperature
    w = np.exp(logits)
    w /= w.sum(axis=1, keepdims=True)
    lap = _adjacency(faces, n)
    for _ in range(iters):
        w = 0.5 * w + 0.5 * (lap @ w)
    w = 0.5 * (w + w[perm][:, list(LEFT_RIGHT)])
    w[w < 1e-6] = 0.0
    return w / w.sum(axis=1, keepdims=True)


def _fit_regressor(verts: np.ndarray, targets: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Convex vertex averages that reproduce ``targets``, (24, V) float64, mirror-symmetric.

    Each row is half a uniform average of the vertices nearest the joint and half a non-negative
    least-squares solution that moves that average exactly onto the target (sum-to-one enforced
    by a heavily weighted row).
    """
    from scipy.optimize import nnls  # only when the body is generated (once; then cached): not on every start

    n = len(verts)
    tree = cKDTree(verts)
    reg = np.zeros((NUM_JOINTS, n))
    for j, t in enumerate(targets):
        for k in (24, 40, 64, 96, 160, 256):
            _, idx = tree.query(t, k=k)
            idx = np.sort(idx)
            prior = verts[idx].mean(axis=0)
            alpha = 0.5
            goal = (t - (1.0 - alpha) * prior) / alpha
            a = np.vstack([verts[idx].T, 1e3 * np.ones((1, k))])
            u, _ = nnls(a, np.append(goal, 1e3))
            u /= u.sum()
            row = (1.0 - alpha) / k + alpha * u
            if np.abs(row @ verts[idx] - t).max() < 2e-4:
                break
        else:
            raise RuntimeError(f"Could not fit the built-in regressor for joint {j}.")
        reg[j, idx] = row
    reg = 0.5 * (reg + reg[list(LEFT_RIGHT)][:, perm])
    return reg


# ----------------------------------------------------------------------------------------------
# Shape fields
# ----------------------------------------------------------------------------------------------


def _smoothstep(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """0 below ``lo``, 1 above ``hi``, C1 cubic in between."""
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _bone_segments(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis segment of each joint's body part, (24, 3) starts and (24, 3) ends."""
    ji = JOINT_INDEX
    child = {j: -1 for j in range(NUM_JOINTS)}
    for j, p in enumerate(PARENTS):
        if p >= 0 and child[p] < 0:
            child[p] = j
    child[ji["pelvis"]] = ji["spine1"]
    child[ji["spine3"]] = ji["neck"]
    start = joints.copy()
    end = np.empty_like(joints)
    for j in range(NUM_JOINTS):
        end[j] = joints[child[j]] if child[j] >= 0 else joints[j]
    end[ji["head"]] = joints[ji["head"]] + np.array([0.0, 0.12, 0.0])
    for side in ("left_", "right_"):
        hand, wrist = ji[side + "hand"], ji[side + "wrist"]
        end[hand] = joints[hand] + (joints[hand] - joints[wrist])
        end[ji[side + "foot"]] = joints[ji[side + "foot"]] + np.array([0.0, 0.0, 0.08])
    return start, end


def _project_to_segments(v: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Closest point of every segment to every vertex, (V, 24, 3)."""
    d = end - start
    dd = np.maximum((d * d).sum(-1), 1e-12)
    t = np.clip(np.einsum("vjc,jc->vj", v[:, None] - start[None], d) / dd, 0.0, 1.0)
    return start[None] + t[..., None] * d[None]


def _shape_fields(v: np.ndarray, joints: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The 10 shape directions (displacement per unit beta) at a template, (V, 3, 10).

    Args:
        v: template vertices (V, 3), soles at y = 0, symmetric about x = 0.
        joints: its rest joints (24, 3).
        w: skinning weights (V, 24).
    """
    ji = JOINT_INDEX
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    stature = y.max() - y.min()
    out = np.zeros(v.shape + (NUM_BETAS,))

    # 0 stature: uniform scale about the floor point (0, 0, 0).
    out[..., 0] = v * (0.07 / stature)

    # 1 mass: radial growth away from each part's bone axis.
    start, end = _bone_segments(joints)
    radial = v[:, None] - _project_to_segments(v, start, end)  # (V, 24, 3)
    gain = np.ones(NUM_JOINTS)
    part_gain = {
        "head": 0.2,
        "neck": 0.6,
        "left_hand": 0.4,
        "left_wrist": 0.6,
        "left_foot": 0.2,
        "left_ankle": 0.3,
    }
    for name, g in part_gain.items():
        gain[ji[name]] = g
        gain[LEFT_RIGHT[ji[name]]] = g
    mass = 0.06 * np.einsum("vj,vjc->vc", w * gain, radial)
    mass[:, 1] *= _smoothstep(y, 0.0, 0.08)  # keep the soles on the floor
    out[..., 1] = mass

    # 2 leg-to-torso ratio: legs longer by delta, upper body compressed by delta (top fixed).
    delta = 0.02
    y_hip = joints[ji["left_hip"], 1]
    top = y.max()
    out[:, 1, 2] = np.where(y <= y_hip, delta * y / y_hip, delta * (top - y) / (top - y_hip))

    # 3 arm length: stretch along x beyond the shoulder joint, on the arms only.
    arm = sum(w[:, ji[s + p]] for s in ("left_", "right_") for p in ("shoulder", "elbow", "wrist", "hand"))
    x_sh = joints[ji["left_shoulder"], 0]
    out[:, 0, 3] = 0.04 * np.sign(x) * np.maximum(np.abs(x) - x_sh, 0.0) * arm

    # 4 shoulder width: upper body and arms move outwards (head excluded).
    upper = _smoothstep(y, joints[ji["spine2"], 1], joints[ji["left_collar"], 1]) * (1.0 - w[:, ji["head"]])
    out[:, 0, 4] = 0.012 * np.clip(x / x_sh, -1.0, 1.0) * upper

    # 5 hip width: pelvis widens and the legs move outwards.
    lower = 1.0 - _smoothstep(y, joints[ji["pelvis"], 1], joints[ji["spine2"], 1])
    x_hip = joints[ji["left_hip"], 0]
    out[:, 0, 5] = 0.01 * np.clip(x / x_hip, -1.0, 1.0) * lower

    # 6 chest depth: front-to-back growth of the chest about the spine.
    chest = w[:, ji["spine2"]] + w[:, ji["spine3"]]
    out[:, 2, 6] = 0.06 * (z - joints[ji["spine2"], 2]) * chest

    # 7 waist girth: radial growth of the torso around the waist.
    torso = sum(w[:, ji[n]] for n in ("pelvis", "spine1", "spine2", "spine3"))
    y_waist = joints[ji["spine1"], 1]
    sigma = 0.09 * stature / 1.7
    band = np.exp(-(((y - y_waist) / sigma) ** 2)) * torso * 0.07
    out[:, 0, 7] = x * band
    out[:, 2, 7] = (z - joints[ji["spine1"], 2]) * band

    # 8 head size: scale about the head joint.
    out[..., 8] = 0.05 * (v - joints[ji["head"]]) * w[:, ji["head"], None]

    # 9 neck length: everything above the neck moves up, blending in over the neck.
    out[:, 1, 9] = 0.01 * _smoothstep(y, joints[ji["neck"], 1], joints[ji["head"], 1])
    return out


_GENDER_BETAS: dict[Gender, tuple[float, ...]] = {
    # stature is set afterwards by rescaling; these give the gender's proportions.
    Gender.NEUTRAL: (0.0,) * NUM_BETAS,
    Gender.MALE: (0.0, 0.3, -0.3, 0.3, 1.6, -0.8, 0.6, 0.2, 0.2, 0.5),
    Gender.FEMALE: (0.0, -0.3, 0.3, -0.4, -1.6, 1.4, 0.3, -1.0, -0.3, 0.0),
}


# ----------------------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Neutral:
    v: np.ndarray  # (V, 3)
    f: np.ndarray  # (F, 3)
    perm: np.ndarray  # (V,)
    weights: np.ndarray  # (V, 24)
    regressor: np.ndarray  # (24, V)


@lru_cache(maxsize=1)
def _neutral() -> _Neutral:
    """The neutral mesh, weights and regressor shared by all genders (computed once per process)."""
    import trimesh

    verts, faces = _build_neutral_mesh()
    perm = _mirror_permutation(verts)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53, iterations=8)
    design = _symmetrize_vertices(np.asarray(mesh.vertices, dtype=np.float64), perm)
    weights = _skinning_weights(design, faces, perm)

    floor = design[:, 1].min()
    scale = STATURE_M[Gender.NEUTRAL] / (design[:, 1].max() - floor)
    offset = np.array([0.0, -floor, 0.0])
    v = _symmetrize_vertices((design + offset) * scale, perm)
    targets = (_design_joints() + offset) * scale
    regressor = _fit_regressor(v, targets, perm)
    for a in (v, faces, perm, weights, regressor):
        a.flags.writeable = False
    return _Neutral(v=v, f=faces, perm=perm, weights=weights, regressor=regressor)


def generate_builtin_model(gender: Gender | str) -> dict[str, np.ndarray]:
    """Generate the built-in body model of ``gender`` in SMPL's array layout (deterministic).

    Returns:
        ``v_template`` (V, 3) float64, ``shapedirs`` (V, 3, 10) float64, ``posedirs`` (V, 3, 207)
        float64 (zeros: no pose correctives), ``J_regressor`` (24, V) float64 dense with convex rows,
        ``weights`` (V, 24) float64 with convex rows, ``kintree_table`` (2, 24) int64 (row 0 the
        parents, root entry 4294967295 as in SMPL files; row 1 ``arange(24)``), ``f`` (F, 3) int64
        and ``gender`` a 0-d str array.
    """
    g = Gender.parse(gender)
    base = _neutral()
    v = base.v
    joints = base.regressor @ v
    if g is not Gender.NEUTRAL:
        dirs = _shape_fields(v, joints, base.weights)
        v = v + dirs @ np.asarray(_GENDER_BETAS[g])
        v = v * (STATURE_M[g] / (v[:, 1].max() - v[:, 1].min()))  # the floor stays at y = 0
        v = _symmetrize_vertices(v, base.perm)
        joints = base.regressor @ v
    shapedirs = _symmetrize_vertices(_shape_fields(v, joints, base.weights), base.perm)
    kintree = np.stack([np.array(PARENTS, dtype=np.int64), np.arange(NUM_JOINTS, dtype=np.int64)])
    kintree[0, 0] = _ROOT_PARENT
    return {
        "v_template": np.array(v, dtype=np.float64),
        "shapedirs": np.ascontiguousarray(shapedirs, dtype=np.float64),
        "posedirs": np.zeros((len(v), 3, 9 * (NUM_JOINTS - 1)), dtype=np.float64),
        "J_regressor": np.array(base.regressor, dtype=np.float64),
        "weights": np.array(base.weights, dtype=np.float64),
        "kintree_table": kintree,
        "f": np.array(base.f, dtype=np.int64),
        "gender": np.array(g.value),
    }


def builtin_cache_dir(cache_dir: str | Path | None = None) -> Path:
    """Folder of the built-in model files.

    ``<cache_dir or smplik.paths.cache_dir()>/builtin-<BUILTIN_VERSION>-<source hash>``:
    the hash of this module's source keys the cache, so an edited generator never reuses stale files.
    """
    return default_cache_dir(cache_dir) / f"builtin-{BUILTIN_VERSION}-{_source_hash()}"


@lru_cache(maxsize=1)
def _source_hash() -> str:
    return hashlib.sha1(Path(__file__).read_bytes()).hexdigest()[:10]


def builtin_model_path(gender: Gender | str, cache_dir: str | Path | None = None) -> Path:
    """Path of ``SMPL_{NEUTRAL,MALE,FEMALE}.npz`` for the built-in model, generating it on first use.

    The file goes into ``cache_dir`` or :func:`smplik.paths.cache_dir` (``$SMPLIK_CACHE_DIR``), under a
    sub-folder ``builtin-{BUILTIN_VERSION}``. It is written atomically (a temporary file in the same
    folder, then :func:`os.replace`, via :func:`smplik.atomic.write_npz_deterministic`), so a crash never
    leaves a half-written file.
    """
    g = Gender.parse(gender)
    folder = builtin_cache_dir(cache_dir)
    path = folder / _FILE_NAMES[g]
    if path.is_file():
        return path
    return write_npz_deterministic(path, generate_builtin_model(g), compressed=False)
