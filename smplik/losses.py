"""Training losses of ProtoRes Algorithm 1 (pure functions) and their weights."""

from __future__ import annotations

import torch
from torch import Tensor

from smplik.configs import LossConfig
from smplik.conventions import NUM_JOINTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.network import IKOutput
from smplik.rotations import geodesic_distance


def lookat_angle(target: Tensor, direction: Tensor, p_joint: Tensor, R_joint: Tensor) -> Tensor:
    """Angle (rad) between the joint's world-space ``direction`` and the ray to ``target`` (eq. 10).

    target (..., 3), direction (..., 3) in the joint frame, p_joint (..., 3), R_joint (..., 3, 3) -> (...).
    """
    to_target = torch.nn.functional.normalize(target - p_joint, dim=-1, eps=1e-8)
    facing = torch.nn.functional.normalize((R_joint @ direction[..., None])[..., 0], dim=-1, eps=1e-8)
    cross = torch.linalg.cross(to_target, facing, dim=-1).norm(dim=-1)
    return torch.atan2(cross, (to_target * facing).sum(-1))


def _weighted_mean(values: Tensor, weights: Tensor) -> Tensor:
    """Per-row weighted mean over effectors; rows with no weight give 0. (B, N), (B, N) -> (B,)."""
    return (values * weights).sum(1) / weights.sum(1).clamp_min(1e-12)


def protores_loss(out: IKOutput, R_local: Tensor, R_world: Tensor, p_world: Tensor, eff: EffectorBatch,
                  weight: Tensor, cfg: LossConfig) -> tuple[Tensor, dict[str, Tensor]]:
    """Total loss (scalar, mean over the batch) and its terms.

    Ground truth: R_local/R_world (B, J, 3, 3), p_world (B, J, 3). eff: the (noisy) inputs,
    weight (B, N): W(tolerance) per effector.
    """
    J = NUM_JOINTS
    bi = torch.arange(p_world.shape[0], device=p_world.device)[:, None]
    j = eff.joint
    w_pos = weight * ((eff.type == int(EffectorType.POSITION)) & eff.mask)
    w_rot = weight * ((eff.type == int(EffectorType.ROTATION)) & eff.mask)
    is_look = ((eff.type == int(EffectorType.LOOK_AT)) & eff.mask).to(weight.dtype)

    gt_eff = p_world[bi, j]
    gpd_rnd = _weighted_mean((out.draft[bi, j] - gt_eff).square().sum(-1), w_pos)
    ikd_rnd = _weighted_mean((out.p_world[bi, j] - gt_eff).square().sum(-1), w_pos)
    gpd_det = (out.draft - p_world).square().sum(-1).sum(-1)
    ikd_det = (out.p_world - p_world).square().sum(-1).sum(-1)
    loc_geo = geodesic_distance(R_local, out.R_local).sum(-1)
    glob_geo = _weighted_mean(geodesic_distance(R_world[bi, j], out.R_world[bi, j]), w_rot)
    lat = _weighted_mean(lookat_angle(eff.data[..., :3], eff.data[..., 3:], out.p_world[bi, j], out.R_world[bi, j]),
                         is_look)
    terms = {
        "gpd_rnd": gpd_rnd.mean(), "ikd_rnd": ikd_rnd.mean(), "gpd_det": gpd_det.mean(), "ikd_det": ikd_det.mean(),
        "loc_geo": loc_geo.mean(), "glob_geo": glob_geo.mean(), "lookat": lat.mean(),
    }
    total = (cfg.w_pos_rnd / J * (terms["gpd_rnd"] + terms["ikd_rnd"])
             + cfg.w_pos_det * (terms["gpd_det"] + terms["ikd_det"])
             + (cfg.w_lookat * terms["lookat"] + cfg.w_rot_global * terms["glob_geo"]
                + cfg.w_rot_local * terms["loc_geo"]) / J)
    return total, terms


def distillation_loss(out: IKOutput, teacher: IKOutput, cfg: LossConfig) -> Tensor:
    """Pull the network towards a teacher's answer (scalar, mean over the batch): the deterministic
    terms of :func:`protores_loss` with the teacher's pose as the target,
    ``w_pos_det (|draft - p_t|^2 + |p - p_t|^2) + w_rot_local / J * sum_j geodesic(R_t, R)``."""
    p_t = teacher.p_world.detach()
    det = (out.draft - p_t).square().sum(-1).sum(-1) + (out.p_world - p_t).square().sum(-1).sum(-1)
    loc = geodesic_distance(teacher.R_local.detach(), out.R_local).sum(-1)
    return (cfg.w_pos_det * det + cfg.w_rot_local / NUM_JOINTS * loc).mean()
