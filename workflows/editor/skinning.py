"""Fast linear blend skinning of the SMPL mesh from posed joint transforms (numpy, float32).

The editor redraws a mesh on every gizmo update, so it skins in numpy from the world transforms
it already has instead of calling smplx (:meth:`smplik.body_model.BodyModel.vertices`, which gives
the same vertices; the tests compare both). SMPL's model, per vertex ``v``::

    v_shaped = v_template + shapedirs @ betas
    v_posed  = v_shaped + posedirs @ (R_parent_joint[1:] - I).flatten()     # pose correctives
    v_world  = sum_j weights[v, j] (R_world_joint[j] (v_posed - J_rest[j]) + p_world_joint[j])

The built-in model has no pose correctives (``posedirs`` = 0); they are skipped when all zero.
Shaped vertices are cached per ``betas`` by the caller (:meth:`Skinner.shaped`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplik.body_model import BodyModel
from smplik.conventions import NUM_BETAS, NUM_JOINTS


@dataclass(frozen=True, eq=False)
class ShapedBody:
    """A body at one shape: ``v_shaped`` (V, 3) float32 and rest joints ``J_rest`` (24, 3) float32."""

    betas: np.ndarray
    v_shaped: np.ndarray
    J_rest: np.ndarray


@dataclass(frozen=True, eq=False)
class Skinner:
    """Skinning arrays of one body model (float32).

    Attributes:
        v_template: (V, 3); shapedirs: (V * 3, 10); posedirs: (207, V * 3) or None when all zero;
        weights: (V, 24); J_regressor: (24, V); faces: (F, 3) int32.
    """

    v_template: np.ndarray
    shapedirs: np.ndarray
    posedirs: np.ndarray | None
    weights: np.ndarray
    J_regressor: np.ndarray
    faces: np.ndarray

    @classmethod
    def from_model(cls, model: BodyModel) -> Skinner:
        a = model.arrays
        V = model.num_vertices
        shapedirs = np.asarray(a["shapedirs"][:, :, :NUM_BETAS], np.float32).reshape(V * 3, NUM_BETAS)
        pd = np.asarray(a["posedirs"], np.float32)
        posedirs = pd.reshape(V * 3, -1).T.copy() if pd.shape == (V, 3, 207) else pd  # smplx's (207, V * 3)
        return cls(np.asarray(a["v_template"], np.float32), shapedirs,
                   None if not np.any(posedirs) else posedirs, np.asarray(a["weights"], np.float32),
                   np.asarray(a["J_regressor"], np.float32), np.asarray(a["f"], np.int32))

    def shaped(self, betas: np.ndarray) -> ShapedBody:
        """The body at shape ``betas`` (10,)."""
        b = np.asarray(betas, np.float32).reshape(NUM_BETAS)
        v = self.v_template + (self.shapedirs @ b).reshape(-1, 3)
        return ShapedBody(b.copy(), v, self.J_regressor @ v)

    def skin(self, body: ShapedBody, R_world: np.ndarray, p_world: np.ndarray,
             R_local: np.ndarray | None = None) -> np.ndarray:
        """Posed vertices (V, 3) float32.

        Args:
            body: the shaped body (its rest joints must be those the pose was solved on).
            R_world: (24, 3, 3) ``R_world_joint``; p_world: (24, 3) posed joint positions.
            R_local: (24, 3, 3) ``R_parent_joint``, needed only for models with pose correctives.
        """
        R = np.asarray(R_world, np.float32)
        t = np.asarray(p_world, np.float32) - np.einsum("jab,jb->ja", R, body.J_rest)
        A = np.concatenate([R, t[:, :, None]], axis=2).reshape(NUM_JOINTS, 12)  # (24, 3x4)
        M = (self.weights @ A).reshape(-1, 3, 4)  # (V, 3, 4) blended transforms
        v = body.v_shaped
        if self.posedirs is not None:
            if R_local is None:
                raise ValueError("This body model has pose correctives: skin() needs R_local (24, 3, 3).")
            feature = (np.asarray(R_local[1:], np.float32) - np.eye(3, dtype=np.float32)).reshape(-1)
            v = v + (feature @ self.posedirs).reshape(-1, 3)
        return np.einsum("vab,vb->va", M[:, :, :3], v) + M[:, :, 3]
