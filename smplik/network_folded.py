"""``ProtoResIK.forward`` with its weights folded for inference: the same function in fewer, larger operations.

This is the graph :mod:`smplik.onnx_runtime` exports (one-pose latency there is per-operator overhead, about
1.5 us per node). Every fold is exact algebra, so the outputs equal the network's up to float32 rounding
(tested within 1e-5):

* The first layer of the encoder (its MLP and skip layers side by side) reads a token
  ``[data, tolerance, E_joint[j], E_type[t], beta, gender]``: the two embeddings go through it once, at
  folding time, into one table indexed by ``3 j + t``; the ``(beta, gender)`` parts of every first layer
  (encoder and both decoders) are one matmul plus one gathered row per pose.
* Token layers run on ``(B N, C)`` matrices (``Linear`` + ``ReLU`` export as ``Gemm`` that onnxruntime
  fuses); a block's forward layer ``F`` moves after the masked mean (``mean(F h) = F mean(h)``), so it
  runs once per pose instead of once per token.
* The decoders' outputs accumulate in the ``C`` input of their output ``Gemm``; the IKD reads the draft
  directly (the root-relative shift folded into its weights) and the 6D identity offset is a bias.
* J(beta, gender) and the bone offsets are one ``Gemm`` of beta for the three genders, the row's gender
  picked by a one-hot product. From the 6D outputs on, tensors are batch last, ``(C, J, B)``, so every
  elementwise operation runs over long contiguous rows (onnxruntime broadcasts over short inner axes slowly):
  the Gram-Schmidt writes the local transforms in :func:`~smplik.kinematics.compose_to_root`'s layout,
  whose FK takes four pointer-jumping rounds instead of eight tree levels.
"""

from __future__ import annotations

import copy

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from smplik.conventions import NUM_BETAS, NUM_JOINTS, PARENTS, EffectorType
from smplik.effectors import EffectorBatch
from smplik.kinematics import compose_to_root
from smplik.network import NUM_GENDERS, FCRDecoder, ProtoResIK, ResidualBlock, effector_slots

_EPS = 1e-8
"""Gram-Schmidt's norm floor (:func:`smplik.rotations.rot6d_to_matrix`)."""


def _hidden(block: ResidualBlock) -> list[nn.Linear]:
    return [m for m in block.mlp if isinstance(m, nn.Linear)]


class _Block(nn.Module):
    """A residual block after its first layer: the remaining MLP layers (weights as ``Gemm`` operands),
    the skip layer (None for a stack's last block) and the forward layer."""

    def __init__(self, block: ResidualBlock, first: bool):
        super().__init__()
        self.layers = nn.ModuleList(copy.deepcopy(_hidden(block)[1 if first else 0:]))
        self.skip = copy.deepcopy(block.skip) if not first else None
        self.forward_out = copy.deepcopy(block.forward_out)

    def hidden(self, h: Tensor) -> Tensor:
        for layer in self.layers:
            h = torch.relu(layer(h))
        return h


class FoldedProtoResIK(nn.Module):
    """A :class:`ProtoResIK` (eval mode; its weights are read once) folded for inference.

    ``forward(joint, type, data, tolerance, mask, betas, gender)`` takes the tensors of an
    :class:`~smplik.effectors.EffectorBatch` (B rows of N effectors) and the body, betas (B, 10) and
    gender (B,) long, and returns ``(R_local, R_world, p_world, draft, transl)`` as ``ProtoResIK.forward``'s
    :class:`~smplik.network.IKOutput` holds them.
    """

    def __init__(self, model: ProtoResIK):
        super().__init__()
        cfg = model.cfg
        w, E, J = cfg.width, cfg.embedding_dim, NUM_JOINTS
        cond_dim = NUM_BETAS + NUM_GENDERS
        self.width, self.slots = w, cfg.effector_slots
        f = {"dtype": model.J_template.dtype}  # constants in the model's float type
        with torch.no_grad():
            # --- encoder block 0: MLP layer 0 and the skip layer on the token, side by side.
            enc0 = model.encoder[0]
            first = [_hidden(enc0)[0]] + ([enc0.skip] if enc0.skip is not None else [])
            W0 = torch.cat([lin.weight for lin in first])  # (K, 7 + 2E + 13)
            b0 = torch.cat([lin.bias for lin in first])
            self.register_buffer("W_token", W0[:, :7].T.contiguous())  # data (6) and tolerance (1)
            table = (model.joint_embedding.weight @ W0[:, 7:7 + E].T)[:, None, :] + \
                (model.type_embedding.weight @ W0[:, 7 + E:7 + 2 * E].T)[None, :, :]
            self.register_buffer("joint_type_table", table.reshape(J * 3, -1))  # row 3 j + t
            cond_parts = [(W0[:, 7 + 2 * E:], b0)]
            # --- decoders' first layers: [p, cond, slots] (GPD) and [p, cond, slots, root-relative draft] (IKD).
            slots = J * 21 if cfg.effector_slots else 0
            self.gpd_first = self._decoder_first(model.gpd, w, cond_dim, slots, None, cond_parts)
            # draft @ root_relative = draft - draft[root] on flattened (B, 3J) drafts
            tile = torch.cat([torch.eye(3, **f).repeat(1, J), torch.zeros(3, 3 * J, **f)])  # (6, 3J)
            root_relative = torch.eye(3 * J, **f) - torch.cat([tile[:3], torch.zeros(3 * J - 3, 3 * J, **f)])
            self.ikd_first = self._decoder_first(model.ikd, w, cond_dim, slots, root_relative, cond_parts)
            W_cond = torch.cat([W for W, _ in cond_parts])  # (sum K, 13)
            self.register_buffer("W_betas", W_cond[:, :NUM_BETAS].T.contiguous())
            self.register_buffer("gender_rows", (W_cond[:, NUM_BETAS:].T + torch.cat([b for _, b in cond_parts]))
                                 .contiguous())
            self.cond_sizes = [W.shape[0] for W, _ in cond_parts]
            # --- rest skeleton: per gender, beta -> [bone offsets (72; root row 0), J_rest[0] (3)].
            J_template, J_dirs = model.J_template, model.J_dirs  # (3, 24, 3), (3, 24, 3, 10)
            parent = torch.tensor([max(p, 0) for p in PARENTS])
            not_root = (torch.arange(J) > 0).to(J_template.dtype)
            off_t = (J_template - J_template[:, parent]) * not_root[:, None]
            off_d = (J_dirs - J_dirs[:, parent]) * not_root[:, None, None]
            # all three genders in one Gemm, (10, 3 * 75) and (3 * 75,); offsets component-major (c J + j)
            rest_t = torch.cat([off_t.transpose(1, 2).reshape(3, -1), J_template[:, 0]], -1)  # (3, 75)
            rest_d = torch.cat([off_d.permute(0, 2, 1, 3).reshape(3, -1, NUM_BETAS), J_dirs[:, 0]], 1)  # (3, 75, 10)
            self.register_buffer("rest_template", rest_t.reshape(-1))
            self.register_buffer("rest_dirs", rest_d.permute(2, 0, 1).reshape(NUM_BETAS, -1).contiguous())
            self.register_buffer("gender_onehot", torch.eye(3, **f)[:, :, None])  # (3, 3, 1): selects a gender
            root_row = torch.zeros(3, 3, J, **f)
            root_row[:, :, 0] = torch.eye(3, **f)
            self.register_buffer("root_row", root_row.reshape(3, -1))  # pelvis -> the root's translation
            # (6, 3J): the centroid's xyz (columns 0-2 of the 6-wide centroid) added to every joint
            self.register_buffer("centroid_tile", tile)
            # per effector type: is it a position effector, and which data columns the centroid shifts
            self.register_buffer("position_type", (torch.arange(3) == int(EffectorType.POSITION)).to(**f)[:, None])
            shifted = (torch.arange(3) != int(EffectorType.ROTATION)).to(**f)[:, None] * \
                torch.tensor([1.0, 1, 1, 0, 0, 0], **f)
            self.register_buffer("centroid_shift", shifted)
            # cross product of the columns [b1, b2] (6): (b1.yzx, b1.zxy) * (b2.zxy, b2.yzx), then first - second
            self.register_buffer("cross_left", torch.tensor([1, 2, 0, 2, 0, 1]))
            self.register_buffer("cross_right", torch.tensor([5, 3, 4, 4, 5, 3]))
        self.encoder = nn.ModuleList(_Block(b, r == 0) for r, b in enumerate(model.encoder))
        self.gpd = nn.ModuleList(_Block(b, r == 0) for r, b in enumerate(model.gpd.blocks))
        self.ikd = nn.ModuleList(_Block(b, r == 0) for r, b in enumerate(model.ikd.blocks))
        with torch.no_grad():
            self.register_buffer("gpd_bias", sum(b.forward_out.bias for b in model.gpd.blocks))
            # the IKD's outputs component-major (k J + j, not 6 j + k), so that they go batch last as (6, J, B)
            order = torch.arange(6 * J).reshape(J, 6).T.reshape(-1)
            for block in self.ikd:
                block.forward_out.weight.copy_(block.forward_out.weight[order])
            self.register_buffer("ikd_bias", (sum(b.forward_out.bias for b in model.ikd.blocks)
                                              + model.identity_6d)[order])
        self.requires_grad_(False)
        self.eval()

    def _decoder_first(self, decoder: FCRDecoder, w: int, cond_dim: int, slots: int, draft_map: Tensor | None,
                       cond_parts: list) -> nn.ParameterList:
        """The decoder's block-0 MLP and skip layers as ``(W (in, out), cond)`` with ``in`` = [p, slots, draft]
        (the draft through ``draft_map``); the (beta, gender) columns and biases go to ``cond_parts``."""
        block = decoder.blocks[0]
        weights = []
        for lin in [_hidden(block)[0]] + ([block.skip] if block.skip is not None else []):
            W = lin.weight  # (out, w + 13 + slots [+ 72])
            pieces = [W[:, :w], W[:, w + cond_dim:w + cond_dim + slots]]
            if draft_map is not None:
                pieces.append((draft_map @ W[:, w + cond_dim + slots:].T).T)
            weights.append(nn.Parameter(torch.cat(pieces, 1).T.contiguous(), requires_grad=False))
            cond_parts.append((W[:, w:w + cond_dim], lin.bias))
        return nn.ParameterList(weights)

    def _decode(self, first: nn.ParameterList, blocks: nn.ModuleList, x: Tensor, cond: tuple[Tensor, ...],
                bias: Tensor) -> Tensor:
        """FCR decoder (eq. 6-7) on x = [p, slots, draft] (B, in), block 0's (beta, gender) rows in ``cond``."""
        out = None
        for r, block in enumerate(blocks):
            h = block.hidden(torch.relu(torch.addmm(cond[0], x, first[0])) if r == 0 else x)
            if r < len(blocks) - 1:
                x = torch.relu((torch.addmm(cond[1], x, first[1]) if r == 0 else block.skip(x)) + h)
            out = F.linear(h, block.forward_out.weight, bias) if out is None else \
                torch.addmm(out, h, block.forward_out.weight.T)
        return out

    def forward(self, joint: Tensor, type: Tensor, data: Tensor, tolerance: Tensor, mask: Tensor, betas: Tensor,
                gender: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        w, J = self.width, NUM_JOINTS
        # Centroid of the position effectors (B, 6; columns 3-5 unused) and the centroid-relative data.
        mask_f = mask.unsqueeze(-1).to(data.dtype)  # (B, N, 1)
        w_pos = self.position_type[type] * mask_f
        centroid = (data * w_pos).sum(1) / w_pos.sum(1).clamp_min(1.0)
        data_rel = data - self.centroid_shift[type] * centroid[:, None, :]
        w_mean = mask_f / mask_f.sum(1, keepdim=True).clamp_min(1.0)
        # (beta, gender) rows of every first layer.
        cond = torch.addmm(self.gender_rows[gender], betas, self.W_betas).split(self.cond_sizes, -1)
        # Encoder block 0 on (B, N, K), then every token layer on (B N, C).
        z = torch.cat([data_rel, tolerance.unsqueeze(-1)], -1) @ self.W_token + \
            self.joint_type_table[joint * 3 + type] + cond[0][:, None, :]
        p = None
        x = None
        for r, block in enumerate(self.encoder):
            if r == 0:
                parts = z.split(w, -1)
                tokens = parts[0]  # (B, N, w): the shape every per-pose broadcast reshapes to
                h = block.hidden(torch.relu(tokens.reshape(-1, w)))
                if len(parts) > 1:
                    x = torch.relu(parts[1].reshape(-1, w) + h)
            else:
                x = torch.relu(x.view_as(tokens) - (p if r == 1 else p / r)[:, None, :]).reshape(-1, w)
                h = block.hidden(x)
                if block.skip is not None:
                    x = torch.relu(block.skip(x) + h)
            mean = (h.view_as(tokens) * w_mean).sum(1)  # (B, w)
            proto = block.forward_out(mean)
            p = proto if p is None else p + proto
        gpd_cond, ikd_cond = cond[1:1 + len(self.gpd_first)], cond[1 + len(self.gpd_first):]
        context = p
        if self.slots:
            eff = EffectorBatch(joint, type, data_rel, tolerance, mask)
            context = torch.cat([p, effector_slots(eff, data_rel)], -1)
        draft = self._decode(self.gpd_first, self.gpd, context, gpd_cond, self.gpd_bias)  # (B, 3J) centroid-relative
        rot6d = self._decode(self.ikd_first, self.ikd, torch.cat([context, draft], -1), ikd_cond, self.ikd_bias)
        draft = torch.addmm(draft, centroid, self.centroid_tile)
        pelvis = draft[:, :3]
        # Rest skeleton: bone offsets and J_rest[0] of (beta, gender).
        rest = torch.addmm(self.rest_template, betas, self.rest_dirs).reshape(-1, 3, 3 * J + 3)
        rest = (rest * self.gender_onehot[gender]).sum(1)  # the row's gender: exact (one 1, two 0)
        offsets, J0 = rest.split([3 * J, 3], -1)
        t = torch.addmm(offsets, pelvis, self.root_row)  # (B, 3J); the root's: J0 + transl = pelvis
        # Batch last from here, (C, J, B): each operation runs over contiguous rows of J B values, and each
        # output goes batch-first with one block transpose and one 2-D transpose.
        # 6D -> rotation columns b1, b2, b3 (Gram-Schmidt, ProtoRes eq. 14), each (3, J, B).
        a1, a2 = rot6d.T.reshape(6, J, -1).split(3, 0)
        b1 = a1 / a1.norm(dim=0, keepdim=True).clamp_min(_EPS)
        a2 = a2 - (b1 * a2).sum(0, keepdim=True) * b1
        b2 = a2 / a2.norm(dim=0, keepdim=True).clamp_min(_EPS)
        b12 = torch.cat([b1, b2], 0)
        # b3 = b1 x b2 = b1.yzx * b2.zxy - b1.zxy * b2.yzx: two gathers, one product, one difference
        left, right = (b12[self.cross_left] * b12[self.cross_right]).split(3, 0)
        R_local = torch.stack([b1, b2, left - right], 1)  # (3, 3, J, B)
        T_world = compose_to_root(torch.cat([R_local, t.T.reshape(3, 1, J, -1)], 1))  # (3, 4, J, B)
        R_world, p_world = T_world.split([3, 1], 1)
        R_local, R_world = (R.permute(2, 0, 1, 3).reshape(9 * J, -1).T.reshape(-1, J, 3, 3) for R in (R_local, R_world))
        p_world = p_world.reshape(3, J, -1).transpose(0, 1).reshape(3 * J, -1).T.reshape(-1, J, 3)
        return R_local, R_world, p_world, draft.reshape(-1, J, 3), pelvis - J0
