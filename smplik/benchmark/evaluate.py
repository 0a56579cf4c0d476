"""Benchmark metrics of a prediction: per sample, then pooled over any group of samples.

MPJPE and PA-MPJPE (mm, 24 joints; :mod:`smplik.metrics`), mean geodesic error of the local
rotations (rad), position-effector residual (mm), rotation-effector residual (degrees, global
rotation) and look-at error (degrees between the joint's rotated direction and the ray to the
target). Pose errors are averaged over samples; effector errors over all effectors of that type
among the samples (None when there is none). The wall time per pose (ms) is measured by the
runner on the whole set.

:class:`SampleErrors` keeps the per-sample values (and per-sample effector sums and counts), so
a set, one subject's samples of a set, or one subject's samples of several sets all average the
same way (:meth:`SampleErrors.summary`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.metrics import local_geodesic, mpjpe, pa_mpjpe
from smplik.rotations import geodesic_distance, rot6d_to_matrix

from .files import BenchmarkSet

EFFECTOR_KINDS = {"position": EffectorType.POSITION, "rotation": EffectorType.ROTATION,
                  "look_at": EffectorType.LOOK_AT}
"""Effector type names of the per-type errors."""
_EFFECTOR_METRICS = {"position": ("position_residual_mm", 1000.0), "rotation": ("rotation_residual_deg", 180 / math.pi),
                     "look_at": ("lookat_error_deg", 180 / math.pi)}


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


def effector_slot_errors(eff: EffectorBatch, R_world: Tensor, p_world: Tensor) -> Tensor:
    """Each effector's error in its type's unit: metres (position), radians (rotation, look-at).

    Args: eff (S rows of N); R_world (S, 24, 3, 3); p_world (S, 24, 3).
    Returns: (S, N), 0 on padding slots.
    """
    rows = torch.arange(eff.joint.shape[0])[:, None]
    p = p_world[rows, eff.joint]  # (S, N, 3)
    R = R_world[rows, eff.joint]  # (S, N, 3, 3)
    err = torch.zeros(eff.joint.shape, dtype=p_world.dtype)
    sel = eff.mask & (eff.type == int(EffectorType.POSITION))
    err[sel] = (p[sel] - eff.data[sel][:, :3]).norm(dim=-1)
    sel = eff.mask & (eff.type == int(EffectorType.ROTATION))
    err[sel] = geodesic_distance(R[sel], rot6d_to_matrix(eff.data[sel]).to(R.dtype))
    sel = eff.mask & (eff.type == int(EffectorType.LOOK_AT))
    axis = (R[sel] @ eff.data[sel][:, 3:, None].to(R.dtype))[..., 0]
    ray = eff.data[sel][:, :3] - p[sel]
    err[sel] = torch.acos(torch.nn.functional.cosine_similarity(axis, ray, dim=-1).clamp(-1.0, 1.0))
    return err


def effector_errors(eff: EffectorBatch, R_world: Tensor, p_world: Tensor) -> dict[str, Tensor]:
    """Per-effector errors, flattened over the effectors of each type.

    Args: eff (S rows of N); R_world (S, 24, 3, 3); p_world (S, 24, 3).
    Returns: ``position`` (metres), ``rotation`` (radians), ``look_at`` (radians), 1-D tensors.
    """
    err = effector_slot_errors(eff, R_world, p_world)
    return {name: err[eff.mask & (eff.type == int(t))] for name, t in EFFECTOR_KINDS.items()}


@dataclass(frozen=True)
class SampleErrors:
    """Per-sample errors of a prediction on a set of S samples.

    Attributes:
        mpjpe, pa_mpjpe: (S,) metres. geodesic: (S,) radians (mean over the 24 local rotations).
        effector_sum, effector_count: type name (:data:`EFFECTOR_KINDS`) -> (S,) sum of that type's
            effector errors (metres or radians) and their number, per sample.
    """

    mpjpe: Tensor
    pa_mpjpe: Tensor
    geodesic: Tensor
    effector_sum: dict[str, Tensor]
    effector_count: dict[str, Tensor]

    def __len__(self) -> int:
        return int(self.mpjpe.shape[0])

    def select(self, index: Tensor) -> SampleErrors:
        """The samples picked by a boolean mask or index tensor (S,)."""
        return SampleErrors(self.mpjpe[index], self.pa_mpjpe[index], self.geodesic[index],
                            {k: v[index] for k, v in self.effector_sum.items()},
                            {k: v[index] for k, v in self.effector_count.items()})

    @staticmethod
    def concat(parts: Sequence[SampleErrors]) -> SampleErrors:
        """The samples of several sets, one after the other."""
        return SampleErrors(torch.cat([p.mpjpe for p in parts]), torch.cat([p.pa_mpjpe for p in parts]),
                            torch.cat([p.geodesic for p in parts]),
                            {k: torch.cat([p.effector_sum[k] for p in parts]) for k in EFFECTOR_KINDS},
                            {k: torch.cat([p.effector_count[k] for p in parts]) for k in EFFECTOR_KINDS})

    def summary(self) -> dict[str, Any]:
        """:class:`SetMetrics` fields but the time: pose errors averaged over the samples, effector errors
        over all effectors of their type among them (None where there is none); ``samples``."""
        out: dict[str, Any] = {"mpjpe_mm": float(self.mpjpe.mean() * 1000),
                               "pa_mpjpe_mm": float(self.pa_mpjpe.mean() * 1000),
                               "geodesic_rad": float(self.geodesic.mean())}
        for kind, (key, scale) in _EFFECTOR_METRICS.items():
            count = int(self.effector_count[kind].sum())
            out[key] = float(self.effector_sum[kind].sum() / count * scale) if count else None
        out["samples"] = len(self)
        return out


def sample_errors(bset: BenchmarkSet, pred: Prediction, bodies: BodyModelSet) -> SampleErrors:
    """Per-sample errors of ``pred`` on ``bset``; joints by our FK on the set's bodies."""
    J_rest = bodies.rest_joints(bset.betas, bset.gender)
    R_world, p_world = forward_kinematics(pred.R_local.float(), J_rest, pred.transl.float())
    eff = bset.effectors
    err = effector_slot_errors(eff, R_world, p_world).double()
    sums, counts = {}, {}
    for name, t in EFFECTOR_KINDS.items():
        sel = (eff.mask & (eff.type == int(t))).double()
        sums[name], counts[name] = (err * sel).sum(1), sel.sum(1)
    return SampleErrors(mpjpe(p_world, bset.joints).double(), pa_mpjpe(p_world.double(), bset.joints.double()),
                        local_geodesic(pred.R_local.float(), bset.R_local).double(), sums, counts)


def evaluate_prediction(bset: BenchmarkSet, pred: Prediction, bodies: BodyModelSet,
                        seconds: float = float("nan")) -> SetMetrics:
    """Metrics of ``pred`` on ``bset`` (``seconds``: the method's wall time on the whole set)."""
    summary = sample_errors(bset, pred, bodies).summary()
    return SetMetrics(**summary, time_ms_per_pose=seconds * 1000.0 / max(len(bset), 1))
