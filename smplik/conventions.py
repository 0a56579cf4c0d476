"""Conventions shared by every part of smplik, written down once.

* Units are metres. The world frame is **y-up** (SMPL's template frame); the body faces +z
  in its rest pose and its left side is at +x.
* The skeleton is SMPL's 24-joint tree, in SMPL order (:data:`JOINT_NAMES`), with
  :data:`PARENTS` giving each joint's parent index (-1 for the root).
* A pose is SMPL's: ``global_orient (3)``, ``body_pose (23, 3)`` (axis-angle, radians, each
  rotation relative to the parent joint's frame, ``R_parent_joint``) and ``transl (3)`` with
  smplx's meaning: the root rotates about the rest pelvis ``J0(beta)`` and ``transl`` is added
  afterwards, so the posed pelvis is at ``J0(beta) + transl``.
* 6D rotations are the first two **columns** of the rotation matrix (Zhou et al. 2019),
  laid out as ``[R[:, 0], R[:, 1]]``. Quaternions are scalar-first ``(w, x, y, z)``.
* beta has :data:`NUM_BETAS` = 10 components. Gender is the :class:`Gender` enum; the network
  receives it as a one-hot vector of 3 in :class:`Gender` order.
"""

from __future__ import annotations

from enum import Enum

NUM_JOINTS = 24
NUM_BETAS = 10

JOINT_NAMES: tuple[str, ...] = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hand",
    "right_hand",
)

PARENTS: tuple[int, ...] = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)

JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}


def _mirror_map() -> tuple[int, ...]:
    out = []
    for name in JOINT_NAMES:
        if name.startswith("left_"):
            out.append(JOINT_INDEX["right_" + name[5:]])
        elif name.startswith("right_"):
            out.append(JOINT_INDEX["left_" + name[6:]])
        else:
            out.append(JOINT_INDEX[name])
    return tuple(out)


LEFT_RIGHT: tuple[int, ...] = _mirror_map()
"""``LEFT_RIGHT[j]`` is the joint that mirrors joint ``j`` across the body's sagittal (x = 0) plane."""

ZONES: dict[str, tuple[str, ...]] = {
    "pelvis_hips": ("pelvis", "left_hip", "right_hip"),
    "torso_head": ("spine1", "spine2", "spine3", "neck", "head"),
    "left_arm": ("left_collar", "left_shoulder", "left_elbow", "left_wrist", "left_hand"),
    "right_arm": ("right_collar", "right_shoulder", "right_elbow", "right_wrist", "right_hand"),
    "left_leg": ("left_knee", "left_ankle", "left_foot"),
    "right_leg": ("right_knee", "right_ankle", "right_foot"),
}
"""Joint zones (every SMPL joint is in exactly one): the benchmark's random sets and the training
option ``limb_first`` place effectors by zone."""
LIMB_ZONES: tuple[str, ...] = ("left_arm", "right_arm", "left_leg", "right_leg")
"""The zones of the four limbs (animators pin hands and feet first)."""
LIMB_CHAINS: dict[str, tuple[str, ...]] = {
    "left_arm": ZONES["left_arm"],
    "right_arm": ZONES["right_arm"],
    "left_leg": ("left_hip", *ZONES["left_leg"]),
    "right_leg": ("right_hip", *ZONES["right_leg"]),
}
"""Each limb's joints whose local rotations pose it relative to the torso (the hip's rotation poses
the thigh); the training option ``part_swap`` exchanges these between frames."""


class Gender(str, Enum):
    """SMPL body model gender; the value is the lowercase name used in files and on the CLI."""

    NEUTRAL = "neutral"
    MALE = "male"
    FEMALE = "female"

    @property
    def index(self) -> int:
        """Position of this gender in the network's one-hot vector."""
        return list(Gender).index(self)

    @classmethod
    def parse(cls, value: str | Gender) -> Gender:
        """Parse ``"neutral"``, ``"male"``, ``"female"`` (any case) or a :class:`Gender`."""
        if isinstance(value, Gender):
            return value
        try:
            return cls(str(value).strip().lower())
        except ValueError:
            valid = ", ".join(g.value for g in cls)
            raise ValueError(f"Unknown gender {value!r}; expected one of: {valid}.") from None


class EffectorType(int, Enum):
    """Effector kinds, with the integer ids the network embeds (ProtoRes section 2)."""

    POSITION = 0
    ROTATION = 1
    LOOK_AT = 2

    @classmethod
    def parse(cls, value: str | int | EffectorType) -> EffectorType:
        """Parse ``"position"``, ``"rotation"``, ``"look_at"`` (or ``"lookat"``), an id or the enum."""
        if isinstance(value, EffectorType):
            return value
        if isinstance(value, int):
            return cls(value)
        key = str(value).strip().lower().replace("-", "_")
        if key == "lookat":
            key = "look_at"
        try:
            return cls[key.upper()]
        except KeyError:
            valid = ", ".join(t.name.lower() for t in cls)
            raise ValueError(f"Unknown effector type {value!r}; expected one of: {valid}.") from None


def unknown_joint(name: object) -> str:
    """The message for a joint name that is not an SMPL joint: ``unknown joint 'left_wirst' (did you mean
    'left_wrist'?); valid names: ...`` (:func:`difflib.get_close_matches`; every parser of joint names uses it)."""
    import difflib

    text = str(name)
    close = difflib.get_close_matches(text.lower(), JOINT_NAMES, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    shown = repr(text[:60]) if isinstance(name, str) else text[:60]  # a number stays a number: unknown joint 15
    return f"unknown joint {shown}{hint}; valid names: {', '.join(JOINT_NAMES)}."


def joint_index(joint: str | int) -> int:
    """Return the SMPL index of ``joint`` given by name or index, with a clear error otherwise."""
    if isinstance(joint, bool):
        raise ValueError(f"Invalid joint {joint!r}.")
    if isinstance(joint, int):
        if not 0 <= joint < NUM_JOINTS:
            raise ValueError(f"Joint index {joint} out of range [0, {NUM_JOINTS - 1}].")
        return joint
    if isinstance(joint, str) and joint in JOINT_INDEX:
        return JOINT_INDEX[joint]
    message = unknown_joint(joint)
    raise ValueError(message[0].upper() + message[1:])


def tree_depth(parents: tuple[int, ...] = PARENTS) -> tuple[int, ...]:
    """Depth of each joint in the tree (root = 0); parents must precede children."""
    depth: list[int] = []
    for j, p in enumerate(parents):
        if p >= j:
            raise ValueError(f"Parent {p} of joint {j} does not precede it.")
        depth.append(0 if p < 0 else depth[p] + 1)
    return tuple(depth)
