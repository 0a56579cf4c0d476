"""Test-time ensemble: the network run on mirrored and turned copies of the effectors, averaged.

The network is trained with left/right mirroring and random turns about the vertical axis
(:mod:`smplik.data.sampler`), so it should answer a mirrored or turned problem with the mirrored or
turned pose; it does only approximately. Solving ``yaw`` turns (by ``2 pi k / yaw``) of the problem,
each also mirrored when ``mirror`` is set, mapping every answer back and averaging them gives a pose
that is closer to the truth than any single answer (validation split: see the README's benchmark).

Forward map of copy ``(m, k)``: mirror (``M = diag(-1, 1, 1)``, left/right joints swapped) if ``m``,
then turn by ``R_y(2 pi k / yaw)``, applied to the effectors:

* position ``p -> R M p``;
* rotation ``R_world -> R (M R_world M)`` on the swapped joint (6D columns transform accordingly);
* look-at ``target -> R M target`` and ``direction -> M direction`` (it is in the joint's frame).

The answers are mapped back with :func:`smplik.symmetry.rotate_about_vertical` (inverse turn) and
:func:`smplik.symmetry.mirror_pose`; local rotations are averaged as their first two columns and
re-orthonormalised (Gram-Schmidt, as the network's 6D output), the pelvis position is averaged.
All copies run as one batch of ``size * B`` rows, so for one pose the network's cost barely grows.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass
from functools import lru_cache

import torch
from torch import Tensor

from smplik.conventions import LEFT_RIGHT, EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.network import IKOutput
from smplik.rotations import matrix_to_rot6d, rot6d_to_matrix
from smplik.symmetry import mirror_pose, rotate_about_vertical, rotation_about_y

_FLIP_X = (-1.0, 1.0, 1.0)


@dataclass(frozen=True)
class EnsembleConfig:
    """Copies of each problem the network solves: ``yaw`` turns about the vertical axis, each also
    mirrored when ``mirror``. ``EnsembleConfig()`` (1 turn, no mirror) is the network alone."""

    yaw: int = 1
    mirror: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.yaw, bool) or not isinstance(self.yaw, int) or not 1 <= self.yaw <= 64:
            raise ValueError(f"EnsembleConfig.yaw must be an integer in [1, 64], got {self.yaw!r}.")

    @property
    def size(self) -> int:
        """Copies per problem."""
        return self.yaw * (2 if self.mirror else 1)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def parse(cls, text: str) -> EnsembleConfig:
        """``"none"``, ``"mirror"``, ``"yawK"`` or ``"mirror+yawK"`` (e.g. ``mirror+yaw4``); strictly: no empty
        part, no part twice, ``none`` alone."""
        parts = [p.strip() for p in str(text).lower().split("+")]
        unknown = (f"Unknown ensemble {text!r:.40}; expected none, mirror, yawK or mirror+yawK (e.g. mirror+yaw4), "
                   "each part once.")
        if any(not p for p in parts) or len(set(parts)) != len(parts) or len(parts) > 2 \
                or ("none" in parts and len(parts) > 1):
            raise ValueError(unknown)
        if parts == ["none"]:
            return cls()
        yaw, mirror = 1, False
        for part in parts:
            yaw_match = re.fullmatch(r"yaw([0-9]{1,6})", part)
            if part == "mirror":
                mirror = True
            elif yaw_match and sum(p.startswith("yaw") for p in parts) == 1:
                yaw = int(yaw_match.group(1))
            else:
                raise ValueError(unknown)
        return cls(yaw=yaw, mirror=mirror)


NO_ENSEMBLE = EnsembleConfig()


@lru_cache(maxsize=8)
def _copies(yaw: int, mirror: bool) -> tuple[Tensor, Tensor]:
    """(K, 3, 3) turn of each copy and (K,) bool whether it is mirrored, K = yaw * (1 + mirror)."""
    with torch.inference_mode(False):
        angles = torch.arange(yaw, dtype=torch.float64) * (2.0 * math.pi / yaw)
        flips = [False, True] if mirror else [False]
        turns = torch.cat([rotation_about_y(angles)] * len(flips))
        mirrored = torch.tensor([f for f in flips for _ in range(yaw)])
        return turns, mirrored


def augment_effectors(eff: EffectorBatch, cfg: EnsembleConfig) -> EffectorBatch:
    """The ``K = cfg.size`` transformed copies of B effector rows, copy-major: row ``k * B + b``.

    Returns an :class:`EffectorBatch` of ``K * B`` rows (see the module docstring for the map).
    """
    turns, mirrored = _copies(cfg.yaw, cfg.mirror)
    K = turns.shape[0]
    dt = eff.data.dtype
    is_rot = (eff.type == int(EffectorType.ROTATION))[None, ..., None]  # (1, B, N, 1)
    flip = torch.tensor(_FLIP_X, dtype=dt)
    m = mirrored.to(dt)[:, None, None, None]  # (K, 1, 1, 1)
    sign = 1.0 - 2.0 * m  # -1 for mirrored copies
    xyz, extra = eff.data[..., :3][None], eff.data[..., 3:][None]  # (1, B, N, 3)
    # M v = v * flip; rotation 6D columns: column 0 of M R M is -M c0, column 1 is M c1.
    xyz_m = torch.where(m.bool(), xyz * flip, xyz)
    xyz_m = torch.where(is_rot & m.bool(), xyz_m * sign, xyz_m)
    extra_m = torch.where(m.bool(), extra * flip, extra)
    R = turns.to(dt)[:, None]  # (K, 1, 3, 3)
    xyz_t = xyz_m @ R.transpose(-1, -2)
    extra_t = torch.where(is_rot, extra_m @ R.transpose(-1, -2), extra_m)
    lr = torch.tensor(LEFT_RIGHT)
    joint = torch.where(mirrored[:, None, None], lr[eff.joint][None], eff.joint[None])
    B, N = eff.joint.shape
    return EffectorBatch(joint.reshape(K * B, N), eff.type.repeat(K, 1), torch.cat([xyz_t, extra_t], -1).reshape(
        K * B, N, 6), eff.tolerance.repeat(K, 1), eff.mask.repeat(K, 1))


def combine_outputs(out: IKOutput, J_rest: Tensor, cfg: EnsembleConfig) -> IKOutput:
    """Map the ``K * B`` answers to :func:`augment_effectors`' copies back and average them.

    Args:
        out: the network's output for the K * B rows (copy-major).
        J_rest: (B, 24, 3) rest joints of the B bodies.

    Returns:
        An :class:`IKOutput` for the B problems (FK recomputed from the averaged rotations).
    """
    turns, mirrored = _copies(cfg.yaw, cfg.mirror)
    K, B = turns.shape[0], J_rest.shape[0]
    dt = out.R_local.dtype
    angles = -torch.arange(cfg.yaw, dtype=dt).repeat(len(turns) // cfg.yaw) * (2.0 * math.pi / cfg.yaw)
    R_local = out.R_local.view(K, B, *out.R_local.shape[1:])
    transl = out.transl.view(K, B, 3)
    J0 = J_rest[None, :, 0].expand(K, B, 3)
    R_local, transl = rotate_about_vertical(R_local, transl, angles[:, None].expand(K, B), J0)
    if cfg.mirror:
        half = cfg.yaw
        R_m, t_m = mirror_pose(R_local[half:], transl[half:], J0[half:])
        R_local, transl = torch.cat([R_local[:half], R_m]), torch.cat([transl[:half], t_m])
    draft = out.draft.view(K, B, -1, 3) @ turns.to(dt)[:, None]  # row vectors: p @ R = R^T p
    if cfg.mirror:
        flip = torch.tensor(_FLIP_X, dtype=dt)
        lr = torch.tensor(LEFT_RIGHT)
        draft = torch.cat([draft[:cfg.yaw], draft[cfg.yaw:][:, :, lr] * flip])
    R_mean = rot6d_to_matrix(matrix_to_rot6d(R_local).mean(0))
    transl_mean = transl.mean(0)
    R_world, p_world = forward_kinematics(R_mean, J_rest.to(dt), transl_mean)
    return IKOutput(R_mean, R_world, p_world, draft.mean(0), transl_mean)


def run_ensemble(network, eff: EffectorBatch, betas: Tensor, gender: Tensor, J_rest: Tensor,
                 cfg: EnsembleConfig) -> IKOutput:
    """``network(eff, betas, gender)`` (torch model or :class:`~smplik.onnx_runtime.OnnxNetwork`) on the
    ``cfg.size`` copies in one call, combined. ``cfg.size == 1``: the network's answer as it is."""
    if cfg.size == 1:
        return network(eff, betas, gender)
    K = cfg.size
    out = network(augment_effectors(eff, cfg), betas.repeat(K, 1), gender.repeat(K))
    return combine_outputs(out, J_rest, cfg)
