"""Randomized-effector benchmark (ProtoRes section 3.2 and App. E; SMPL-IK F.2): files, metrics, baselines.

Benchmark files (:func:`make_benchmark`, format :data:`BENCHMARK_VERSION`)
--------------------------------------------------------------------------
Built once from one split of a pose cache with a stored seed, into a folder holding
``manifest.json`` and one ``.npz`` per set:

* ``random_06`` ... ``random_12``: N = 6..12 effectors per pose. Joints are grouped in
  :data:`ZONES` (pelvis/hips, torso/head, left arm, right arm, left leg, right leg). The first
  four effectors are one position effector on a random joint of each limb zone
  (:data:`LIMB_ZONES`); each further effector takes a random zone, a random joint in it and a
  random type (position, rotation, look-at), redrawn until its (joint, type) pair is new.
* ``fixed_5pt`` (spine3, wrists, ankles) and ``fixed_6pt`` (pelvis, neck, wrists, ankles):
  position effectors only.

Every set draws its own frames (without replacement when the split is large enough), and per
sample a body ``beta ~ N(0, I)`` and a gender uniform over neutral/male/female; the frame's
local rotations and translation are kept (no augmentation) and the joints recomputed by FK on
that body. Effectors are exact (tolerance 0, no noise): positions are the joints' world positions,
rotations their global rotations (stored as 6D), look-at targets lie at a distance
``0.1 + 2 |N(0, 1)|`` m along a random unit direction in the joint's frame (as in training). Set
``i`` uses ``numpy.random.default_rng([seed, i])``; the ``.npz`` files are written with sorted
keys and fixed zip timestamps, so the same seed, cache and body models give identical bytes.

``.npz`` keys (S samples, N effectors): ``R_local (S, 24, 3, 3)``, ``transl (S, 3)``,
``betas (S, 10)``, ``gender (S,)`` (:class:`Gender` index), ``joints (S, 24, 3)``, ``frame (S,)``
(row in the split), ``eff_joint (S, N)``, ``eff_type (S, N)``, ``eff_data (S, N, 6)`` (packed as in
:mod:`smplik.effectors`), ``eff_tolerance (S, N)``; floats are float32.

Metrics (:func:`evaluate_prediction`)
-------------------------------------
MPJPE and PA-MPJPE (mm, 24 joints), mean geodesic error of the local rotations (rad),
position-effector residual (mm), rotation-effector residual (degrees, global rotation) and
look-at error (degrees between the joint's rotated direction and the ray to the target), each
averaged over all effectors of that type in the set (None when the set has none), and the
wall time per pose (ms; the method runs on the whole set in batches).

Methods
-------
* :class:`LearnedMethod`: the SMPL-IK solver (:meth:`IKSolver.solve_tensors`): ``smplik`` is its
  default (network, then three Levenberg-Marquardt refinement steps anchored to the network's pose,
  :mod:`smplik.refine`), ``smplik_net`` the network's pose alone.
* :class:`OptimizationIK`: batched Adam over local 6D rotations and the root translation, our FK
  with ``J(beta, gender)``, on the same effector losses plus a pose prior: a diagonal Gaussian
  over the 6D local rotations of joints 1..23 fitted to the train split (:class:`PosePrior`); the
  root is free. Initialised at the rest pose, root rotation and translation by a Kabsch fit of
  the rest joints to the position effectors; a fixed iteration count.
* :class:`NearestNeighborMethod`: scikit-learn ``NearestNeighbors`` over a subsample of the train
  split. Features are the position-effector joints of each train pose (neutral body, beta = 0)
  minus their centroid (translation invariant); an index is built per distinct set of position-
  effector joints. Rotation and look-at effectors are ignored. The neighbour's local rotations are
  put on the query body and translated so that its effector-joint centroid matches the query's.
* :class:`RestPoseMethod`: the rest (T) pose, translated so that its position-effector joints'
  centroid matches the targets' centroid.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.atomic import atomic_path, write_json_atomic, write_npz_deterministic
from smplik.body_model import BodyModelSet
from smplik.conventions import JOINT_INDEX, NUM_BETAS, NUM_JOINTS, EffectorType, Gender
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.metrics import local_geodesic, mpjpe, pa_mpjpe
from smplik.refine import RefineConfig
from smplik.rotations import axis_angle_to_matrix, geodesic_distance, matrix_to_rot6d, rot6d_to_matrix

BENCHMARK_FORMAT = "smplik-benchmark"
BENCHMARK_VERSION = 1
RESULTS_FORMAT = "smplik-benchmark-results"
RESULTS_VERSION = 1
MANIFEST = "manifest.json"

ZONES: dict[str, tuple[str, ...]] = {
    "pelvis_hips": ("pelvis", "left_hip", "right_hip"),
    "torso_head": ("spine1", "spine2", "spine3", "neck", "head"),
    "left_arm": ("left_collar", "left_shoulder", "left_elbow", "left_wrist", "left_hand"),
    "right_arm": ("right_collar", "right_shoulder", "right_elbow", "right_wrist", "right_hand"),
    "left_leg": ("left_knee", "left_ankle", "left_foot"),
    "right_leg": ("right_knee", "right_ankle", "right_foot"),
}
"""Joint zones of the random sets (every SMPL joint is in exactly one)."""
LIMB_ZONES = ("left_arm", "right_arm", "left_leg", "right_leg")
RANDOM_COUNTS = tuple(range(6, 13))
FIXED_SETS: dict[str, tuple[str, ...]] = {
    "fixed_5pt": ("spine3", "left_wrist", "right_wrist", "left_ankle", "right_ankle"),
    "fixed_6pt": ("pelvis", "neck", "left_wrist", "right_wrist", "left_ankle", "right_ankle"),
}
LOOKAT_DISTANCE_STD = 2.0


def set_names() -> list[str]:
    """Set names in file order: random_06..random_12, then the fixed sets."""
    return [f"random_{n:02d}" for n in RANDOM_COUNTS] + list(FIXED_SETS)


# ----------------------------------------------------------------------------- deterministic files


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ----------------------------------------------------------------------------- making the files


def _sample_effector_layout(rng: np.random.Generator, num: int) -> tuple[np.ndarray, np.ndarray]:
    """One random set's (joint, type) pairs: a position per limb zone, then random zone/type. -> (N,), (N,)."""
    zones = list(ZONES)
    pairs: list[tuple[int, int]] = []
    for zone in LIMB_ZONES:
        names = ZONES[zone]
        pairs.append((JOINT_INDEX[names[rng.integers(len(names))]], int(EffectorType.POSITION)))
    while len(pairs) < num:
        names = ZONES[zones[rng.integers(len(zones))]]
        pair = (JOINT_INDEX[names[rng.integers(len(names))]], int(rng.integers(3)))
        if pair not in pairs:
            pairs.append(pair)
    arr = np.array(pairs, dtype=np.int64)
    return arr[:, 0], arr[:, 1]


def _effector_data(rng: np.random.Generator, joint: np.ndarray, kind: np.ndarray, R_world: np.ndarray,
                   p_world: np.ndarray) -> np.ndarray:
    """Exact effector data (S, N, 6) from ground truth. joint/kind (S, N); R_world (S, 24, 3, 3); p_world (S, 24, 3)."""
    S, N = joint.shape
    rows = np.arange(S)[:, None]
    pos = p_world[rows, joint]  # (S, N, 3)
    rot = R_world[rows, joint]  # (S, N, 3, 3)
    d_local = rng.standard_normal((S, N, 3))
    d_local /= np.linalg.norm(d_local, axis=-1, keepdims=True)
    dist = 0.1 + LOOKAT_DISTANCE_STD * np.abs(rng.standard_normal((S, N, 1)))
    target = pos + dist * np.einsum("snij,snj->sni", rot, d_local)
    data = np.zeros((S, N, 6))
    is_pos, is_rot, is_look = (kind == 0), (kind == 1), (kind == 2)
    data[is_pos, :3] = pos[is_pos]
    data[is_rot] = np.concatenate([rot[is_rot][..., :, 0], rot[is_rot][..., :, 1]], axis=-1)
    data[is_look] = np.concatenate([target[is_look], d_local[is_look]], axis=-1)
    return data


def make_benchmark(data: str | Path, out: str | Path, *, split: str = "test", seed: int = 0,
                   samples_per_count: int = 500, model_dir: str | Path | None = None) -> Path:
    """Write the benchmark files (see the module docstring) into ``out``; returns the manifest path.

    Raises:
        ValueError: unknown split, empty split, or a non-positive sample count.
    """
    from smplik.data.dataset import load_cache

    if samples_per_count < 1:
        raise ValueError(f"samples_per_count must be positive, got {samples_per_count}.")
    dataset = load_cache(data).subset(split)
    if len(dataset) == 0:
        raise ValueError(f"{data}: the {split!r} split is empty.")
    bodies = BodyModelSet.load(model_dir)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pose_all = dataset.pose.double()
    transl_all = dataset.transl.double()
    S = samples_per_count
    entries = []
    for set_index, name in enumerate(set_names()):
        rng = np.random.default_rng([seed, set_index])
        frame = rng.choice(len(dataset), size=S, replace=S > len(dataset))
        betas = rng.standard_normal((S, NUM_BETAS))
        gender = rng.integers(0, len(Gender), size=S)
        R_local = axis_angle_to_matrix(pose_all[torch.from_numpy(frame)])
        transl = transl_all[torch.from_numpy(frame)]
        J_rest = bodies.rest_joints(torch.from_numpy(betas), torch.from_numpy(gender))
        R_world, p_world = forward_kinematics(R_local, J_rest, transl)
        if name.startswith("random_"):
            num = int(name.split("_")[1])
            layouts = [_sample_effector_layout(rng, num) for _ in range(S)]
            joint = np.stack([j for j, _ in layouts])
            kind = np.stack([k for _, k in layouts])
            fixed: list[str] | None = None
        else:
            fixed = list(FIXED_SETS[name])
            joint = np.tile([JOINT_INDEX[j] for j in fixed], (S, 1))
            kind = np.zeros_like(joint)
        eff_data = _effector_data(rng, joint, kind, R_world.numpy(), p_world.numpy())
        arrays = {
            "R_local": R_local.numpy().astype(np.float32),
            "transl": transl.numpy().astype(np.float32),
            "betas": betas.astype(np.float32),
            "gender": gender.astype(np.int8),
            "joints": p_world.numpy().astype(np.float32),
            "frame": frame.astype(np.int64),
            "eff_joint": joint.astype(np.int16),
            "eff_type": kind.astype(np.int8),
            "eff_data": eff_data.astype(np.float32),
            "eff_tolerance": np.zeros(joint.shape, np.float32),
        }
        path = write_npz_deterministic(out / f"{name}.npz", arrays)
        entries.append({"name": name, "file": path.name, "kind": "random" if fixed is None else "fixed",
                        "num_effectors": int(joint.shape[1]), "samples": S, "joints": fixed,
                        "sha256": _sha256(path)})
    manifest = {
        "format": BENCHMARK_FORMAT,
        "version": BENCHMARK_VERSION,
        "seed": int(seed),
        "source": {"data": str(data), "split": split, "frames_in_split": len(dataset)},
        "samples_per_count": S,
        "body_fingerprint": bodies.fingerprint,
        "zones": {k: list(v) for k, v in ZONES.items()},
        "limb_zones": list(LIMB_ZONES),
        "lookat_distance": f"0.1 + {LOOKAT_DISTANCE_STD} * |N(0, 1)| m",
        "sets": entries,
    }
    path = out / MANIFEST
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    return path


# ----------------------------------------------------------------------------- loading


@dataclass(frozen=True)
class BenchmarkSet:
    """One benchmark set (float32 tensors). S samples of N effectors.

    Attributes:
        name, kind ("random" | "fixed"), num_effectors.
        R_local (S, 24, 3, 3), transl (S, 3), betas (S, 10), gender (S,) long, joints (S, 24, 3): ground truth.
        effectors: the packed effectors (S rows of N, no padding).
    """

    name: str
    kind: str
    num_effectors: int
    R_local: Tensor
    transl: Tensor
    betas: Tensor
    gender: Tensor
    joints: Tensor
    effectors: EffectorBatch

    def __len__(self) -> int:
        return int(self.R_local.shape[0])

    def head(self, n: int) -> BenchmarkSet:
        """The first ``n`` samples."""
        e = self.effectors
        return BenchmarkSet(self.name, self.kind, self.num_effectors, self.R_local[:n], self.transl[:n],
                            self.betas[:n], self.gender[:n], self.joints[:n],
                            EffectorBatch(e.joint[:n], e.type[:n], e.data[:n], e.tolerance[:n], e.mask[:n]))


@dataclass(frozen=True)
class Benchmark:
    """Loaded benchmark files: the manifest and the sets in manifest order."""

    manifest: dict[str, Any]
    sets: tuple[BenchmarkSet, ...]
    folder: str


def load_benchmark(folder: str | Path, *, verify: bool = True) -> Benchmark:
    """Read a benchmark folder. ``verify`` checks each file's SHA-256 against the manifest.

    Raises:
        FileNotFoundError: no manifest. ValueError: another format or version, a modified file.
    """
    folder = Path(folder)
    mpath = folder / MANIFEST
    if not mpath.is_file():
        raise FileNotFoundError(f"No {MANIFEST} in {folder}; create the files with `smplik benchmark make`.")
    manifest = json.loads(mpath.read_text())
    if manifest.get("format") != BENCHMARK_FORMAT:
        raise ValueError(f"{mpath}: not an smplik benchmark manifest.")
    if manifest.get("version") != BENCHMARK_VERSION:
        raise ValueError(f"{mpath}: benchmark version {manifest.get('version')}, this smplik reads "
                         f"{BENCHMARK_VERSION}; re-create the files with `smplik benchmark make`.")
    sets = []
    for entry in manifest["sets"]:
        path = folder / entry["file"]
        if verify and _sha256(path) != entry["sha256"]:
            raise ValueError(f"{path}: content differs from the manifest's SHA-256 (modified file?).")
        with np.load(path, allow_pickle=False) as npz:
            a = {k: torch.from_numpy(npz[k]) for k in npz.files}
        S, N = a["eff_joint"].shape
        eff = EffectorBatch(a["eff_joint"].long(), a["eff_type"].long(), a["eff_data"].float(),
                            a["eff_tolerance"].float(), torch.ones(S, N, dtype=torch.bool))
        sets.append(BenchmarkSet(entry["name"], entry["kind"], N, a["R_local"].float(), a["transl"].float(),
                                 a["betas"].float(), a["gender"].long(), a["joints"].float(), eff))
    return Benchmark(manifest, tuple(sets), str(folder))


# ----------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class Prediction:
    """A method's output on a set: R_local (S, 24, 3, 3) local rotations, transl (S, 3) smplx translation."""

    R_local: Tensor
    transl: Tensor


@dataclass(frozen=True)
class SetMetrics:
    """Metrics of one method on one set (see the module docstring; None: no effector of that type)."""

    mpjpe_mm: float
    pa_mpjpe_mm: float
    geodesic_rad: float
    position_residual_mm: float | None
    rotation_residual_deg: float | None
    lookat_error_deg: float | None
    time_ms_per_pose: float
    samples: int

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def effector_errors(eff: EffectorBatch, R_world: Tensor, p_world: Tensor) -> dict[str, Tensor]:
    """Per-effector errors, flattened over the effectors of each type.

    Args: eff (S rows of N); R_world (S, 24, 3, 3); p_world (S, 24, 3).
    Returns: ``position`` (metres), ``rotation`` (radians), ``look_at`` (radians), 1-D tensors.
    """
    rows = torch.arange(eff.joint.shape[0])[:, None]
    p = p_world[rows, eff.joint]  # (S, N, 3)
    R = R_world[rows, eff.joint]  # (S, N, 3, 3)
    out = {}
    sel = eff.mask & (eff.type == int(EffectorType.POSITION))
    out["position"] = (p - eff.data[..., :3]).norm(dim=-1)[sel]
    sel = eff.mask & (eff.type == int(EffectorType.ROTATION))
    out["rotation"] = geodesic_distance(R[sel], rot6d_to_matrix(eff.data[sel]))
    sel = eff.mask & (eff.type == int(EffectorType.LOOK_AT))
    axis = (R[sel] @ eff.data[sel][:, 3:, None])[..., 0]
    ray = eff.data[sel][:, :3] - p[sel]
    cos = torch.nn.functional.cosine_similarity(axis, ray, dim=-1).clamp(-1.0, 1.0)
    out["look_at"] = torch.acos(cos)
    return out


def evaluate_prediction(bset: BenchmarkSet, pred: Prediction, bodies: BodyModelSet,
                        seconds: float = float("nan")) -> SetMetrics:
    """Metrics of ``pred`` on ``bset``; joints by our FK on the set's bodies."""
    J_rest = bodies.rest_joints(bset.betas, bset.gender)
    R_world, p_world = forward_kinematics(pred.R_local.float(), J_rest, pred.transl.float())
    err = effector_errors(bset.effectors, R_world, p_world)

    def mean_or_none(x: Tensor, scale: float) -> float | None:
        return float(x.mean() * scale) if x.numel() else None

    return SetMetrics(
        mpjpe_mm=float(mpjpe(p_world, bset.joints).mean() * 1000),
        pa_mpjpe_mm=float(pa_mpjpe(p_world.double(), bset.joints.double()).mean() * 1000),
        geodesic_rad=float(local_geodesic(pred.R_local.float(), bset.R_local).mean()),
        position_residual_mm=mean_or_none(err["position"], 1000.0),
        rotation_residual_deg=mean_or_none(err["rotation"], 180.0 / math.pi),
        lookat_error_deg=mean_or_none(err["look_at"], 180.0 / math.pi),
        time_ms_per_pose=seconds * 1000.0 / max(len(bset), 1),
        samples=len(bset),
    )


# ----------------------------------------------------------------------------- methods

Method = Callable[[BenchmarkSet], Prediction]
"""A method maps a set to a prediction; it may use the effectors, betas and gender (not the ground truth)."""


def _position_targets(eff: EffectorBatch) -> tuple[Tensor, Tensor]:
    """Position-effector weights (S, N) (1 for real position effectors) and the targets (S, N, 3)."""
    w = (eff.mask & (eff.type == int(EffectorType.POSITION))).float()
    return w, eff.data[..., :3]


def _rest_transl_to_centroid(eff: EffectorBatch, J_rest: Tensor, R_root: Tensor | None = None) -> Tensor:
    """smplx transl placing the posed (root rotation only) effector-joint centroid on the targets' centroid."""
    w, target = _position_targets(eff)
    rows = torch.arange(J_rest.shape[0])[:, None]
    P = J_rest[rows, eff.joint]  # (S, N, 3) rest positions of the effector joints
    wsum = w.sum(1, keepdim=True).clamp_min(1.0)
    P_bar = (P * w[..., None]).sum(1) / wsum
    T_bar = (target * w[..., None]).sum(1) / wsum
    J0 = J_rest[:, 0]
    rel = P_bar - J0
    if R_root is not None:
        rel = (R_root @ rel[..., None])[..., 0]
    return T_bar - J0 - rel


@dataclass(frozen=True)
class RestPoseMethod:
    """The rest pose (all local rotations identity) at the position effectors' centroid."""

    bodies: BodyModelSet

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        J_rest = self.bodies.rest_joints(bset.betas, bset.gender)
        R = torch.eye(3).expand(len(bset), NUM_JOINTS, 3, 3).clone()
        return Prediction(R, _rest_transl_to_centroid(bset.effectors, J_rest))


@dataclass(frozen=True)
class LearnedMethod:
    """SMPL-IK: the solver's local rotations and translation, in batches of ``batch_size``.

    ``refine`` overrides the solver's refinement; None keeps it.
    """

    solver: Any  # smplik.solver.IKSolver (not imported here: keeps this module free of the solver)
    batch_size: int = 1024
    refine: RefineConfig | None = None

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        Rs, ts = [], []
        e = bset.effectors
        for s in range(0, len(bset), self.batch_size):
            sl = slice(s, s + self.batch_size)
            chunk = EffectorBatch(e.joint[sl], e.type[sl], e.data[sl], e.tolerance[sl], e.mask[sl])
            out = self.solver.solve_tensors(chunk, bset.betas[sl], bset.gender[sl], refine=self.refine)
            Rs.append(out.R_local)
            ts.append(out.transl)
        return Prediction(torch.cat(Rs), torch.cat(ts))


@dataclass(frozen=True)
class PosePrior:
    """Diagonal Gaussian over the 6D local rotations: mean (24, 6), std (24, 6) (joint 0 unused)."""

    mean: Tensor
    std: Tensor

    @classmethod
    def fit(cls, pose_axis_angle: Tensor, min_std: float = 0.02) -> PosePrior:
        """Fit to local rotations (M, 24, 3) axis-angle (e.g. a train split's ``pose``)."""
        x = matrix_to_rot6d(axis_angle_to_matrix(pose_axis_angle.double()))
        return cls(x.mean(0).float(), x.std(0).clamp_min(min_std).float())

    def nll(self, rot6d: Tensor) -> Tensor:
        """0.5 * squared Mahalanobis distance over joints 1..23. rot6d (S, 24, 6) -> (S,)."""
        z = (rot6d[:, 1:] - self.mean[1:]) / self.std[1:]
        return 0.5 * z.square().sum((-1, -2))


def kabsch_rotation(P: Tensor, T: Tensor, w: Tensor) -> Tensor:
    """Weighted rotation R minimising sum w |R (P - P_bar) - (T - T_bar)|^2. P, T (S, N, 3), w (S, N) -> (S, 3, 3)."""
    wsum = w.sum(1, keepdim=True).clamp_min(1e-9)
    Pc = P - (P * w[..., None]).sum(1, keepdim=True) / wsum[..., None]
    Tc = T - (T * w[..., None]).sum(1, keepdim=True) / wsum[..., None]
    H = (Pc * w[..., None]).transpose(1, 2) @ Tc  # (S, 3, 3)
    U, _, Vh = torch.linalg.svd(H)
    d = torch.sign(torch.linalg.det(Vh.transpose(1, 2) @ U.transpose(1, 2)))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return Vh.transpose(1, 2) @ D @ U.transpose(1, 2)


@dataclass(frozen=True)
class OptimizationIK:
    """Gradient-based IK on SMPL: Adam over local 6D rotations + root translation (module docstring).

    Loss per pose: ``sum_pos |p - t|^2 / sigma_pos^2 + sum_rot |R - R*|_F^2 / sigma_rot^2 +
    sum_lookat (1 - cos) / sigma_lookat^2 + prior_weight * prior.nll``.
    """

    bodies: BodyModelSet
    prior: PosePrior
    iterations: int = 200
    lr: float = 0.1
    sigma_pos: float = 0.01
    """metres."""
    sigma_rot: float = 0.1
    """Frobenius norm (about radians x sqrt 2)."""
    sigma_lookat: float = 0.05
    """on 1 - cos (about 0.3 rad)."""
    prior_weight: float = 3.0
    """Defaults (iterations, lr, sigmas, prior weight) were chosen on validation-split benchmark files."""

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        eff = bset.effectors
        S = len(bset)
        J_rest = self.bodies.rest_joints(bset.betas, bset.gender)
        rows = torch.arange(S)[:, None]
        w_pos, target = _position_targets(eff)
        R0 = kabsch_rotation(J_rest[rows, eff.joint], target, w_pos)
        x = matrix_to_rot6d(torch.eye(3)).expand(S, NUM_JOINTS, 6).clone()
        x[:, 0] = matrix_to_rot6d(R0)
        transl = _rest_transl_to_centroid(eff, J_rest, R0).clone()
        x.requires_grad_(True)
        transl.requires_grad_(True)
        w_rot = (eff.mask & (eff.type == int(EffectorType.ROTATION))).float()
        w_look = (eff.mask & (eff.type == int(EffectorType.LOOK_AT))).float()
        R_target = rot6d_to_matrix(torch.where(w_rot.bool()[..., None], eff.data,
                                               torch.tensor([1.0, 0, 0, 0, 1.0, 0])))
        look_target, look_dir = eff.data[..., :3], eff.data[..., 3:]
        opt = torch.optim.Adam([x, transl], lr=self.lr)
        with torch.enable_grad():
            for _ in range(self.iterations):
                opt.zero_grad(set_to_none=True)
                R_local = rot6d_to_matrix(x)
                R_world, p_world = forward_kinematics(R_local, J_rest, transl)
                p = p_world[rows, eff.joint]
                R = R_world[rows, eff.joint]
                loss_pos = ((p - target).square().sum(-1) * w_pos).sum(1) / self.sigma_pos ** 2
                loss_rot = ((R - R_target).square().sum((-1, -2)) * w_rot).sum(1) / self.sigma_rot ** 2
                axis = (R @ look_dir[..., None])[..., 0]
                cos = torch.nn.functional.cosine_similarity(axis, look_target - p, dim=-1)
                loss_look = ((1 - cos) * w_look).sum(1) / self.sigma_lookat ** 2
                loss = (loss_pos + loss_rot + loss_look + self.prior_weight * self.prior.nll(x)).sum()
                loss.backward()
                opt.step()
        with torch.no_grad():
            return Prediction(rot6d_to_matrix(x).detach(), transl.detach().clone())


@dataclass(frozen=True)
class NearestNeighborMethod:
    """Nearest train pose on centroid-relative position-effector joints (module docstring).

    Attributes:
        bodies: body models (query bodies are posed with them).
        R_local: (M, 24, 3, 3) train local rotations (root included).
        joints: (M, 24, 3) train joints on the neutral body, beta = 0, transl = 0.
    """

    bodies: BodyModelSet
    R_local: Tensor
    joints: Tensor

    @classmethod
    def from_dataset(cls, pose_axis_angle: Tensor, bodies: BodyModelSet, *, max_samples: int = 20_000,
                     seed: int = 0) -> NearestNeighborMethod:
        """Index a deterministic subsample (at most ``max_samples``) of train poses (M, 24, 3) axis-angle."""
        M = pose_axis_angle.shape[0]
        if M > max_samples:
            idx = np.sort(np.random.default_rng(seed).choice(M, max_samples, replace=False))
            pose_axis_angle = pose_axis_angle[torch.from_numpy(idx)]
        R_local = axis_angle_to_matrix(pose_axis_angle.float())
        J_rest = bodies.J_template[Gender.NEUTRAL.index]
        _, joints = forward_kinematics(R_local, J_rest)
        return cls(bodies, R_local, joints)

    def __call__(self, bset: BenchmarkSet) -> Prediction:
        from sklearn.neighbors import NearestNeighbors

        eff = bset.effectors
        S = len(bset)
        w_pos, target = _position_targets(eff)
        groups: dict[tuple[int, ...], list[int]] = {}
        for s in range(S):
            key = tuple(sorted(int(j) for j in eff.joint[s][w_pos[s].bool()]))
            groups.setdefault(key, []).append(s)
        train = self.joints.numpy()
        nearest = np.zeros(S, dtype=np.int64)
        for key, members in groups.items():
            cols = list(key)
            feats = train[:, cols]
            feats = (feats - feats.mean(1, keepdims=True)).reshape(len(train), -1)
            queries = []
            for s in members:
                order = np.argsort(eff.joint[s].numpy(), kind="stable")
                sel = [i for i in order if w_pos[s, i] > 0]
                q = target[s, sel].numpy()
                queries.append((q - q.mean(0)).reshape(-1))
            index = NearestNeighbors(n_neighbors=1, algorithm="brute" if len(members) < 64 else "auto").fit(feats)
            nearest[members] = index.kneighbors(np.stack(queries), return_distance=False)[:, 0]
        R_local = self.R_local[torch.from_numpy(nearest)]
        J_rest = self.bodies.rest_joints(bset.betas, bset.gender)
        _, p = forward_kinematics(R_local, J_rest)
        rows = torch.arange(S)[:, None]
        wsum = w_pos.sum(1, keepdim=True).clamp_min(1.0)
        shift = ((target - p[rows, eff.joint]) * w_pos[..., None]).sum(1) / wsum
        return Prediction(R_local, shift)


# ----------------------------------------------------------------------------- running and reporting

METHOD_DESCRIPTIONS = {
    "smplik": "SMPL-IK solver: network + 3 Levenberg-Marquardt refinement steps (batched solve_tensors)",
    "smplik_net": "SMPL-IK network alone (no refinement)",
    "optim": "Adam IK on SMPL + diagonal Gaussian 6D pose prior (train split)",
    "nn": "nearest neighbour in the train split (scikit-learn)",
    "rest": "rest pose at the effector centroid",
}
_METRIC_KEYS = ("mpjpe_mm", "pa_mpjpe_mm", "geodesic_rad", "position_residual_mm", "rotation_residual_deg",
                "lookat_error_deg", "time_ms_per_pose")


def _mean_metrics(items: Sequence[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in _METRIC_KEYS:
        vals = [m[key] for m in items if m.get(key) is not None]
        out[key] = float(np.mean(vals)) if vals else None
    out["samples"] = int(sum(m["samples"] for m in items))
    return out


def run_benchmark(bench: Benchmark, methods: Mapping[str, Method], bodies: BodyModelSet, *,
                  settings: Mapping[str, Any] | None = None,
                  progress: Callable[[str, str, SetMetrics], None] | None = None) -> dict[str, Any]:
    """Evaluate each method on every set; returns the results document (JSON-ready).

    ``results["methods"][name]["sets"][set_name]`` holds :class:`SetMetrics` fields and
    ``results["methods"][name]["random_mean"]`` their mean over the random N = 6..12 sets.
    """
    if bench.manifest.get("body_fingerprint") not in (None, bodies.fingerprint):
        raise ValueError(f"{bench.folder}: the benchmark was made with body models "
                         f"{bench.manifest['body_fingerprint']}, the models in use are {bodies.fingerprint}; "
                         "re-create the files or pass the same --model-dir.")
    results: dict[str, Any] = {
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "benchmark": {"files": bench.folder, "seed": bench.manifest["seed"], "version": bench.manifest["version"],
                      "source": bench.manifest["source"], "samples_per_count": bench.manifest["samples_per_count"]},
        "settings": dict(settings or {}) | {"torch_threads": torch.get_num_threads()},
        "methods": {},
    }
    for name, method in methods.items():
        per_set: dict[str, Any] = {}
        for bset in bench.sets:
            t0 = time.perf_counter()
            pred = method(bset)
            seconds = time.perf_counter() - t0
            m = evaluate_prediction(bset, pred, bodies, seconds)
            per_set[bset.name] = m.to_dict()
            if progress is not None:
                progress(name, bset.name, m)
        randoms = [per_set[s.name] for s in bench.sets if s.kind == "random"]
        results["methods"][name] = {"description": METHOD_DESCRIPTIONS.get(name, name), "sets": per_set,
                                    "random_mean": _mean_metrics(randoms) if randoms else None}
    return results


def save_results(path: str | Path, results: Mapping[str, Any]) -> Path:
    return write_json_atomic(path, results)


def _fmt(value: float | None, digits: int) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def results_markdown(results: Mapping[str, Any]) -> str:
    """Markdown tables: the N = 6..12 average per method, then the fixed 5-/6-point sets."""
    cols = [("mpjpe_mm", "MPJPE (mm)", 1), ("pa_mpjpe_mm", "PA-MPJPE (mm)", 1), ("geodesic_rad", "geodesic (rad)", 4),
            ("position_residual_mm", "pos. residual (mm)", 1), ("rotation_residual_deg", "rot. residual (°)", 2),
            ("lookat_error_deg", "look-at (°)", 2), ("time_ms_per_pose", "time / pose (ms, batched)", 3)]
    bench = results["benchmark"]
    lines = [f"Random effectors, mean over N = 6..12 ({bench['samples_per_count']} poses per N, "
             f"{bench['source']['split']} split, seed {bench['seed']}):", "",
             "| method | " + " | ".join(c[1] for c in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, res in results["methods"].items():
        mean = res.get("random_mean")
        if mean:
            lines.append(f"| {name} | " + " | ".join(_fmt(mean[k], d) for k, _, d in cols) + " |")
    fixed = [s for s in next(iter(results["methods"].values()))["sets"] if s.startswith("fixed_")]
    if fixed:
        lines += ["", "Fixed sparse sets (positions only): MPJPE / PA-MPJPE (mm) / geodesic (rad):", "",
                  "| method | " + " | ".join(fixed) + " |", "|---" * (len(fixed) + 1) + "|"]
        for name, res in results["methods"].items():
            cells = [f"{_fmt(res['sets'][s]['mpjpe_mm'], 1)} / {_fmt(res['sets'][s]['pa_mpjpe_mm'], 1)} / "
                     f"{_fmt(res['sets'][s]['geodesic_rad'], 3)}" for s in fixed]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
