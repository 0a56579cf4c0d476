"""Map an ordinary humanoid rig's joints to SMPL's by their names, checked against the skeleton's topology.

For rigs without a preset. Names are split into words (``LeftUpLeg`` -> left, up, leg; ``L_Knee``
-> l, knee; ``knee_l``; ``lowerleg01.L``; ``Bip01 L Thigh``; any ``namespace:`` or ``path|`` prefix
dropped); a side word (left/l, right/r) and a body-part word give the SMPL joint:

==============  ====================================================
SMPL joint      part words (first match wins, per side)
==============  ====================================================
hip             upleg, thigh, upperleg, femur, hip (sided)
knee            knee, shin, calf, lowerleg, leg, tibia
ankle           ankle, foot
foot (toes)     toe, toebase, toes, ball
collar          clavicle, collar, shoulder (when an arm joint exists)
shoulder        upperarm, uparm, arm, humerus, shoulder (no arm joint)
elbow           forearm, lowerarm, lowarm, elbow
wrist           wrist, hand (hand = SMPL hand when a wrist exists)
pelvis          hips, pelvis, hip (unsided), else the root
spine1..3       spine, chest, abdomen, torso, back, waist (ancestors of the neck, by depth)
neck, head      neck, head
==============  ====================================================

Among several candidates the earlier word of the table wins (CMU's ``LeftUpLeg`` before
``LHipJoint``), then the one nearest the root (``upperleg01`` before ``upperleg02``).
The match is accepted only if the topology agrees: on each side hip -> knee -> ankle -> toes and
collar -> shoulder -> elbow -> wrist are ancestor chains, neck -> head too, the left and right
chains are disjoint, and all SMPL-SI's required joints are found; otherwise :class:`NameMatchError`
says which check failed.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from smplik.conventions import JOINT_NAMES

_WORD = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")
_SIDED_PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("toe", ("toebase", "toes", "toe", "ball")),
    ("hip", ("upleg", "thigh", "upperleg", "femur", "hip")),
    ("knee", ("knee", "shin", "calf", "lowerleg", "leg", "tibia")),
    ("ankle", ("ankle", "foot")),
    ("clavicle", ("clavicle", "collar")),
    ("shoulder_word", ("shoulder",)),
    ("upperarm", ("upperarm", "uparm", "arm", "humerus")),
    ("elbow", ("forearm", "lowerarm", "lowarm", "elbow")),
    ("wrist", ("wrist",)),
    ("hand", ("hand",)),
)
_FINGERS = ("thumb", "index", "middle", "ring", "pinky", "little", "finger", "metacarpal")
_IGNORED = ("bip", "biped", "def", "org", "jnt", "joint", "bone", "mch", "b")
_SPINE = ("spine", "chest", "upperchest", "abdomen", "torso", "back", "lowerback", "waist")


class NameMatchError(ValueError):
    """The joint names do not match an ordinary humanoid, or the match contradicts the topology."""


_EXPORTER_SUFFIX = re.compile(r"(?:[._]\d+)+$")
_COMPOUNDS = {"legupper": "upperleg", "leglower": "lowerleg", "armupper": "upperarm", "armlower": "lowerarm",
              "legup": "upleg", "armup": "uparm", "leglow": "lowleg", "armlow": "lowarm"}
"""Reversed compounds of some exporters (Sketchfab's ``leg_upper.L_6``) in the usual order."""
_HELPER = ("ik", "pole", "target", "ctrl", "control", "helper")
"""Words of IK and control helpers: such a joint takes a role only when no other joint has the same name."""


def name_words(name: str) -> list[str]:
    """Lower-case words of a joint name, prefix and exporter suffix dropped: ``"mixamorig:LeftUpLeg"`` ->
    ``["left", "up", "leg"]``, Sketchfab's ``"leg_upper.L_6"`` -> ``["leg", "upper", "l"]``."""
    base = name.rsplit("|", 1)[-1].rsplit(":", 1)[-1]
    base = _EXPORTER_SUFFIX.sub("", base) or base
    return [w.lower() for w in _WORD.findall(base)]


def _side_and_part(name: str) -> tuple[str | None, str]:
    side, part, _ = _side_part_helper(name)
    return side, part


def _side_part_helper(name: str) -> tuple[str | None, str, bool]:
    """(side, body-part word, whether the name marks an IK or control helper)."""
    words = name_words(name)
    side = None
    rest = []
    helper = False
    for w in words:
        if w in ("left", "l") and side is None:
            side = "left"
        elif w in ("right", "r") and side is None:
            side = "right"
        elif w in _HELPER:
            helper = True
        elif not w.isdigit() and w not in _IGNORED:
            rest.append(w)
    part = "".join(rest)
    return side, _COMPOUNDS.get(part, part), helper


def _classify(part: str, side: str | None) -> tuple[str, int] | None:
    """(label, rank of the matching word: lower is preferred) or None."""
    if any(f in part for f in _FINGERS):
        return "finger", 0
    if side is None:
        if part in ("hips", "pelvis", "hip"):
            return "pelvis", 0
        if part == "neck":
            return "neck", 0
        if part == "head":
            return "head", 0
        if any(part == s or part.startswith(s) for s in _SPINE):
            return "spine", 0
        return None
    for label, words in _SIDED_PARTS:
        if part in words:
            return label, words.index(part)
    return None


def _depths(parents: Sequence[int]) -> list[int]:
    depth = [0] * len(parents)
    for j, p in enumerate(parents):  # parents precede children
        depth[j] = 0 if p < 0 else depth[p] + 1
    return depth


def is_ancestor(a: int, b: int, parents: Sequence[int]) -> bool:
    """Whether joint ``a`` is a proper ancestor of joint ``b``."""
    p = parents[b]
    while p >= 0:
        if p == a:
            return True
        p = parents[p]
    return False


def match_humanoid(names: Sequence[str], parents: Sequence[int],
                   required: Sequence[str] = ()) -> dict[str, int]:
    """SMPL joint name -> index into ``names`` (see the module docstring). Raises :class:`NameMatchError`."""
    if len(names) != len(parents) or any(p >= j for j, p in enumerate(parents)):
        raise NameMatchError("name matching needs parents listed before children")
    depth = _depths(parents)
    ranked: dict[tuple[str | None, str], list[tuple[int, int, int]]] = {}
    for j, n in enumerate(names):
        side, part, helper = _side_part_helper(n)
        hit = _classify(part, side)
        if hit is not None:  # an IK / control helper ranks after every plain joint of its name
            ranked.setdefault((side, hit[0]), []).append((hit[1] + (100 if helper else 0), depth[j], j))
    # per label: the preferred word first (CMU's LeftUpLeg before LHipJoint), then nearest the root
    cands = {key: [j for _, _, j in sorted(v)] for key, v in ranked.items()}
    found: dict[str, int] = {}

    def first(side: str | None, label: str) -> int | None:
        v = cands.get((side, label))
        return v[0] if v else None

    pelvis = first(None, "pelvis")
    found["pelvis"] = pelvis if pelvis is not None else next(j for j, p in enumerate(parents) if p < 0)
    for side in ("left", "right"):
        has_arm = (side, "upperarm") in cands
        roles = {
            "hip": first(side, "hip"), "knee": first(side, "knee"), "ankle": first(side, "ankle"),
            "foot": first(side, "toe"), "elbow": first(side, "elbow"),
            "collar": first(side, "clavicle") if not has_arm or (side, "clavicle") in cands
            else first(side, "shoulder_word"),
            "shoulder": first(side, "upperarm") if has_arm else first(side, "shoulder_word"),
        }
        # "LeftLeg" is the knee beside "LeftUpLeg"; a rig whose only leg joints are "...Leg" has no such pair
        wrist, hand = first(side, "wrist"), first(side, "hand")
        roles["wrist"] = wrist if wrist is not None else hand
        if wrist is not None and hand is not None:
            roles["hand"] = hand
        elif roles["wrist"] is not None:
            fingers = [j for j in cands.get((side, "finger"), []) if is_ancestor(roles["wrist"], j, parents)]
            if fingers:
                roles["hand"] = fingers[0]
        for role, j in roles.items():
            if j is not None:
                found[f"{side}_{role}"] = j
    neck, head = first(None, "neck"), first(None, "head")
    if head is not None:
        found["head"] = head
        necks = [j for j in cands.get((None, "neck"), []) if is_ancestor(j, head, parents)]
        if necks:
            found["neck"] = necks[-1]  # the one just below the head (CMU: Neck1)
    elif neck is not None:
        found["neck"] = neck
    top = found.get("neck", found.get("head"))
    spine = [j for j in cands.get((None, "spine"), []) if top is None or is_ancestor(j, top, parents)]
    spine = [j for j in spine if is_ancestor(found["pelvis"], j, parents)]
    if spine:
        found["spine1"] = spine[0]
        found["spine3"] = spine[-1]
        if len(spine) >= 3:
            found["spine2"] = spine[len(spine) // 2]
    _check_topology(found, names, parents)
    missing = [r for r in required if r not in found]
    if missing:
        raise NameMatchError(f"no joint name matches SMPL joint(s) {', '.join(missing)}")
    return found


def _check_topology(found: dict[str, int], names: Sequence[str], parents: Sequence[int]) -> None:
    chains = (("hip", "knee", "ankle", "foot"), ("collar", "shoulder", "elbow", "wrist", "hand"))
    for side in ("left", "right"):
        for chain in chains:
            present = [f"{side}_{r}" for r in chain if f"{side}_{r}" in found]
            for a, b in zip(present, present[1:], strict=False):
                if not is_ancestor(found[a], found[b], parents):
                    raise NameMatchError(f"name match contradicts the hierarchy: {a} = {names[found[a]]!r} is not "
                                         f"an ancestor of {b} = {names[found[b]]!r}")
    for a, b in (("neck", "head"), ("pelvis", "left_hip"), ("pelvis", "right_hip")):
        if a in found and b in found and found[a] != found[b] and not is_ancestor(found[a], found[b], parents):
            raise NameMatchError(f"name match contradicts the hierarchy: {a} = {names[found[a]]!r} is not an "
                                 f"ancestor of {b} = {names[found[b]]!r}")
    for role in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist"):
        left, right = found.get(f"left_{role}"), found.get(f"right_{role}")
        if left is not None and right is not None and (
                left == right or is_ancestor(left, right, parents) or is_ancestor(right, left, parents)):
            raise NameMatchError(f"name match contradicts the hierarchy: left_{role} = {names[left]!r} and "
                                 f"right_{role} = {names[right]!r} are on one chain")
    assert set(found) <= set(JOINT_NAMES)
