"""IKSolver: a trained SMPL-IK model behind a validated, keyword-only API.

>>> solver = IKSolver.load()                              # the packaged model
>>> pose = solver.solve([Effector.position("left_wrist", (0.5, 1.2, 0.1)), ...], betas=b, gender="female")
>>> pose.body_pose.shape, pose.joints.shape
((23, 3), (24, 3))

Effectors are :class:`~smplik.effectors.Effector` objects or their JSON dicts
(``{"joint", "type", "value" | "target"/"direction", "tolerance"}``, see
:mod:`smplik.effector_schema`). The returned :class:`~smplik.pose.Pose` holds smplx's
``global_orient``, ``body_pose`` and ``transl`` plus ``joints`` (24, 3), equal to
``smplx.SMPL(...).joints[:, :24]`` for that pose on the body models in use.

A solve is the network's pose followed by a short effector refinement (:mod:`smplik.refine`: three
Levenberg-Marquardt steps anchored to the network's local rotations, weighted by each effector's
tolerance), which takes reachable exact effectors from a few centimetres to a millimetre or two. Load with
``refine=RefineConfig(iterations=0)`` (``smplik solve --refine-steps 0``) for the network alone.

The rest skeleton used for the forward kinematics is the one of the body models in use
(built-in, or real SMPL files from ``model_dir``/``$SMPLIK_MODEL_DIR``); when they differ from the
models the network was trained on (``body_fingerprint``), a warning says so.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import PARENTS, EffectorType, Gender
from smplik.effectors import (
    Effector,
    EffectorBatch,
    EffectorError,
    pack_effector_arrays,
    pack_effectors,
    parse_effector_dict,
)
from smplik.ensemble import NO_ENSEMBLE, EnsembleConfig, run_ensemble
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput, ProtoResIK
from smplik.onnx_runtime import OnnxNetwork, Runtime, select_network
from smplik.pose import Pose
from smplik.refine import DEFAULT_REFINEMENT, RefineConfig, fast_backend_default, refine_output
from smplik.rotations import axis_angle_to_matrix, matrix_to_axis_angle_np
from smplik.validation import check_betas
from smplik.variants import Variant

PACKAGED_MODEL = "smplik_cmu.pt"
"""File name of the shipped model in ``smplik/checkpoints``."""

EffectorLike = Effector | Mapping[str, Any]


def packaged_model_path() -> Path:
    """Path of the model shipped as package data (it may be absent in a source checkout)."""
    return Path(str(resources.files("smplik").joinpath("checkpoints", PACKAGED_MODEL)))


def as_effector(item: EffectorLike, index: int | None = None) -> Effector:
    """An :class:`Effector` from itself or its JSON dict; errors name the list position."""
    if isinstance(item, Effector):
        return item
    if isinstance(item, Mapping):
        return parse_effector_dict(item, f"effectors[{index}]" if index is not None else "")
    where = f"effectors[{index}]: " if index is not None else ""
    raise EffectorError(f"{where}expected an Effector or a dict, got {type(item).__name__}.")


def as_effector_list(effectors: Sequence[EffectorLike]) -> list[Effector]:
    """Validate a non-empty list of effectors (objects or dicts)."""
    if isinstance(effectors, (Effector, Mapping, str)) or not isinstance(effectors, Sequence):
        raise EffectorError(f"effectors must be a list of Effector objects or dicts, got {type(effectors).__name__}.")
    if len(effectors) == 0:
        raise EffectorError("The effector list is empty; at least one effector is needed.")
    return [as_effector(e, i) for i, e in enumerate(effectors)]


def _parse_gender(value: Any) -> Gender:
    if not isinstance(value, (str, Gender)):
        raise ValueError(f"Unknown gender {value!r}; expected one of: {', '.join(g.value for g in Gender)}.")
    return Gender.parse(value)


@dataclass(frozen=True)
class EffectorResidual:
    """How far a solved pose is from one effector: ``value`` in mm (position) or degrees (rotation: the
    geodesic angle; look-at: the angle between the joint's direction and the ray to the target)."""

    effector: Effector
    value: float

    @property
    def unit(self) -> str:
        return "mm" if self.effector.type == EffectorType.POSITION else "deg"

    def __str__(self) -> str:
        return f"{self.effector.joint_name} {self.effector.type.name.lower()}: {self.value:.1f} {self.unit}"


def effector_residuals(pose: Pose, effectors: Sequence[Effector], bodies: BodyModelSet) -> list[EffectorResidual]:
    """Each effector's residual on ``pose`` (FK on ``bodies`` of the pose's gender), in effector order."""
    aa = torch.as_tensor(np.concatenate([pose.global_orient[None], pose.body_pose]), dtype=torch.float64)
    J_rest = bodies[pose.gender].rest_joints(torch.as_tensor(pose.betas, dtype=torch.float64))
    R_world, p_world = forward_kinematics(axis_angle_to_matrix(aa), J_rest, torch.as_tensor(pose.transl))
    R_world, p_world = R_world.numpy(), p_world.numpy()
    out = []
    for e in effectors:
        R, p = R_world[e.joint], p_world[e.joint]
        if e.type == EffectorType.POSITION:
            value = 1000.0 * float(np.linalg.norm(p - e.value))
        elif e.type == EffectorType.ROTATION:
            cos = (np.trace(R @ np.asarray(e.value).T) - 1.0) / 2.0
            value = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        else:
            ray = np.asarray(e.value) - p
            axis = R @ np.asarray(e.direction)
            cos = float(axis @ ray) / max(float(np.linalg.norm(ray) * np.linalg.norm(axis)), 1e-12)
            value = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        out.append(EffectorResidual(e, value))
    return out


VARIANT_CHUNK = 128
"""Most variant candidates solved in one batch (:meth:`IKSolver.sample_variants`): bounds the memory of
``scene variants --candidates 1024`` (benchmarks/fuzz_campaign.py measures it)."""


@dataclass(frozen=True)
class IKSolver:
    """A loaded model and the body models it poses.

    Attributes:
        model: the network (eval mode, float32) whose rest skeletons are those of ``bodies``.
        bodies: the body models in use (all three genders).
        meta: the model file's metadata (network config, step, metrics, body_fingerprint, ...).
        source: the model file.
        refine: the effector refinement applied after the network (:mod:`smplik.refine`);
            ``RefineConfig(iterations=0)`` gives the network's pose alone.
    """

    model: ProtoResIK
    bodies: BodyModelSet
    meta: dict[str, Any]
    source: str
    refine: RefineConfig = DEFAULT_REFINEMENT
    network: OnnxNetwork | None = None
    """The network backend of :meth:`solve_tensors`: an onnxruntime session (:mod:`smplik.onnx_runtime`), or
    None for ``model`` (torch, the reference)."""
    ensemble: EnsembleConfig = NO_ENSEMBLE
    """Test-time ensemble of the network (:mod:`smplik.ensemble`): mirrored and turned copies of each
    problem, averaged; the default runs the network once."""

    @classmethod
    def load(cls, path: str | Path | None = None, *, model_dir: str | Path | None = None,
             refine: RefineConfig | None = None, runtime: Runtime = "auto",
             onnx_file: str | Path | None = None, onnx_threads: int = 1,
             ensemble: EnsembleConfig = NO_ENSEMBLE, small_batches: bool = True) -> IKSolver:
        """Load a model file (default: the packaged ``smplik/checkpoints/smplik_cmu.pt``).

        Args:
            path: an exported model (``smplik export-model``) or a training checkpoint.
            model_dir: folder with real SMPL files (default ``$SMPLIK_MODEL_DIR``, else built-in).
            refine: refinement after the network (default: the model file's calibrated ``refine`` settings
                (``smplik benchmark calibrate``) when it has them, else :data:`~smplik.refine.DEFAULT_REFINEMENT`,
                3 Levenberg-Marquardt steps; ``iterations=0``: none).
            runtime: network backend, ``"auto"`` (default: onnxruntime when it is installed and a matching
                ``onnx_file``/``PATH.onnx`` exists, as for the packaged model; else torch), ``"torch"`` or ``"onnx"``
                (onnxruntime); see :func:`smplik.onnx_runtime.select_network`. ``onnx_threads``: onnxruntime threads.
            ensemble: test-time ensemble (e.g. ``EnsembleConfig(yaw=4, mirror=True)``; default: none).
            small_batches: with onnxruntime and numba, calls of at most 16 effector tokens (one pose of up to
                16 effectors) run in the network's numba kernel (:mod:`smplik.network_numba`; same weights,
                about half the time of a session call).

        Raises:
            FileNotFoundError: no such file (or no packaged model in this installation).
            ValueError: the file is not an smplik model (or, with ``runtime``, an unusable ONNX file).
            OnnxUnavailableError: ``runtime="onnx"`` without onnxruntime installed.
        """
        from smplik.model_io import load_model

        if path is None:
            path = packaged_model_path()
            if not path.is_file():
                raise FileNotFoundError(
                    f"No packaged model at {path}: this installation ships without one. Train one "
                    "(`smplik train`), export it (`smplik export-model RUN/checkpoint.pt --out FILE.pt`) and pass "
                    "it with --checkpoint / IKSolver.load(FILE.pt).")
        path = Path(path)
        try:
            model, meta = load_model(path)
        except (KeyError, TypeError, RuntimeError, AttributeError) as exc:
            raise ValueError(f"{path}: not a valid smplik model ({type(exc).__name__}: {exc}).") from exc
        bad = [k for k, v in model.state_dict().items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
        if bad:
            raise ValueError(f"{path}: not a valid smplik model (weights '{bad[0]}' hold NaN or inf; the file is "
                             "corrupt).")
        if refine is None:
            refine = DEFAULT_REFINEMENT if meta.get("refine") is None else \
                RefineConfig.from_dict(meta["refine"], f"{path}: key 'refine'")
        bodies = BodyModelSet.load(model_dir)
        trained_on = meta.get("body_fingerprint")
        # The network depends on the bodies only through their rest skeletons, which the file holds:
        # a file whose fingerprint predates the grid hashing (or another CPU's noise) but whose skeletons
        # match those in use (within a micrometre) was trained on these bodies.
        same_skeletons = bool(torch.allclose(model.J_template, bodies.J_template, rtol=0, atol=1e-6)
                              and torch.allclose(model.J_dirs, bodies.J_dirs, rtol=0, atol=1e-6))
        if trained_on is not None and trained_on != bodies.fingerprint and not same_skeletons:
            warnings.warn(f"{path} was trained on body models with fingerprint {trained_on}, but the body models "
                          f"in use ({bodies.models[0].source}, ...) have fingerprint {bodies.fingerprint}; the "
                          "solver uses the current skeletons, so accuracy may be lower.", stacklevel=2)
        model.J_template.copy_(bodies.J_template)
        model.J_dirs.copy_(bodies.J_dirs)
        model.requires_grad_(False)
        network = select_network(runtime, model, path, onnx_file, threads=onnx_threads,
                                 meta={"source": str(path), "body_fingerprint": bodies.fingerprint},
                                 small_batches=small_batches)
        return cls(model, bodies, meta, str(path), refine, network, ensemble)

    # ------------------------------------------------------------------------- fast path

    def solve_tensors(self, eff: EffectorBatch, betas: Tensor, gender: Tensor, *,
                      refine: RefineConfig | None = None, ensemble: EnsembleConfig | None = None) -> IKOutput:
        """Network + FK, then the effector refinement, without validation, under ``torch.inference_mode()``.

        Args: eff (B rows of N), betas (B, 10) float32, gender (B,) long in :class:`Gender` order;
        refine: overrides the solver's ``refine`` (``RefineConfig(iterations=0)``: the network alone);
        ensemble: overrides the solver's ``ensemble``.
        """
        cfg = self.refine if refine is None else refine
        ens = self.ensemble if ensemble is None else ensemble
        network = self.model if self.network is None else self.network
        with torch.inference_mode():
            if ens.size == 1 and cfg.iterations == 0:
                return network(eff, betas, gender)
            J_rest = self.model.rest_joints(betas, gender)
            out = run_ensemble(network, eff, betas, gender, J_rest, ens)
            if cfg.iterations > 0:
                out = refine_output(out, J_rest, eff, cfg)
            return out

    # ------------------------------------------------------------------------- validated API

    def solve(self, effectors: Sequence[EffectorLike], *, betas: Any = None,
              gender: Gender | str = Gender.NEUTRAL) -> Pose:
        """Solve one pose.

        Args:
            effectors: non-empty list of :class:`Effector` or JSON dicts.
            betas: (10,) body shape (default zeros).
            gender: ``"neutral"``, ``"male"``, ``"female"`` or a :class:`Gender`.

        Raises:
            ValueError: naming the problem (unknown joint, NaN, shapes, tolerance, rotation, betas, ...).
        """
        rows = [as_effector_list(effectors)]
        b = check_betas(betas)[None]
        g = _parse_gender(gender)
        return self._solve_rows(rows, b, [g])[0]

    def solve_batch(self, effector_lists: Sequence[Sequence[EffectorLike]], *, betas: Any = None,
                    gender: Gender | str | Sequence[Gender | str] = Gender.NEUTRAL) -> list[Pose]:
        """Solve B poses in one network call (lists may have different lengths).

        Args:
            effector_lists: B non-empty effector lists.
            betas: None (zeros), (10,) shared, or (B, 10).
            gender: one gender for all, or a list of B.
        """
        if isinstance(effector_lists, (str, Mapping)) or not isinstance(effector_lists, Sequence):
            raise ValueError("effector_lists must be a list of effector lists.")
        if len(effector_lists) == 0:
            raise ValueError("effector_lists is empty; nothing to solve.")
        rows = []
        for b, row in enumerate(effector_lists):
            try:
                rows.append(as_effector_list(row))
            except ValueError as exc:
                raise ValueError(f"pose {b}: {exc}") from None
        B = len(rows)
        beta_arr = check_betas(betas, B)
        if isinstance(gender, (str, Gender)):
            genders = [_parse_gender(gender)] * B
        else:
            genders = [_parse_gender(g) for g in gender]
            if len(genders) != B:
                raise ValueError(f"gender has {len(genders)} entries for {B} poses.")
        return self._solve_rows(rows, beta_arr, genders)

    def sample(self, effectors: Sequence[EffectorLike], k: int = 4, *, betas: Any = None,
               gender: Gender | str = Gender.NEUTRAL, seed: int = 0, candidates: int = 32,
               floor: float | None = None) -> list[Pose]:
        """Up to ``k`` diverse poses that all meet ``effectors`` ("variants", :mod:`smplik.variants`).

        Pose 0 is :meth:`solve`'s; the others are the network's poses for the effectors plus 1-3 random soft
        *guide* effectors on free limbs (``candidates`` of them solved in one batch), kept when they still meet the
        effectors and are plausible, picked far apart (farthest points on the 24 joints). Deterministic for a seed.
        :meth:`sample_variants` also returns the guides of each pose.

        Args:
            effectors: non-empty list of :class:`Effector` or JSON dicts.
            k: number of poses wanted (>= 1); fewer come back when the effectors leave too little freedom.
            betas: (10,) body shape (default zeros). gender: as in :meth:`solve`.
            seed: seed (>= 0) of the random guides. candidates: guided effector sets tried (>= 1).
            floor: height (y, metres) of a floor no joint may go below, or None.

        Returns:
            list of up to ``k`` :class:`~smplik.pose.Pose` (each ``body_pose`` (23, 3), ``joints`` (24, 3)).

        Raises:
            ValueError: one line naming the problem (bad effector, betas, k, seed, candidates or floor).
        """
        return [v.pose for v in self.sample_variants(effectors, k, betas=betas, gender=gender, seed=seed,
                                                     candidates=candidates, floor=floor)]

    def sample_variants(self, effectors: Sequence[EffectorLike], k: int = 4, *, betas: Any = None,
                        gender: Gender | str = Gender.NEUTRAL, seed: int = 0, candidates: int = 32,
                        floor: float | None = None) -> list[Variant]:
        """:meth:`sample` returning :class:`~smplik.variants.Variant` records: each pose with the guide effectors
        that produced it (``variant.effectors`` = the effectors + its guides, which re-solve to its pose) and its
        mean joint distance to pose 0 (metres)."""
        from smplik.variants import (
            ANOMALY_MAX,
            check_count,
            free_guide_joints,
            guide_effectors,
            implausibility,
            meets_effectors,
            pick_variants,
        )

        user = tuple(as_effector_list(effectors))
        b, g = check_betas(betas), _parse_gender(gender)
        k, seed = check_count("k", k, 1), check_count("seed", seed, 0)
        candidates = check_count("candidates", candidates, 1)
        if floor is not None and (isinstance(floor, bool) or not isinstance(floor, (int, float, np.floating))
                                  or not np.isfinite(floor)):
            raise ValueError(f"floor must be a finite height (metres) or None, got {floor!r:.40}.")
        base = self._solve_rows([list(user)], b[None], [g])[0]  # exactly solve()'s pose
        variants = [Variant(base, (), user, 0.0)]
        free = free_guide_joints(user)
        if k == 1 or not free:
            return variants
        rng = np.random.default_rng(seed)
        drawn = [guide_effectors(base, free, rng) for _ in range(candidates)]
        rows_b, rows_g = np.repeat(b[None], candidates, 0), [g] * candidates
        poses = self._solve_rows_chunked([list(user + d) for d in drawn], rows_b, rows_g)
        # pass 2: each guide moved to where pass 1 put its joint, so the stored guides describe the variant's pose
        guides = [tuple(Effector.position(e.joint, p.joints[e.joint], e.tolerance) for e in d)
                  for d, p in zip(drawn, poses, strict=True)]
        poses = self._solve_rows_chunked([list(user + gs) for gs in guides], rows_b, rows_g)
        base_res = [r.value for r in effector_residuals(base, user, self.bodies)]
        plausible = implausibility(poses, floor) <= ANOMALY_MAX
        keep = [m for m in range(candidates) if plausible[m] and meets_effectors(
            [r.value for r in effector_residuals(poses[m], user, self.bodies)], base_res, user)]
        if keep:
            variants += [Variant(poses[m], guides[m], user + guides[m], d)
                         for m, d in pick_variants(base, poses, keep, k)]
        return variants

    def _solve_rows_chunked(self, rows: list[list[Effector]], betas: np.ndarray, genders: list[Gender]) -> list[Pose]:
        """:meth:`_solve_rows` in batches of at most :data:`VARIANT_CHUNK` rows: the network's and refinement's
        activations grow with the batch, so 1024 variant candidates cost one chunk's memory, not 1024 rows'."""
        return [pose for start in range(0, len(rows), VARIANT_CHUNK)
                for pose in self._solve_rows(rows[start:start + VARIANT_CHUNK], betas[start:start + VARIANT_CHUNK],
                                             genders[start:start + VARIANT_CHUNK])]

    def _solve_rows(self, rows: list[list[Effector]], betas: np.ndarray, genders: list[Gender]) -> list[Pose]:
        if self.network is not None and self.ensemble.size == 1 and (self.refine.iterations == 0
                                                                     or fast_backend_default()):
            return self._solve_rows_numpy(rows, betas, genders)
        eff = pack_effectors(rows)
        out = self.solve_tensors(eff, torch.from_numpy(np.ascontiguousarray(betas, np.float32)),
                                 torch.tensor([g.index for g in genders]))
        return self._poses(out.R_local.double().numpy(), out.transl.double().numpy(), out.p_world.double().numpy(),
                           betas, genders)

    @cached_property
    def _rest_skeleton(self) -> tuple[np.ndarray, np.ndarray]:
        """The model's rest skeletons per gender as float64 numpy: J_template (3, J, 3), J_dirs (3, J * 3, 10)."""
        J_dirs = self.model.J_dirs.double().numpy()
        return self.model.J_template.double().numpy(), J_dirs.reshape(J_dirs.shape[0], -1, J_dirs.shape[-1])

    def _solve_rows_numpy(self, rows: list[list[Effector]], betas: np.ndarray, genders: list[Gender]) -> list[Pose]:
        """:meth:`_solve_rows` without torch for the onnxruntime network and the fast refinement: the same
        network graph and refinement kernels as :meth:`solve_tensors` (tested equal), with the refined pose kept
        in float64, minus half the Python glue of one pose's solve."""
        from smplik.refine_fast import refine_arrays

        joint, kind, data, tol, mask = pack_effector_arrays(rows)
        gender = np.array([g.index for g in genders], np.int64)
        R_local, R_world, p_world, _, transl = self.network.run_arrays(joint, kind, data, tol, mask, betas, gender)
        if self.refine.iterations > 0:
            J_template, J_dirs = self._rest_skeleton
            J_rest = J_template[gender] + (J_dirs[gender] @ betas[..., None]).reshape(J_template[gender].shape)
            R_local, _, p_world, transl = refine_arrays(
                R_local.astype(np.float64), R_world.astype(np.float64), p_world.astype(np.float64),
                transl.astype(np.float64), J_rest, joint, kind, data, tol, mask, PARENTS, self.refine)
        return self._poses(R_local, transl, p_world, betas, genders)

    def _poses(self, R_local: np.ndarray, transl: np.ndarray, joints: np.ndarray, betas: np.ndarray,
               genders: list[Gender]) -> list[Pose]:
        """Poses from local rotations (B, J, 3, 3), transl (B, 3) and joints (B, J, 3); non-finite ones raise."""
        aa = matrix_to_axis_angle_np(R_local)
        transl, joints = np.asarray(transl, np.float64), np.asarray(joints, np.float64)
        finite = np.isfinite(aa).all((1, 2)) & np.isfinite(transl).all(1) & np.isfinite(joints).all((1, 2))
        if not finite.all():
            raise ValueError(f"{self.source}: the model gave a non-finite pose for pose {int(np.argmin(finite))} "
                             "(a corrupt model file?).")
        return [Pose(global_orient=aa[b, 0].copy(), body_pose=aa[b, 1:].copy(), transl=transl[b].copy(),
                     betas=np.array(betas[b], dtype=np.float64), gender=genders[b], joints=joints[b].copy())
                for b in range(len(genders))]
