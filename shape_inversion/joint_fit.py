"""The skeleton's mapped rest joints as retargeting places them on an SMPL body (SMPL-SI's joint fit).

Retargeting (:mod:`workflows.character`) turns every mapped custom joint ``k`` (SMPL joint ``j``) by the
rest alignment ``A_k``: the minimal rotation taking the custom direction from ``k`` to the joint mapped to
``j``'s aim child onto SMPL's direction of that bone; unmapped joints keep their mapped ancestor's rotation.
In SMPL's rest pose the custom joints therefore sit at

    ``q_m = q_a + A_a (P_m - P_a)``  (``a``: the nearest mapped ancestor of ``m`` in the custom hierarchy),

the character's own bone lengths laid along SMPL's bone directions. Comparing ``q`` with ``scale * J(beta)``
after a rigid alignment is the rest-pose residual of the mapped joints: what a body ``(beta, scale)`` costs
before any pose, whatever pose the character's file rests in (T, A, arms down). SMPL-SI's joint fit
(:meth:`shape_inversion.estimator.ShapeEstimator.estimate`) minimises it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, PARENTS
from smplik.data.retarget import swing_rotation

AIM_CHILD = {"pelvis": "spine1", "spine3": "neck"}
"""SMPL joints with several children aim at this one, or up the trunk past it when it is unmapped
(:func:`aim_children`); others at their first mapped child."""


@dataclass(frozen=True, eq=False)
class MappedRest:
    """A skeleton's mapped joints at rest.

    Attributes:
        smpl: (M,) SMPL joint index of each mapped joint.
        positions: (M, 3) rest positions, metres, in smplik's frame (y-up, facing +z: SMPL's rest frame; the
            rest alignments are minimal rotations, so a skeleton turned about its bones would be twisted).
        parents: (M,) index (into the M joints) of the nearest mapped ancestor in the skeleton's hierarchy,
            -1 for a joint without one; every parent comes before its children.
    """

    smpl: np.ndarray
    positions: np.ndarray
    parents: np.ndarray

    @classmethod
    def from_skeleton(cls, positions: np.ndarray, parents: Sequence[int], smpl_joints: Mapping[str, int]) -> MappedRest:
        """From a whole skeleton: positions (K, 3), parents (K,) (-1: root), SMPL joint name -> skeleton index."""
        mapped = {int(k): JOINT_INDEX[name] for name, k in smpl_joints.items() if name in JOINT_INDEX}

        def mapped_ancestor(k: int) -> int:
            p, seen = parents[k], 0
            while p >= 0 and p not in mapped and seen <= len(parents):
                p, seen = parents[p], seen + 1
            return p if p in mapped else -1

        def depth(k: int) -> int:
            d, p = 0, mapped_ancestor(k)
            while p >= 0 and d <= len(mapped):
                d, p = d + 1, mapped_ancestor(p)
            return d

        order = sorted(mapped, key=lambda k: (depth(k), k))
        slot = {k: m for m, k in enumerate(order)}
        anc = np.array([slot.get(mapped_ancestor(k), -1) for k in order], dtype=np.int64)
        return cls(np.array([mapped[k] for k in order], dtype=np.int64),
                   np.asarray(positions, dtype=np.float64)[order].reshape(-1, 3), anc)

    def __len__(self) -> int:
        return len(self.smpl)


def aim_children(smpl: np.ndarray) -> np.ndarray:
    """Per mapped joint (SMPL indices ``smpl`` (M,)), the index into ``smpl`` of its aim child, -1 if none.

    A joint with several SMPL children (:data:`AIM_CHILD`: the pelvis, spine3) aims up the trunk at the first
    mapped joint from its :data:`AIM_CHILD` on, through unmapped ones (spine1 -> spine2 -> spine3 -> neck ->
    head): a pelvis whose spine1 and spine2 are unmapped aims at spine3, as the retargeted unmapped joints keep
    its rotation, not sideways at a hip, whose direction from the root is the rig's convention (SMPL's hips sit
    below its pelvis, many rigs' level with their root). Without such a joint, and for every other joint: its
    first mapped SMPL child.
    """
    where = {int(j): m for m, j in enumerate(smpl)}
    out = np.full(len(smpl), -1, dtype=np.int64)
    for m, j in enumerate(smpl):
        chain = JOINT_INDEX.get(AIM_CHILD.get(JOINT_NAMES[int(j)], ""), -1)
        while chain >= 0 and chain not in where:  # up the trunk through unmapped joints
            chain = next((c for c in range(NUM_JOINTS) if PARENTS[c] == chain), -1)
        if chain >= 0:
            out[m] = where[chain]
            continue
        children = [c for c in range(NUM_JOINTS) if PARENTS[c] == j and c in where]
        out[m] = where[children[0]] if children else -1
    return out


def rest_alignments(positions: np.ndarray, smpl: np.ndarray, smpl_rest: np.ndarray) -> np.ndarray:
    """Rest alignments ``A`` (M, 3, 3): per mapped joint, custom aim direction -> SMPL's (identity without one).

    positions (M, 3) the mapped custom joints; smpl (M,) their SMPL joints; smpl_rest (24, 3) SMPL's rest joints.
    """
    aim = aim_children(smpl)
    has = aim >= 0
    A = np.broadcast_to(np.eye(3), (len(smpl), 3, 3)).copy()
    if has.any():
        d_custom = positions[aim[has]] - positions[has]
        d_smpl = smpl_rest[smpl[aim[has]]] - smpl_rest[smpl[has]]
        A[has] = swing_rotation(d_custom, d_smpl)
    return A


def reposed_rest(rest: MappedRest, smpl_rest: np.ndarray) -> np.ndarray:
    """The mapped joints (M, 3) with every bone turned onto SMPL's direction, as retargeting places them.

    ``smpl_rest`` (24, 3): SMPL's rest joints (any scale: only directions are used).
    """
    A = rest_alignments(rest.positions, rest.smpl, smpl_rest)
    q = rest.positions.copy()
    for m, a in enumerate(rest.parents):
        if a >= 0:
            q[m] = q[a] + A[a] @ (rest.positions[m] - rest.positions[a])
    return q
