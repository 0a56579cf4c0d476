"""SMPL-IK: the ProtoRes network conditioned on SMPL shape (beta) and gender.

Pipeline (ProtoRes section 2 and App. A; SMPL-IK section 3):

1. Tokens: per effector ``[data (6), tolerance (1), joint embedding, type embedding, beta (10),
   gender one-hot (3)]``. Position data and look-at targets are made relative to the centroid of
   the position effectors (translation invariance); with no position effector the centroid is the
   origin.
2. Encoder: ``R`` blocks of ``L`` fully connected layers with the prototype-subtract-accumulate
   scheme (eq. 2-5); the pose embedding is ``p_R``.
3. GPD (global position decoder): ``[p_R, beta, gender]`` -> draft joint positions (24 x 3).
4. IKD (inverse kinematics decoder): ``[p_R, beta, gender, root-relative draft]`` -> 24 local 6D
   rotations. The root position is the GPD's pelvis.
5. FK with the rest skeleton ``J(beta, gender)`` -> global rotations and positions.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from smplik.configs import NETWORK_RANGES, NetworkConfig  # noqa: F401 - re-exported
from smplik.conventions import NUM_BETAS, NUM_JOINTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import forward_kinematics
from smplik.rotations import rot6d_to_matrix

NUM_GENDERS = 3
_IDENTITY_6D = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


@dataclass(frozen=True)
class IKOutput:
    """Network outputs, world frame. R_local/R_world (B, 24, 3, 3), p_world/draft (B, 24, 3),
    transl (B, 3) in smplx's convention (pelvis = J0(beta) + transl)."""

    R_local: Tensor
    R_world: Tensor
    p_world: Tensor
    draft: Tensor
    transl: Tensor


def _mlp(in_dim: int, width: int, layers: int, dropout: float) -> nn.Sequential:
    mods: list[nn.Module] = []
    for i in range(layers):
        mods += [nn.Linear(in_dim if i == 0 else width, width), nn.ReLU()]
        if dropout > 0:
            mods.append(nn.Dropout(dropout))
    return nn.Sequential(*mods)


class ResidualBlock(nn.Module):
    """FCR block (ProtoRes Fig. 4): ``h = MLP(x)``, ``b = relu(L x + h)``, ``f = F h``.

    The last block of a stack has no residual output ``b`` (nothing consumes it).
    """

    def __init__(self, in_dim: int, width: int, layers: int, out_dim: int, dropout: float, last: bool = False):
        super().__init__()
        self.mlp = _mlp(in_dim, width, layers, dropout)
        self.skip = None if last else nn.Linear(in_dim, width)
        self.forward_out = nn.Linear(width, out_dim)

    def forward(self, x: Tensor) -> tuple[Tensor | None, Tensor]:
        h = self.mlp(x)
        b = None if self.skip is None else torch.relu(self.skip(x) + h)
        return b, self.forward_out(h)


class FCRDecoder(nn.Module):
    """Fully connected residual decoder (eq. 6-7): outputs accumulate over blocks."""

    def __init__(self, in_dim: int, out_dim: int, cfg: NetworkConfig):
        super().__init__()
        w, L = cfg.width, cfg.layers_per_block
        self.blocks = nn.ModuleList(
            ResidualBlock(in_dim if r == 0 else w, w, L, out_dim, cfg.dropout, last=r == cfg.decoder_blocks - 1)
            for r in range(cfg.decoder_blocks)
        )

    def forward(self, x: Tensor) -> Tensor:
        out = 0
        for block in self.blocks:
            x, f = block(x)
            out = out + f
        return out


def masked_mean(x: Tensor, mask: Tensor) -> Tensor:
    """PROTOTYPE layer: mean over effectors. x (B, N, C), mask (B, N) -> (B, C)."""
    m = mask.to(x.dtype)[..., None]
    return (x * m).sum(1) / m.sum(1).clamp_min(1.0)


SLOT_FEATURES = 21
"""Per joint: position (3) + present + tolerance, rotation 6D (6) + present + tolerance,
look-at target (3) + direction (3) + present + tolerance."""


def effector_slots(eff: EffectorBatch, data: Tensor) -> Tensor:
    """Scatter effectors into per-joint slots. data (B, N, 6) centroid-relative -> (B, 24 * 21).

    Several effectors of one type on one joint are averaged; empty slots are zero.
    """
    onehot = nn.functional.one_hot(eff.joint, NUM_JOINTS).to(data.dtype) * eff.mask.to(data.dtype)[..., None]
    parts = []
    for kind, width in ((EffectorType.POSITION, 3), (EffectorType.ROTATION, 6), (EffectorType.LOOK_AT, 6)):
        sel = onehot * (eff.type == int(kind)).to(data.dtype)[..., None]  # (B, N, J)
        count = sel.sum(1)  # (B, J)
        denom = count.clamp_min(1.0)[..., None]
        values = torch.einsum("bnj,bnc->bjc", sel, data[..., :width]) / denom
        tol = torch.einsum("bnj,bn->bj", sel, eff.tolerance.to(data.dtype))[..., None] / denom
        parts += [values, (count > 0).to(data.dtype)[..., None], tol]
    return torch.cat(parts, dim=-1).reshape(data.shape[0], -1)


def position_centroid(eff: EffectorBatch) -> Tensor:
    """Centroid of the position effectors, the origin where there is none. -> (B, 3)."""
    is_pos = (eff.type == int(EffectorType.POSITION)) & eff.mask
    w = is_pos.to(eff.data.dtype)[..., None]
    return (eff.data[..., :3] * w).sum(1) / w.sum(1).clamp_min(1.0)


class ProtoResIK(nn.Module):
    """ProtoRes conditioned on beta and gender, with the SMPL rest skeletons as buffers.

    Args:
        cfg: network sizes.
        J_template: (3, 24, 3) rest joints at beta = 0 per gender (Gender order).
        J_dirs: (3, 24, 3, 10) rest-joint shape directions per gender.
    """

    def __init__(self, cfg: NetworkConfig, J_template: Tensor, J_dirs: Tensor):
        super().__init__()
        self.cfg = cfg
        J, E, w = NUM_JOINTS, cfg.embedding_dim, cfg.width
        self.register_buffer("J_template", J_template.clone().float())
        self.register_buffer("J_dirs", J_dirs.clone().float())
        self.joint_embedding = nn.Embedding(J, E)
        self.type_embedding = nn.Embedding(3, E)
        cond = NUM_BETAS + NUM_GENDERS
        token_dim = 6 + 1 + 2 * E + cond
        self.encoder = nn.ModuleList(
            ResidualBlock(token_dim if r == 0 else w, w, cfg.layers_per_block, w, cfg.dropout,
                          last=r == cfg.encoder_blocks - 1)
            for r in range(cfg.encoder_blocks)
        )
        slots = J * SLOT_FEATURES if cfg.effector_slots else 0
        self.gpd = FCRDecoder(w + cond + slots, 3 * J, cfg)
        self.ikd = FCRDecoder(w + cond + slots + 3 * J, 6 * J, cfg)
        self.register_buffer("identity_6d", torch.tensor(_IDENTITY_6D).repeat(J))

    def rest_joints(self, betas: Tensor, gender: Tensor) -> Tensor:
        """J(beta, gender): betas (B, 10), gender (B,) long -> (B, 24, 3)."""
        J, n = self.J_dirs.shape[1], self.J_dirs.shape[-1]
        dirs = self.J_dirs.view(-1, J * 3, n)[gender]  # one batched matmul: fewer operators than einsum at batch 1
        return torch.baddbmm(self.J_template[gender].view(-1, J * 3, 1), dirs, betas[..., None]).view(-1, J, 3)

    @staticmethod
    def relative_data(eff: EffectorBatch, centroid: Tensor) -> Tensor:
        """Effector data with positions and look-at targets relative to the centroid. -> (B, N, 6)."""
        shift = torch.where((eff.type == int(EffectorType.ROTATION))[..., None], 0.0, 1.0) * centroid[:, None, :]
        return torch.cat([eff.data[..., :3] - shift, eff.data[..., 3:]], dim=-1)

    def encode(self, eff: EffectorBatch, data: Tensor, cond: Tensor) -> Tensor:
        """Effector tokens (centroid-relative ``data`` (B, N, 6)) -> pose embedding p_R (B, width)."""
        B, N = eff.joint.shape
        x = torch.cat([data, eff.tolerance[..., None].to(data.dtype), self.joint_embedding(eff.joint),
                       self.type_embedding(eff.type), cond[:, None, :].expand(B, N, cond.shape[-1])], dim=-1)
        p = None
        for r, block in enumerate(self.encoder):
            if r > 0:
                x = torch.relu(x - p[:, None, :] / r)  # eq. (2): subtract the running prototype
            x, f = block(x)
            proto = masked_mean(f, eff.mask)
            p = proto if p is None else p + proto  # eq. (5): accumulate
        return p

    def forward(self, eff: EffectorBatch, betas: Tensor, gender: Tensor) -> IKOutput:
        """eff: B rows of N effectors; betas (B, 10); gender (B,) long in Gender order."""
        B = betas.shape[0]
        cond = torch.cat([betas, nn.functional.one_hot(gender, NUM_GENDERS).to(betas.dtype)], dim=-1)
        centroid = position_centroid(eff)
        data = self.relative_data(eff, centroid)
        p = self.encode(eff, data, cond)
        context = torch.cat([p, cond, effector_slots(eff, data)], -1) if self.cfg.effector_slots else \
            torch.cat([p, cond], -1)
        # Under autocast (training with precision "bf16") only the layers above run in low precision:
        # the outputs are cast back, and rotations and FK run in the input's precision.
        draft = self.gpd(context).view(B, NUM_JOINTS, 3).to(betas.dtype)
        root_relative = (draft - draft[:, :1]).reshape(B, -1)
        rot6d = self.ikd(torch.cat([context, root_relative], -1)).to(betas.dtype) + self.identity_6d
        with torch.autocast(betas.device.type, enabled=False):
            R_local = rot6d_to_matrix(rot6d.view(B, NUM_JOINTS, 6))
            J_rest = self.rest_joints(betas, gender)
            transl = draft[:, 0] - J_rest[:, 0] + centroid
            R_world, p_world = forward_kinematics(R_local, J_rest, transl)
        return IKOutput(R_local, R_world, p_world, draft + centroid[:, None, :], transl)
