"""Training windows for the tracking model: pose-cache clips -> random bodies -> synthetic tracker signals.

Per window (all vectorised over the batch): a clip segment of ``length`` frames; a body drawn as the IK
model's training draws it (DESIGN section 4: the dataset's beta plus unit Gaussian noise, N(0, I) for BVH
clips; gender uniform); the segment's height moved so that the new body's feet stand on the clip's floor (the
mean difference of the lowest foot between the recorded and the new skeleton); left/right mirroring with
probability 0.5; FK; trackers = the tracked joints' world positions and rotations, with Gaussian position
noise of a per-window sigma in [0, ``noise_m``]; non-reference trackers lose their rotation with probability
``rotation_dropout``. Truth foot contacts come from the animation pipeline's detector
(:func:`smplik.contacts.foot_contacts`) on the recorded skeleton, once per clip.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import JOINT_INDEX, LEFT_RIGHT, NUM_BETAS, Gender
from smplik.data.dataset import PoseDataset
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix
from smplik.symmetry import mirror_pose
from smplik.tracking.features import pose_targets, tracker_features

FEET = (JOINT_INDEX["left_foot"], JOINT_INDEX["right_foot"])


@dataclass(frozen=True)
class WindowBatch:
    """One batch of B windows of T frames.

    Attributes: x (B, T, F) features; body (B, 13) beta and gender one-hot; target (B, T, 147); contact (B, T, 2)
    float; R_local (B, T, 24, 3, 3); transl (B, T, 3); J_rest (B, 24, 3); p_world (B, T, 24, 3);
    yaw (B, T); origin (B, T, 3); betas (B, 10); gender (B,) long.
    """

    x: Tensor
    body: Tensor
    target: Tensor
    contact: Tensor
    R_local: Tensor
    transl: Tensor
    J_rest: Tensor
    p_world: Tensor
    yaw: Tensor
    origin: Tensor
    betas: Tensor
    gender: Tensor


def body_vector(betas: Tensor, gender: Tensor) -> Tensor:
    """(..., 13): beta (..., 10) and the one-hot of gender (...) long."""
    return torch.cat([betas, torch.nn.functional.one_hot(gender, len(Gender)).to(betas)], dim=-1)


def clip_contacts(p_world: np.ndarray, fps: float) -> np.ndarray:
    """Truth foot contacts (T, 2) bool of joints (T, 24, 3) by the animation pipeline's detector."""
    from smplik.contacts import ContactConfig, foot_contacts

    return foot_contacts(p_world, fps, ContactConfig())


class WindowSampler:
    """Random windows of one split of a pose cache (see the module docstring)."""

    def __init__(self, dataset: PoseDataset, body_models: BodyModelSet, *, trackers: tuple[str, ...], length: int,
                 batch: int, generator: torch.Generator, beta_noise: float = 1.0, noise_m: float = 0.0,
                 rotation_dropout: float = 0.0, augment: bool = True) -> None:
        self.body_models = body_models
        self.trackers = torch.tensor([JOINT_INDEX[n] for n in trackers])
        self.length, self.batch, self.generator = length, batch, generator
        self.beta_noise, self.noise_m = beta_noise, noise_m
        self.rotation_dropout, self.augment = rotation_dropout, augment
        self.fps = dataset.fps
        self.pose = dataset.pose.float()
        self.transl = dataset.transl.float()
        self.betas = dataset.betas.float()
        self.has_betas = dataset.has_betas.bool()
        gender = dataset.gender.clone()
        self.gender = torch.where(gender < 0, torch.zeros_like(gender), gender)
        # clip boundaries (rows of a clip are consecutive in a cache)
        cid = dataset.clip_id.numpy()
        change = np.nonzero(np.diff(cid))[0] + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [len(cid)]])
        keep = (ends - starts) >= length
        self.starts, self.ends = starts[keep], ends[keep]
        if len(self.starts) == 0:
            raise ValueError(f"No clip has {length} frames in {dataset.source or 'the dataset'}.")
        # per frame: truth contacts and the lowest foot height on the recorded skeleton
        self.contact = torch.zeros(len(cid), 2)
        self.foot_low = torch.zeros(len(cid))
        for s, e in zip(starts, ends, strict=True):
            J = body_models.rest_joints(self.betas[s], self.gender[s])
            _, p = forward_kinematics(axis_angle_to_matrix(self.pose[s:e]), J, self.transl[s:e])
            self.contact[s:e] = torch.from_numpy(clip_contacts(p.numpy().astype(np.float64), self.fps)).float()
            self.foot_low[s:e] = p[:, list(FEET), 1].min(-1).values
        weights = (self.ends - self.starts - length + 1).astype(np.float64)
        self.clip_weights = torch.from_numpy(weights / weights.sum())

    def sample(self) -> WindowBatch:
        """One batch."""
        g, B, T = self.generator, self.batch, self.length
        clip = torch.multinomial(self.clip_weights, B, replacement=True, generator=g).numpy()
        span = self.ends[clip] - self.starts[clip] - T + 1
        start = self.starts[clip] + (torch.rand(B, generator=g).numpy() * span).astype(np.int64)
        rows = torch.from_numpy(start[:, None] + np.arange(T)[None, :])  # (B, T)
        return self.make(rows)

    def make(self, rows: Tensor) -> WindowBatch:
        """The batch of windows at cache rows (B, T) (consecutive frames of one clip each)."""
        g = self.generator
        B, T = rows.shape
        R_local = axis_angle_to_matrix(self.pose[rows])
        transl = self.transl[rows].clone()
        first = rows[:, 0]
        noise = torch.randn(B, NUM_BETAS, generator=g)
        betas = torch.where(self.has_betas[first, None], self.betas[first] + self.beta_noise * noise, noise)
        gender = torch.randint(len(Gender), (B,), generator=g)
        J_rest = self.body_models.rest_joints(betas, gender)
        contact = self.contact[rows].clone()
        if self.augment:
            mirror = torch.rand(B, generator=g) < 0.5
            R_m, t_m = mirror_pose(R_local, transl, J_rest[:, None, 0])
            R_local = torch.where(mirror[:, None, None, None, None], R_m, R_local)
            transl = torch.where(mirror[:, None, None], t_m, transl)
            contact = torch.where(mirror[:, None, None], contact.flip(-1), contact)
        R_world, p_world = forward_kinematics(R_local, J_rest[:, None], transl)
        lift = (self.foot_low[rows] - p_world[..., list(FEET), 1].min(-1).values).mean(1)  # (B,)
        transl[..., 1] += lift[:, None]
        p_world = p_world + lift[:, None, None, None] * p_world.new_tensor([0.0, 1.0, 0.0])
        p_trk = p_world[:, :, self.trackers].clone()
        R_trk = R_world[:, :, self.trackers]
        if self.noise_m > 0:
            sigma = torch.rand(B, 1, 1, 1, generator=g) * self.noise_m
            p_trk = p_trk + sigma * torch.randn(p_trk.shape, generator=g)
        has_rot = torch.ones(B, len(self.trackers), dtype=torch.bool)
        if self.rotation_dropout > 0:
            has_rot[:, 1:] = torch.rand(B, len(self.trackers) - 1, generator=g) >= self.rotation_dropout
        x, yaw, origin = tracker_features(p_trk, R_trk, has_rot, self.fps)
        target = pose_targets(R_local, p_world[..., 0, :], yaw, origin)
        return WindowBatch(x=x, body=body_vector(betas, gender), target=target, contact=contact, R_local=R_local,
                           transl=transl, J_rest=J_rest, p_world=p_world, yaw=yaw, origin=origin, betas=betas,
                           gender=gender)


def mirror_contacts(contact: Tensor) -> Tensor:
    """Left/right swap of (..., 2) contacts (kept for symmetry with :data:`LEFT_RIGHT`)."""
    assert LEFT_RIGHT[FEET[0]] == FEET[1]
    return contact.flip(-1)
