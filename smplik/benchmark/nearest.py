"""Nearest-neighbour baseline: the closest train pose on the position effectors.

:class:`NearestNeighborMethod`: scikit-learn ``NearestNeighbors`` over a subsample of the train
split. Features are the position-effector joints of each train pose (neutral body, beta = 0)
minus their centroid (translation invariant); an index is built per distinct set of position-
effector joints. Rotation and look-at effectors are ignored. The neighbour's local rotations are
put on the query body and translated so that its effector-joint centroid matches the query's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from smplik.body_model import BodyModelSet
from smplik.conventions import Gender
from smplik.kinematics import forward_kinematics
from smplik.rotations import axis_angle_to_matrix

from .evaluate import Prediction
from .files import BenchmarkSet
from .methods import position_targets


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
        w_pos, target = position_targets(eff)
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

