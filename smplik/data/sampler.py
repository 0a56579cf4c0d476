"""Training batches: random poses from a :class:`PoseDataset` on random bodies, augmented.

Per sample (SMPL-IK F.2, DESIGN section 4), all vectorised over the batch:

1. a frame drawn uniformly from the dataset;
2. a body: ``beta = dataset beta + beta_noise * N(0, I)`` when the source has betas, else
   ``N(0, I)``; gender uniform over neutral, male, female; rest joints ``J(beta, gender)``;
3. part swap (optional, ``part_swap`` > 0): each limb (:data:`~smplik.conventions.LIMB_CHAINS`:
   arms from the collar, legs from the hip) independently takes, with probability ``part_swap``,
   its local rotations from another random frame, so limbs meet torsos they were never recorded
   with (more pose combinations from the same clips);
4. augmentation (optional): left/right mirroring with probability 0.5 (:func:`mirror_pose`),
   then a rotation about the vertical (y) axis by an angle uniform in [0, 2 pi)
   (:func:`rotate_about_vertical`), both about the body's rest pelvis so that the pelvis
   moves as the whole body does;
5. global joint rotations and positions by our FK.

Mirroring reflects across the x = 0 plane with ``M = diag(-1, 1, 1)``: local rotations become
``M R M`` (axis-angle ``(x, y, z) -> (x, -y, -z)``), left and right
joints swap (:data:`LEFT_RIGHT`), and the posed pelvis reflects. On a mirror-symmetric rest
skeleton (the built-in model is exactly symmetric, real SMPL nearly) the mirrored pose's joint
``j`` lands on the reflection of the original joint ``LEFT_RIGHT[j]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import JOINT_INDEX, LIMB_CHAINS, NUM_BETAS, Gender
from smplik.data.dataset import PoseDataset
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix
from smplik.symmetry import mirror_pose, rotate_about_vertical, rotation_about_y

__all__ = ["PoseBatch", "PoseSampler", "mirror_pose", "rotate_about_vertical", "rotation_about_y"]

@dataclass(frozen=True)
class PoseBatch:
    """One training batch of posed bodies (float32 unless noted).

    Attributes:
        R_local: (B, 24, 3, 3) local rotations ``R_parent_joint`` (joint 0: the root's global rotation).
        transl: (B, 3) smplx translation (the pelvis is at ``J_rest[:, 0] + transl``).
        betas: (B, 10) body shape.
        gender: (B,) long :class:`Gender` index.
        J_rest: (B, 24, 3) rest joints ``J(beta, gender)``.
        R_world: (B, 24, 3, 3) global joint rotations.
        p_world: (B, 24, 3) global joint positions.
    """

    R_local: Tensor
    transl: Tensor
    betas: Tensor
    gender: Tensor
    J_rest: Tensor
    R_world: Tensor
    p_world: Tensor

    def __len__(self) -> int:
        return int(self.R_local.shape[0])


class PoseSampler:
    """Draws :class:`PoseBatch` es from a dataset on random bodies (see the module docstring).

    All randomness comes from ``generator``: two samplers with equally seeded generators give
    identical batches. ``max_cached_bytes`` caps the memory of the precomputed local rotation
    matrices (above it they are computed per batch). A batch of 2048 takes about 10 ms on one
    CPU thread, two thirds of it in :func:`forward_kinematics`.
    """

    def __init__(self, dataset: PoseDataset, body_models: BodyModelSet, *, batch_size: int,
                 generator: torch.Generator, augment: bool = True, beta_noise: float = 1.0,
                 part_swap: float = 0.0, max_cached_bytes: int = 1 << 30) -> None:
        if len(dataset) == 0:
            raise ValueError("Cannot sample from an empty dataset.")
        if batch_size < 1:
            raise ValueError(f"batch_size must be positive, got {batch_size}.")
        if beta_noise < 0:
            raise ValueError(f"beta_noise must be non-negative, got {beta_noise}.")
        if not 0.0 <= part_swap <= 1.0:
            raise ValueError(f"part_swap must be a probability in [0, 1], got {part_swap}.")
        self.dataset = dataset
        self.body_models = body_models
        self.batch_size = int(batch_size)
        self.generator = generator
        self.augment = augment
        self.beta_noise = float(beta_noise)
        self.part_swap = float(part_swap)
        pose = dataset.pose.float()
        # Local rotation matrices are precomputed when they fit (36 floats per frame), which
        # saves the per-batch Rodrigues; otherwise they are computed per batch.
        self._R_local = axis_angle_to_matrix(pose) if pose.numel() * 12 <= max_cached_bytes else None
        self._pose = pose.contiguous()
        self._transl = dataset.transl.float().contiguous()
        self._betas = dataset.betas.float().contiguous()
        self._has_betas = dataset.has_betas.bool()[:, None]

    def _local_rotations(self, idx: Tensor) -> Tensor:
        """Local rotation matrices of frames ``idx`` (K,) -> (K, 24, 3, 3), a fresh tensor."""
        return self._R_local[idx] if self._R_local is not None else axis_angle_to_matrix(self._pose[idx])

    def sample(self) -> PoseBatch:
        """One batch of ``batch_size`` samples."""
        g, B = self.generator, self.batch_size
        idx = torch.randint(len(self.dataset), (B,), generator=g)
        R_local = self._local_rotations(idx)
        if self.part_swap > 0:  # draws nothing at 0: the stream (and a resumed run) stays the same
            for chain in LIMB_CHAINS.values():
                cols = torch.tensor([JOINT_INDEX[n] for n in chain])
                donor = torch.randint(len(self.dataset), (B,), generator=g)
                swap = torch.rand(B, generator=g) < self.part_swap
                R_local[:, cols] = torch.where(swap[:, None, None, None], self._local_rotations(donor)[:, cols],
                                               R_local[:, cols])
        transl = self._transl[idx]
        noise = torch.randn(B, NUM_BETAS, generator=g)
        betas = torch.where(self._has_betas[idx], self._betas[idx] + self.beta_noise * noise, noise)
        gender = torch.randint(len(Gender), (B,), generator=g)
        J_rest = self.body_models.rest_joints(betas, gender)
        if self.augment:
            J0 = J_rest[:, 0]
            mirror = torch.rand(B, generator=g) < 0.5
            angle = torch.rand(B, generator=g) * (2 * math.pi)
            R_m, transl_m = mirror_pose(R_local, transl, J0)
            R_local = torch.where(mirror[:, None, None, None], R_m, R_local)
            transl = torch.where(mirror[:, None], transl_m, transl)
            R_local, transl = rotate_about_vertical(R_local, transl, angle, J0)
        R_world, p_world = forward_kinematics(R_local, J_rest, transl)
        return PoseBatch(R_local=R_local, transl=transl, betas=betas, gender=gender, J_rest=J_rest,
                         R_world=R_world, p_world=p_world)
