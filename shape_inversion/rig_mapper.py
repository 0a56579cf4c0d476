"""One rig mapper: a humanoid skeleton's joints -> SMPL's 24, from topology first, then geometry, then names.

Used by every command that takes a character (``invert-shape``, ``scene from-estimate --character``,
``scene export``) through :func:`shape_inversion.rigs.detect_rig`, and by ``smplik data build``
(:mod:`smplik.data.retarget`). The steps, for a skeleton given as names, parents and rest positions
(any units, any up axis):

1. **Hierarchy.** With several root joints, each root's hierarchy is tried and the one holding a
   humanoid is kept (``root`` overrides); IK targets, helpers and props under other roots are ignored.
2. **Extremities.** Leaves far apart along the tree (farthest-point sampling in the tree metric) are
   the candidate feet, hands and head; every assignment of five of them is checked against the
   humanoid topology: the pelvis is where the two leg chains and the spine chain meet (the common
   ancestor of both feet and the head, and of feet and hands), the arms branch from the upper spine
   (the common ancestor of both hands, below the pelvis and off the legs). Among valid assignments the
   most symmetric one with the feet lowest wins. IK/twist/helper leaves (``ik_hand_l`` under the root,
   a twist bone off the thigh) fail the topology or lose on symmetry.
3. **Chains.** Along each chain, SMPL joints are placed by position and relative bone length: the
   hip/shoulder is the first joint off the pelvis/spine line (the deepest of a cluster of nearly
   coincident joints, ``lButtock``/``lThigh``), knee and elbow at the chain's length fraction nearest
   SMPL's (twist bones inside a chain lose), the ankle ends the last bone pointing down, the toe is
   the next joint; the wrist is the last branching joint (the fingers), the hand the first finger
   joint clear of it; collar is the arm chain's joint before the shoulder; spine1..3 along the
   pelvis -> upper-spine path (spine3 = where the arms branch); neck and head on the head chain.
4. **Names** confirm or break ties: a joint whose name says the role (``shin`` -> knee, ``forearm``
   -> elbow, ``head``, ``neck``) wins among the geometric candidates of its chain segment; the side
   comes from side tokens in any convention (``Left``/``Right``, ``L``/``R``, ``_l``/``_r``,
   ``.L``/``.R``, ``lThigh``, ``Bip01 L Thigh``, ``J_Bip_L_``), and where the names are silent or
   contradict each other, from the rest geometry: left = up x forward, forward from the toes (or
   the thumbs). A side taken from geometry alone is a warning naming the joints.

Doubts are returned as warnings naming the joints (:func:`map_doubts`, also applied to a preset's or a
humanoid table's map): a side taken from the geometry; a chain with too few joints for SMPL's (no collar
between the spine and the shoulder, a spine of two joints for SMPL's three, no neck, no toe, no finger);
a joint of the spine or neck left unmapped while the rig has one.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from shape_inversion.rig_names import name_words
from smplik.conventions import JOINT_NAMES


class RigMappingError(ValueError):
    """The skeleton is not a humanoid the mapper can read (the message says which check failed)."""


@dataclass(frozen=True)
class RigMapping:
    """The mapper's result.

    Attributes:
        joints: SMPL joint name -> index into the skeleton's joints (SMPL order).
        root: index of the root joint of the hierarchy used.
        method: ``"topology"`` or ``"humanoid table"``.
        warnings: doubts, each naming the joints concerned.
    """

    joints: dict[str, int]
    root: int
    method: str = "topology"
    warnings: tuple[str, ...] = ()


_END_WORDS = ("end", "nub", "tip", "top", "null", "site")
_ROLE_WORDS: dict[str, tuple[str, ...]] = {
    "hip": ("thigh", "upleg", "upperleg", "hip", "femur"),
    "knee": ("shin", "calf", "knee", "lowerleg", "lowleg", "leg", "tibia"),
    "ankle": ("foot", "ankle"),
    "foot": ("toe", "toes", "toebase", "ball"),
    "collar": ("collar", "clavicle", "clavic", "shoulder"),
    "shoulder": ("upperarm", "uparm", "shldr", "arm", "shoulder", "humerus"),
    "elbow": ("forearm", "lowerarm", "lowarm", "elbow"),
    "wrist": ("hand", "wrist"),
    "neck": ("neck",),
    "head": ("head",),
}
_HAND_WORDS = ("middle", "mid", "index", "ring")


# ----------------------------------------------------------------------------- names


def side_of(name: str) -> str | None:
    """``"left"``, ``"right"`` or None from a joint name's side token, in any common convention."""
    words = name_words(name)
    for w in words:
        if w in ("left", "l", "lft"):
            return "left"
        if w in ("right", "r", "rgt", "rt"):
            return "right"
    base = name.rsplit("|", 1)[-1].rsplit(":", 1)[-1]
    for prefix, side in (("Left", "left"), ("Right", "right"), ("left", "left"), ("right", "right")):
        if base.startswith(prefix):
            return side
    return None


_COMPOUNDS = {"legupper": "upperleg", "leglower": "lowerleg", "armupper": "upperarm", "armlower": "lowerarm",
              "legup": "upleg", "armup": "uparm", "leglow": "lowleg", "armlow": "lowarm"}
"""Reversed compounds of some exporters (Sketchfab's ``Leg_Upper.L_205``) in the usual order."""
_HELPER_WORDS = ("ik", "pole", "target", "ctrl", "control", "helper", "mch", "twist", "roll", "socket", "prop",
                 "weapon", "attach", "grip", "pv")
"""Words of helper bones (IK targets and poles, twist and roll bones, sockets): never an extremity."""


def strip_suffix(name: str) -> str:
    """The name without exporter suffixes: Sketchfab's ``_6``, Blender's ``.001``, an ``_end``/``.end``.

    ``"leg_upper.L_6"`` -> ``"leg_upper.L"``, ``"DEF-thigh.L.001"`` -> ``"DEF-thigh.L"``.
    """
    return re.sub(r"(?:[._ ](?:\d+|end|End|END))+$", "", name) or name


def _part(name: str) -> str:
    """The name's words without side, digits and tool prefixes, joined (``"Bip01 L Thigh"`` -> ``"thigh"``).

    Exporter suffixes go with the digits (``"leg_upper.L_6"`` -> ``"upperleg"``: reversed compounds are put
    in the usual order).
    """
    ignored = {"left", "l", "right", "r", "lft", "rgt", "rt", "bip", "biped", "def", "org", "jnt", "joint", "bone",
               "mch", "b", "j", "c", "mixamorig", "cc", "base"}
    part = "".join(w for w in name_words(name) if not w.isdigit() and w not in ignored)
    for a, b in _COMPOUNDS.items():
        if part.startswith(a) and not part.startswith(b):
            return b + part[len(a):]
    return part


def is_helper(name: str) -> bool:
    """Whether the name says a helper bone (IK target or pole, twist/roll bone, socket, prop, Rigify MCH-)."""
    words = name_words(name)
    base = name.rsplit("|", 1)[-1].rsplit(":", 1)[-1].lower()
    return base.startswith(("mch-", "mch_", "ik-", "ik_", "vis_", "vis-")) or any(w in _HELPER_WORDS for w in words)


def _says(name: str, role: str) -> bool:
    """Whether the name states the SMPL role (its part word is one of the role's words, end bones excluded)."""
    part = _part(name)
    if any(part.endswith(e) for e in _END_WORDS) and role != "foot":
        return False
    words = _ROLE_WORDS[role]
    if role == "knee" and part in ("upleg", "upperleg"):
        return False
    if role == "shoulder" and part in ("forearm", "lowerarm", "lowarm"):
        return False
    return any(part == w or part.startswith(w) or part.endswith(w) for w in words)


def _is_end(name: str) -> bool:
    part = _part(name)
    return any(part.endswith(e) for e in _END_WORDS) or part.endswith("end")


# ----------------------------------------------------------------------------- tree helpers


class _Tree:
    """Parents, children, depths and ancestor tests of one skeleton."""

    def __init__(self, parents: Sequence[int], positions: np.ndarray, names: Sequence[str] | None = None) -> None:
        self.parents = list(parents)
        self.names = names
        self.P = positions
        n = len(parents)
        self.children: list[list[int]] = [[] for _ in range(n)]
        for j, p in enumerate(parents):
            if p >= 0:
                self.children[p].append(j)
        self.depth = [0] * n
        self.dist = np.zeros(n)  # tree distance from the root, file units
        for j in self._order():
            p = parents[j]
            if p >= 0:
                self.depth[j] = self.depth[p] + 1
                self.dist[j] = self.dist[p] + float(np.linalg.norm(positions[j] - positions[p]))

    def _order(self) -> list[int]:
        order, stack = [], [j for j, p in enumerate(self.parents) if p < 0]
        while stack:
            j = stack.pop()
            order.append(j)
            stack.extend(self.children[j])
        return order

    def path_to_root(self, j: int) -> list[int]:
        out = [j]
        while self.parents[out[-1]] >= 0:
            out.append(self.parents[out[-1]])
        return out

    def lca(self, a: int, b: int) -> int:
        pa = set(self.path_to_root(a))
        for x in self.path_to_root(b):
            if x in pa:
                return x
        return -1

    def is_ancestor(self, a: int, b: int) -> bool:
        """``a`` is ``b`` or one of its ancestors."""
        return a in self.path_to_root(b)

    def chain(self, top: int, leaf: int) -> list[int]:
        """Joints strictly below ``top`` down to ``leaf`` (inclusive), top to bottom."""
        out = []
        for x in self.path_to_root(leaf):
            if x == top:
                return out[::-1]
            out.append(x)
        raise RigMappingError("internal: not a descendant")

    def subtree(self, j: int) -> list[int]:
        out, stack = [], [j]
        while stack:
            k = stack.pop()
            out.append(k)
            stack.extend(self.children[k])
        return sorted(out)

    def tree_distance(self, a: int, b: int) -> float:
        c = self.lca(a, b)
        return float(self.dist[a] + self.dist[b] - 2 * self.dist[c])


# ----------------------------------------------------------------------------- extremities


@dataclass(frozen=True)
class _Body:
    pelvis: int
    feet: tuple[int, int]
    hands: tuple[int, int]
    head: int
    up: np.ndarray
    score: float


def _candidates(tree: _Tree, members: list[int], k: int = 8) -> list[int]:
    """Up to ``k`` leaves far apart in the tree metric (farthest-point sampling from the root)."""
    leaves = [j for j in members if not tree.children[j]]
    names = tree.names
    if names is not None:  # IK targets, poles, twist bones: never a hand, foot or head
        plain = [j for j in leaves if not is_helper(names[j])]
        leaves = plain if len(plain) >= 5 else leaves
    if len(leaves) < 5:
        return leaves
    root = members[0]
    picked = [max(leaves, key=lambda j: tree.tree_distance(root, j))]
    while len(picked) < min(k, len(leaves)):
        best = max((j for j in leaves if j not in picked),
                   key=lambda j: min(tree.tree_distance(j, q) for q in picked))
        if min(tree.tree_distance(best, q) for q in picked) <= 0:
            break
        picked.append(best)
    return picked


def _find_bodies(tree: _Tree, members: list[int], why: list[str] | None = None) -> list[_Body]:
    """Every valid assignment of feet, hands and head among the candidate leaves, best first."""
    cands = _candidates(tree, members)
    P = tree.P
    size = max(float(np.ptp(P[members], axis=0).max()), 1e-12)
    found: dict[tuple, _Body] = {}
    for five in itertools.combinations(cands, 5):
        for head in five:
            rest = [j for j in five if j != head]
            for feet in itertools.combinations(rest, 2):
                hands = tuple(j for j in rest if j not in feet)
                body = _check(tree, head, feet, hands, size, why)  # type: ignore[arg-type]
                if body is not None:
                    found[(head, feet, hands)] = body
    return sorted(found.values(), key=lambda b: b.score)


def _reject(why: list[str] | None, reason: str) -> None:
    if why is not None:
        why.append(reason)
    return None


def _check(tree: _Tree, head: int, feet: tuple[int, int], hands: tuple[int, int], size: float,
           why: list[str] | None = None) -> _Body | None:
    P = tree.P
    legs_meet = tree.lca(*feet)
    pelvis = tree.lca(legs_meet, head)
    arms_meet = tree.lca(*hands)
    if pelvis < 0 or arms_meet < 0 or legs_meet in feet or arms_meet in hands:
        return None
    # the arms branch off the spine: below (or at) the pelvis, not inside a leg, the head above them or beside
    if not tree.is_ancestor(pelvis, arms_meet) or tree.is_ancestor(legs_meet, arms_meet) and legs_meet != pelvis:
        return None
    if any(tree.lca(h, f) != pelvis for h in hands for f in feet) or tree.lca(head, feet[0]) != pelvis:
        return None
    if tree.is_ancestor(arms_meet, feet[0]) or tree.is_ancestor(arms_meet, feet[1]):
        return None
    if tree.lca(head, hands[0]) == pelvis:  # the head hangs on the spine, not on the pelvis
        return None
    # hip, knee, ankle on each leg and shoulder, elbow, wrist on each arm: IK targets hang on one bone
    if min(len(tree.chain(pelvis, f)) for f in feet) < 3 or min(len(tree.chain(arms_meet, x)) for x in hands) < 3:
        return None
    up = P[head] - (P[feet[0]] + P[feet[1]]) / 2
    height = float(np.linalg.norm(up))
    if height < 1e-3 * size:
        return None
    up = up / height
    h = {j: float((P[j] - P[feet[0]]) @ up) for j in (*feet, *hands, head)}
    leg = [tree.tree_distance(pelvis, f) for f in feet]
    arm = [tree.tree_distance(arms_meet, x) for x in hands]
    if min(leg) <= 0 or min(arm) <= 0:
        return None
    # two legs part at the pelvis, not at a hand (two fingers of one hand are not two legs)
    if tree.tree_distance(pelvis, legs_meet) > 0.25 * min(leg):
        return None
    score = abs(leg[0] - leg[1]) / max(leg) + abs(arm[0] - arm[1]) / max(arm)
    score += abs(np.log(np.mean(arm) / np.mean(leg) / 0.85))  # arms about as long as legs (eyes are not arms)
    score += max(0.0, tree.tree_distance(arms_meet, head) / np.mean(arm) - 0.8)  # the neck shorter than an arm
    if min(h[hands[0]], h[hands[1]]) < 0.3 * height:  # hands on the floor: a quadruped's front legs
        return _reject(why, "four legs: the limbs that would be arms reach the floor like front legs "
                       f"(their ends at {min(h[hands[0]], h[hands[1]]) / height:.0%} of the height, a human's hands "
                       "hang above 30%)")
    legs_up = P[pelvis] - (P[feet[0]] + P[feet[1]]) / 2  # along the legs: hands above the knees, the head above
    hip_height = float(np.linalg.norm(legs_up))
    if hip_height > 0:
        legs_up = legs_up / hip_height
        lift = [float((P[j] - (P[feet[0]] + P[feet[1]]) / 2) @ legs_up) / hip_height for j in (*hands, head)]
        if min(lift[:2]) < 0.4 or lift[2] < 1.2:  # a quadruped: front paws on the floor, head ahead of the body
            return _reject(why, "a horizontal body: the head is ahead of the hips, not above them (head at "
                           f"{lift[2]:.1f} hip heights along the legs, a human's above 1.2)" if lift[2] < 1.2 else
                           "four legs: the front limbs stand on the floor (their ends below 40% of the hip height)")
        spine = P[arms_meet] - P[pelvis]
        n_spine = float(np.linalg.norm(spine))
        if n_spine > 0.05 * hip_height and float(spine @ legs_up) < 0.5 * n_spine:  # a quadruped's spine runs forward
            return _reject(why, "a horizontal body: the spine runs forward, not up along the legs ("
                           f"{np.degrees(np.arccos(np.clip(spine @ legs_up / n_spine, -1, 1))):.0f} deg from them, "
                           "a human's within 60 deg)")
    if abs(h[feet[0]] - h[feet[1]]) > 0.25 * height:  # a tail or a raised limb is not the second leg
        return _reject(why, "no two legs of one length: the limbs below the pelvis end at different heights "
                       "(a tail beside a leg)")
    if float((P[pelvis] - P[feet[0]]) @ up) < 0.25 * height:  # no legs below the pelvis (a half-body avatar)
        return _reject(why, "no legs below the pelvis (a half-body)")
    d0, d1 = P[feet[0]] - P[pelvis], P[feet[1]] - P[pelvis]
    if d0 @ d1 < np.cos(np.radians(55)) * np.linalg.norm(d0) * np.linalg.norm(d1):  # legs 55 deg apart: a tail
        return _reject(why, "no two legs side by side: the limbs off the pelvis point more than 55 deg apart "
                       "(legs and a tail)")
    score += 2.0 * sum(max(0.0, (min(h[feet[0]], h[feet[1]]) - h[x]) / height) for x in hands)  # feet lowest
    score += abs(h[feet[0]] - h[feet[1]]) / height
    score += max(0.0, 0.5 - float((P[pelvis] - P[feet[0]]) @ up) / height)  # the pelvis well above the feet
    return _Body(pelvis, feet, hands, head, up, score)


# ----------------------------------------------------------------------------- chain assignment


def _named(chain: list[int], names: Sequence[str], role: str) -> list[int]:
    return [j for j in chain if _says(names[j], role)]


def _at_fraction(P: np.ndarray, chain: list[int], start: int, end: int, fraction: float) -> int | None:
    """The joint of ``chain`` strictly between positions ``start`` and ``end`` nearest ``fraction`` of the path."""
    i0, i1 = chain.index(start), chain.index(end)
    inner = chain[i0 + 1:i1]
    if not inner:
        return None
    seg = [chain[i0]] + inner + [chain[i1]]
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P[seg], axis=0), axis=1))])
    total = cum[-1] if cum[-1] > 0 else 1.0
    k = int(np.argmin(np.abs(cum[1:-1] / total - fraction)))
    return inner[k]


def _cluster_end(P: np.ndarray, chain: list[int], first: int, limit: int, names: Sequence[str], role: str,
                 tol: float) -> int:
    """The deepest joint of ``chain`` from ``first`` (before ``limit``) within ``tol`` of it; a named one wins."""
    i0, i1 = chain.index(first), chain.index(limit)
    group = [j for j in chain[i0:i1] if np.linalg.norm(P[j] - P[first]) <= tol]
    named = [j for j in group if _says(names[j], role)]
    return named[-1] if named else group[-1]


def _map_leg(tree: _Tree, names: Sequence[str], pelvis: int, leaf: int, up: np.ndarray, across: np.ndarray,
             stature: float) -> dict[str, int]:
    P = tree.P
    chain = [j for j in tree.chain(pelvis, leaf)]
    while len(chain) > 1 and _is_end(names[chain[-1]]) and not tree.children[chain[-1]]:
        chain = chain[:-1]
    # ankle: the end of the last bone pointing down (the foot bones after it run forward)
    ankle = chain[-1]
    for a, b in zip(chain, chain[1:], strict=False):
        d = P[b] - P[a]
        n = np.linalg.norm(d)
        if n > 1e-6 * stature and -(d @ up) >= 0.8 * n:
            ankle = b
    # a short last bone down to the chain's end is the foot (heel/sole, Cesium's leg_joint_3 -> leg_joint_5):
    # the ankle is where it starts, the shin above it being long
    k = chain.index(ankle)
    if ankle == chain[-1] and k >= 2 and np.linalg.norm(P[ankle] - P[chain[k - 1]]) < 0.08 * stature \
            and -float((P[chain[k - 1]] - P[chain[k - 2]]) @ up) >= 0.15 * stature:
        ankle = chain[k - 1]
    named = [j for j in _named(chain, names, "ankle") if chain.index(j) >= 2]
    if named:
        ankle = named[0]
    hip_first = next((j for j in chain if abs(float((P[j] - P[pelvis]) @ across)) >= 0.025 * stature), chain[0])
    if chain.index(hip_first) >= chain.index(ankle):
        raise RigMappingError(f"leg chain ending at {names[leaf]!r} is too short for hip, knee and ankle")
    thigh_guess = np.linalg.norm(P[ankle] - P[hip_first]) / 2
    # knee first (its position bounds the hip cluster), then the hip
    knee = _at_fraction(P, chain, hip_first, ankle, 0.5)
    if knee is None:
        raise RigMappingError(f"leg chain {names[hip_first]!r} -> {names[ankle]!r} has no joint between hip and "
                              "ankle for the knee")
    hip = _cluster_end(P, chain, hip_first, knee, names, "hip", 0.15 * thigh_guess)
    knees = [j for j in _named(chain, names, "knee") if chain.index(hip) < chain.index(j) < chain.index(ankle)]
    if knees and knee not in knees:
        knee = knees[0]
    out = {"hip": hip, "knee": knee, "ankle": ankle}
    after = chain[chain.index(ankle) + 1:]
    if after:
        total = np.linalg.norm(P[chain[-1]] - P[ankle])
        toe = next((j for j in after if np.linalg.norm(P[j] - P[ankle]) >= 0.3 * total), None)
        named = [j for j in after if _says(names[j], "foot")]
        toe = named[0] if named else toe
        if toe is not None:
            out["foot"] = toe
    return out


def _hand_leaf(tree: _Tree, names: Sequence[str], wrist: int) -> int | None:
    """The finger the SMPL hand joint follows: the middle finger by name, else the longest finger."""
    kids = tree.children[wrist]
    if not kids:
        return None
    for word in _HAND_WORDS:
        for k in kids:
            sub = tree.subtree(k)
            if any(word in name_words(names[j]) or _part(names[j]).startswith(word) for j in sub):
                return max(sub, key=lambda j: tree.dist[j])
    leaves = [j for j in tree.subtree(wrist) if not tree.children[j]]
    return max(leaves, key=lambda j: tree.dist[j])


def _map_arm(tree: _Tree, names: Sequence[str], top: int, leaf: int, stature: float, centre: np.ndarray,
             across: np.ndarray) -> dict[str, int]:
    P = tree.P
    chain = tree.chain(top, leaf)

    def lateral(j: int) -> float:
        return abs(float((P[j] - centre) @ across))

    # wrist: the last joint with several branches (the fingers); without fingers, the chain's last real joint
    branching = [j for j in chain if len(tree.children[j]) >= 2]
    real = [j for j in chain if not (_is_end(names[j]) and not tree.children[j])]
    wrist = branching[-1] if branching else real[-1]
    named = [j for j in _named(chain, names, "wrist") if _part(names[j]) in ("hand", "wrist") or
             _part(names[j]).endswith("hand")]
    if named and named[0] != wrist and (not branching or chain.index(named[0]) < chain.index(wrist)):
        wrist = named[0]
    pre = chain[:chain.index(wrist)]
    if len(pre) < 2:
        raise RigMappingError(f"arm chain ending at {names[leaf]!r} is too short for shoulder, elbow and wrist")
    shoulder_first = next((j for j in pre if lateral(j) >= 0.07 * stature), pre[0])
    if shoulder_first == pre[-1]:
        shoulder_first = pre[-2] if len(pre) >= 2 else pre[0]
    upper_named = [j for j in pre[:-1] if _part(names[j]) in ("upperarm", "uparm", "shldr", "arm", "humerus")]
    if upper_named:  # the name says upper arm: it is the shoulder joint, what comes before is the collar
        shoulder_first = upper_named[0]
    elbow = _at_fraction(P, chain, shoulder_first, wrist, 0.53)
    if elbow is None:
        raise RigMappingError(f"arm chain {names[shoulder_first]!r} -> {names[wrist]!r} has no joint for the elbow")
    upper = np.linalg.norm(P[elbow] - P[shoulder_first])
    shoulder = _cluster_end(P, chain, shoulder_first, elbow, names, "shoulder", 0.15 * upper)
    elbows = [j for j in _named(chain, names, "elbow") if chain.index(shoulder) < chain.index(j) < chain.index(wrist)]
    if elbows and elbow not in elbows:
        elbow = elbows[0]
    out = {"shoulder": shoulder, "elbow": elbow, "wrist": wrist}
    before = chain[:chain.index(shoulder)]
    before = [j for j in before if np.linalg.norm(P[j] - P[shoulder]) > 1e-6 * stature]
    if before:
        ranked = [(_ROLE_WORDS["collar"].index(w), k, j) for k, j in enumerate(before)
                  for w in _ROLE_WORDS["collar"] if _part(names[j]) == w or _part(names[j]).endswith(w)]
        out["collar"] = min(ranked)[2] if ranked else before[0]
    finger = _hand_leaf(tree, names, wrist)
    if finger is not None and finger != wrist:
        path = tree.chain(wrist, finger)
        forearm = np.linalg.norm(P[wrist] - P[elbow])
        hand = next((j for j in path if np.linalg.norm(P[j] - P[wrist]) >= 0.15 * forearm), None)
        if hand is not None and not (_is_end(names[hand]) and not tree.children[hand]):
            out["hand"] = hand
    return out


def _side_votes(chain: list[int], names: Sequence[str]) -> int:
    v = 0
    for j in chain:
        s = side_of(names[j])
        v += 1 if s == "left" else -1 if s == "right" else 0
    return v


def _assign_sides(tree: _Tree, names: Sequence[str], top: int, pair: tuple[int, int], left_axis: np.ndarray | None,
                  what: str, notes: list[str]) -> tuple[int, int]:
    """(left, right) of two chain leaves: names first, else the rest geometry."""
    votes = [_side_votes(tree.chain(top, j), names) for j in pair]
    if votes[0] > 0 > votes[1] or (votes[0] > 0 and votes[1] == 0) or (votes[1] < 0 and votes[0] == 0):
        return pair
    if votes[1] > 0 > votes[0] or (votes[1] > 0 and votes[0] == 0) or (votes[0] < 0 and votes[1] == 0):
        return pair[1], pair[0]
    P = tree.P
    if left_axis is None:
        raise RigMappingError(f"cannot tell the left {what} from the right ({names[pair[0]]!r}, {names[pair[1]]!r}): "
                              "no side in their names and no forward direction in the rest pose")
    s = float((P[pair[0]] - P[pair[1]]) @ left_axis)
    left = names[pair[0] if s > 0 else pair[1]]
    notes.append(f"side of the {what} from the rest geometry (names silent): left = {left!r}")
    return pair if s > 0 else (pair[1], pair[0])


def _left_axis(tree: _Tree, feet_chains: list[list[int]], up: np.ndarray) -> np.ndarray | None:
    """left = up x forward; forward from the toes (ankle -> toe) else from the thumbs; None if neither tells."""
    P = tree.P
    fwd = np.zeros(3)
    for chain in feet_chains:
        if len(chain) >= 2:
            d = P[chain[-1]] - P[chain[-2]]
            fwd += d - (d @ up) * up
    if np.linalg.norm(fwd) < 1e-9:
        return None
    fwd /= np.linalg.norm(fwd)
    return np.cross(up, fwd)


def _map_spine(tree: _Tree, names: Sequence[str], pelvis: int, arms_meet: int, head_leaf: int, up: np.ndarray,
               stature: float, hands: tuple[int, ...] = (), shoulder_h: float | None = None,
               notes: list[str] | None = None) -> dict[str, int]:
    notes = [] if notes is None else notes
    P = tree.P
    out: dict[str, int] = {}
    spine = tree.chain(pelvis, arms_meet) if arms_meet != pelvis else []
    meet_h = float((P[arms_meet] - P[pelvis]) @ up)
    if len(spine) == 1 and shoulder_h is not None and 0.02 * stature <= meet_h < 0.5 * shoulder_h:
        # the arms hang off the one spine joint, low (a low-poly rig's chest bone just above the hips): it is
        # SMPL's spine1, not spine3, which sits 70% of the way up to the shoulders
        out["spine1"] = spine[0]
        notes.append(f"the arms branch from {names[arms_meet]!r}, low on the spine ({meet_h / shoulder_h:.0%} of "
                     "the shoulder height above the pelvis; SMPL's spine3 is at about 70%): mapped from spine1 up, "
                     "spine3 unmapped")
        spine = []
    if spine:
        out["spine3"] = spine[-1]
        inner = [j for j in spine[:-1] if float((P[j] - P[pelvis]) @ up) >= 0.02 * stature]
        if len(inner) < 2 <= len(spine) - 1:  # joints at the pelvis (CMU's LowerBack) still count when few
            inner = spine[:-1]
        if inner:
            out["spine1"] = inner[0]
            if len(inner) >= 2:
                h = np.array([(P[j] - P[pelvis]) @ up for j in inner[1:]])
                top = (P[arms_meet] - P[pelvis]) @ up
                target = (1.083 - 0.844) / (1.141 - 0.844) * top  # SMPL's spine2 height between pelvis and spine3
                out["spine2"] = inner[1 + int(np.argmin(np.abs(h - target)))]
    # neck and head on the chain from the upper spine to the head leaf
    start = arms_meet if tree.is_ancestor(arms_meet, head_leaf) else tree.lca(arms_meet, head_leaf)
    chain = tree.chain(start, head_leaf)
    real = [j for j in chain if not (_is_end(names[j]) and not tree.children[j])] or chain
    heads = [j for j in real if _says(names[j], "head")]
    if not heads:  # the leaf is a helper's (a hood, a hair strand): a joint named head under the spine wins
        named = [j for j in tree.subtree(start) if j != start and _part(names[j]) == "head"
                 and not any(tree.is_ancestor(j, h) for h in hands)]
        if named:
            top = max(named, key=lambda j: float(P[j] @ up))
            chain = tree.chain(start, top)
            real, heads = chain, [top]
    if heads:
        head = heads[0]
    else:
        branching = [j for j in real if len(tree.children[j]) >= 2]
        head = branching[0] if branching else real[-1]
    out["head"] = head
    before = chain[:chain.index(head)]
    # neck: SMPL's sits 70% of the way up from spine3 to the head; a neck-named joint wins
    span = float((P[head] - P[start]) @ up)
    before = [j for j in before if span > 0 and float((P[j] - P[start]) @ up) >= 0.2 * span] or before
    necks = [j for j in before if _says(names[j], "neck")] or before
    if necks:
        out["neck"] = min(necks, key=lambda j: abs(float((P[j] - P[start]) @ up) / (span or 1.0) - 0.7))
    return out


# ----------------------------------------------------------------------------- entry point


def map_skeleton(names: Sequence[str], parents: Sequence[int], positions: np.ndarray, *,
                 root: str | None = None) -> RigMapping:
    """Map a humanoid skeleton to SMPL's joints (see the module docstring).

    Args:
        names: (J,) joint names.
        parents: (J,) parent index per joint (-1 for roots), parents listed before children.
        positions: (J, 3) rest positions, any units and axes.
        root: name of the root joint whose hierarchy to use (default: the one holding a humanoid).

    Raises: :class:`RigMappingError` naming the failed check.
    """
    P = np.asarray(positions, dtype=np.float64)
    if len(names) != len(parents) or P.shape != (len(names), 3):
        raise RigMappingError("names, parents and positions disagree in length")
    tree = _Tree(parents, P, names)
    roots = [j for j, p in enumerate(parents) if p < 0]
    if root is not None:
        chosen = [j for j in roots if names[j] == root] or [j for j, n in enumerate(names) if n == root]
        if not chosen:
            raise RigMappingError(f"--root {root!r} is not a joint of the skeleton; roots: "
                                  f"{', '.join(repr(names[j]) for j in roots)}")
        roots = chosen
    bodies: list[tuple[float, int, _Body]] = []
    why: list[str] = []
    for r in roots:
        members = tree.subtree(r)
        if len(members) >= 5:
            bodies += [(b.score, -len(members), b) for b in _find_bodies(tree, members, why)]
    notes: list[str] = []
    if not bodies:  # a game rig whose IK-driven feet hang on the root: read each as its shin's child
        reattached = _reattach_detached_feet(tree, names, roots)
        if reattached is not None:
            tree, notes = _Tree(reattached[0], P, names), reattached[1]
            for r in roots:
                members = tree.subtree(r)
                if len(members) >= 5:
                    bodies += [(b.score, -len(members), b) for b in _find_bodies(tree, members)]
    if not bodies:
        order = ("four legs", "a horizontal body", "no legs", "no two legs")  # the most telling feature first
        why.sort(key=lambda w: next((k for k, o in enumerate(order) if w.startswith(o)), len(order)))
        feature = f"not a human: {why[0]}; " if why else ""
        raise RigMappingError(f"no humanoid found: {feature}no hierarchy has two legs and a spine meeting at a pelvis "
                              "with two arms branching from the spine")
    bodies.sort(key=lambda t: (t[0], t[1]))
    error: RigMappingError | None = None
    for _, _, body in bodies[:20]:  # the best assignment whose chains hold every joint
        try:
            mapping = _map_body(tree, names, body)
        except RigMappingError as exc:
            error = error or exc
        else:
            return dataclasses.replace(mapping, warnings=tuple(notes) + mapping.warnings) if notes else mapping
    assert error is not None
    raise error


def _reattach_detached_feet(tree: _Tree, names: Sequence[str], roots: list[int]) -> tuple[list[int], list[str]] | None:
    """Parents with each detached foot moved under its shin, and a note per foot; None when there is none.

    Game rigs drive the feet by IK: the foot bone (``Foot.L``) hangs on the root, the leg chain ends at the
    shin (``UpperLeg.L`` -> ``LowerLeg.L``, a leaf). A foot is the bone hanging on an ancestor of the leg,
    outside it, that continues the thigh's line from the shin's head by 0.6-1.6 thigh lengths.
    """
    P, parents = tree.P, list(tree.parents)
    moved: dict[int, int] = {}
    excluded = set(roots)
    min_cos = np.cos(np.radians(25))
    for leaf in (j for j in range(len(parents)) if not tree.children[j] and parents[j] >= 0):
        thigh = P[leaf] - P[parents[leaf]]
        length = float(np.linalg.norm(thigh))
        if length <= 0:
            continue
        line = tree.path_to_root(leaf)
        on_line = set(line)
        # the candidate feet: children of the leg's ancestors (from the thigh's parent up), off the leg; only
        # those are looked at, so a star of 10,000 leaves costs each leaf its ancestors' children, not every joint
        cand = np.array(sorted({c for a in line[2:] for c in tree.children[a]
                                if c not in on_line and c not in moved and c not in excluded}), dtype=np.int64)
        if not len(cand):
            continue
        shin = P[cand] - P[leaf]  # (K, 3)
        n = np.linalg.norm(shin, axis=-1)
        cos = (shin @ thigh) / np.maximum(n * length, 1e-12)
        ok = (0.6 * length <= n) & (n <= 1.6 * length) & (cos >= min_cos)
        if ok.any():  # the straightest; on a tie the last (as the scan this replaces kept it)
            best = cand[ok][np.flatnonzero(cos[ok] == cos[ok].max())[-1]]
            moved[int(best)] = leaf
    if len(moved) != 2:
        return None
    notes = []
    for f, leaf in moved.items():
        notes.append(f"the ankle {names[f]!r} hangs on {names[parents[f]]!r}, not on the shin {names[leaf]!r} (an "
                     "IK-driven foot): mapped as the shin's child for the shape; retargeted poses leave it where the "
                     "IK puts it")
        parents[f] = leaf
    return parents, notes


def _map_body(tree: _Tree, names: Sequence[str], body: _Body) -> RigMapping:
    P = tree.P
    r = tree.path_to_root(body.pelvis)[-1]
    notes: list[str] = []
    up = body.up
    stature = float((P[body.head] - (P[body.feet[0]] + P[body.feet[1]]) / 2) @ up) / 0.88

    def across(a: int, b: int) -> np.ndarray:
        d = P[a] - P[b]
        d = d - (d @ up) * up
        return d / max(float(np.linalg.norm(d)), 1e-12)

    legs = [_map_leg(tree, names, body.pelvis, f, up, across(*body.feet), stature) for f in body.feet]
    leg_chains = [tree.chain(body.pelvis, leg.get("foot", leg["ankle"])) for leg in legs]
    left_axis = _left_axis(tree, [c[-2:] if "foot" in leg else [] for c, leg in zip(leg_chains, legs, strict=True)],
                           up)
    arms_meet = tree.lca(*body.hands)
    arms = [_map_arm(tree, names, arms_meet, x, stature, P[arms_meet], across(*body.hands)) for x in body.hands]
    if left_axis is None:  # no toes: the thumbs point forward in a T/A pose
        fwd = np.zeros(3)
        for arm in arms:
            kids = tree.children[arm["wrist"]]
            thumbs = [k for k in kids if "thumb" in _part(names[k]) or "thumb" in names[k].lower()]
            for t in thumbs:
                d = P[t] - P[arm["wrist"]]
                fwd += d - (d @ up) * up
        if np.linalg.norm(fwd) > 1e-9:
            left_axis = np.cross(up, fwd / np.linalg.norm(fwd))
    feet_lr = _assign_sides(tree, names, body.pelvis, body.feet, left_axis, "legs", notes)
    hands_lr = _assign_sides(tree, names, arms_meet, body.hands, left_axis, "arms", notes)
    out: dict[str, int] = {"pelvis": body.pelvis}
    for side, f in zip(("left", "right"), feet_lr, strict=True):
        for role, j in legs[body.feet.index(f)].items():
            out[f"{side}_{role}"] = j
    for side, x in zip(("left", "right"), hands_lr, strict=True):
        for role, j in arms[body.hands.index(x)].items():
            out[f"{side}_{role}"] = j
    shoulder_h = float(np.mean([(P[arm["shoulder"]] - P[body.pelvis]) @ up for arm in arms]))
    out.update(_map_spine(tree, names, body.pelvis, arms_meet, body.head, up, stature, body.hands,
                          shoulder_h if shoulder_h > 0 else None, notes))
    if "spine3" not in out and "spine1" not in out:
        notes.append(f"the arms branch from the pelvis joint {names[body.pelvis]!r}: no spine joints mapped")
    ordered = {s: out[s] for s in JOINT_NAMES if s in out}
    if len(set(ordered.values())) != len(ordered):
        dup = [s for s in ordered if list(ordered.values()).count(ordered[s]) > 1]
        raise RigMappingError(f"one joint was given several SMPL roles ({', '.join(dup)})")
    notes += map_doubts(names, tree.parents, P, ordered)
    return RigMapping(ordered, r, "topology", tuple(notes))


# ----------------------------------------------------------------------------- doubts of any map


def map_doubts(names: Sequence[str], parents: Sequence[int], positions: np.ndarray,
               joints: dict[str, int]) -> list[str]:
    """Doubts about a map (the mapper's, a preset's or a humanoid table's), each naming the joints.

    * a chain with too few joints for SMPL's: no joint between the spine and a shoulder (collar unmapped),
      a spine of one or two joints between the pelvis and the joint the arms branch from (spine1/spine2
      unmapped), no joint between that joint and the head (neck unmapped), no toe after an ankle, no
      finger after a wrist;
    * a joint of the spine or neck (on the path pelvis -> spine3 -> head) that the map leaves unmapped,
      unless it sits on a mapped neighbour (a zero-length bone).

    Args:
        names, parents: (J,) the skeleton; positions: (J, 3) rest positions, any units.
        joints: SMPL joint name -> index into ``names``.
    """
    tree = _Tree(parents, np.asarray(positions, dtype=np.float64))
    P = tree.P
    mapped = set(joints.values())
    role = {j: s for s, j in joints.items()}
    size = max(float(np.ptp(P, axis=0).max()), 1e-12)

    def q(j: int) -> str:
        return f"{names[j]!r}" + (f" ({role[j]})" if j in role else "")

    def on_mapped_neighbour(j: int, chain: list[int]) -> bool:
        k = chain.index(j)
        near = [chain[i] for i in (k - 1, k + 1) if 0 <= i < len(chain) and chain[i] in mapped]
        return any(np.linalg.norm(P[j] - P[n]) <= 1e-3 * size for n in near)

    notes: list[str] = []
    pelvis, spine3, head = joints.get("pelvis"), joints.get("spine3"), joints.get("head")
    if pelvis is not None and spine3 is not None and tree.is_ancestor(pelvis, spine3) and pelvis != spine3:
        path = [pelvis] + tree.chain(pelvis, spine3)
        lacking = [s for s in ("spine1", "spine2") if s not in joints]
        if lacking:
            inner = ", ".join(q(j) for j in path[1:-1]) or "none"
            notes.append(f"the spine {q(pelvis)} -> {q(spine3)} is too short for SMPL's spine1, spine2, spine3 "
                         f"(joints between: {inner}): {', '.join(lacking)} unmapped")
        extra = [j for j in path if j not in mapped and not on_mapped_neighbour(j, path)]
        if extra:
            notes.append(f"spine joint(s) {', '.join(repr(names[j]) for j in extra)} left unmapped on the spine "
                         f"{q(pelvis)} -> {q(spine3)}")
    top = spine3 if spine3 is not None else pelvis
    if top is not None and head is not None and tree.is_ancestor(top, head) and top != head:
        path = [top] + tree.chain(top, head)
        if "neck" not in joints:
            notes.append(f"no joint between {q(top)} and the head {q(head)}: neck unmapped")
        extra = [j for j in path if j not in mapped and not on_mapped_neighbour(j, path)]
        if extra:
            notes.append(f"neck joint(s) {', '.join(repr(names[j]) for j in extra)} left unmapped between "
                         f"{q(top)} and {q(head)}")
    for side in ("left", "right"):
        shoulder, wrist, ankle = (joints.get(f"{side}_{r}") for r in ("shoulder", "wrist", "ankle"))
        if shoulder is not None and f"{side}_collar" not in joints:
            above = tree.parents[shoulder]
            if above < 0 or above in mapped:
                notes.append(f"the {side} arm has no joint between the spine"
                             f"{' ' + q(above) if above >= 0 else ''} and the shoulder {q(shoulder)}: "
                             f"{side}_collar unmapped")
            else:
                notes.append(f"{q(above)} before the {side} shoulder {q(shoulder)} is not mapped: {side}_collar "
                             "unmapped")
        for end, smpl, what in ((wrist, f"{side}_hand", "finger"), (ankle, f"{side}_foot", "toe")):
            if end is None or smpl in joints:
                continue
            after = [k for k in tree.children[end] if not _is_end(names[k])]
            if after:
                notes.append(f"the {what} joint(s) after the {side} {'wrist' if what == 'finger' else 'ankle'} "
                             f"{q(end)} ({', '.join(repr(names[k]) for k in after[:3])}) are not mapped: {smpl} "
                             "unmapped")
            else:
                notes.append(f"no {what} joint after the {side} {'wrist' if what == 'finger' else 'ankle'} "
                             f"{q(end)}: {smpl} unmapped")
    return notes


# ----------------------------------------------------------------------------- deform sets and virtual hierarchies


_DEF_PREFIX = re.compile(r"^(?:.*[:|])?def[-_.]", re.IGNORECASE)


def deform_bones(names: Sequence[str]) -> list[int] | None:
    """Indices of a Blender Rigify rig's deform bones (``DEF-thigh.L``) when the rig also holds other bones.

    A Rigify control rig holds the deform set (``DEF-``) beside its original (``ORG-``), mechanism (``MCH-``)
    and control bones (``thigh_ik.L``, ``root``): only the ``DEF-`` bones carry the mesh, so they are the
    skeleton. None when the rig has fewer than 10 ``DEF-`` bones or nothing else.
    """
    keep = [j for j, n in enumerate(names) if _DEF_PREFIX.match(n)]
    return keep if 10 <= len(keep) < len(names) else None


def kept_parents(parents: Sequence[int], keep: Sequence[int]) -> list[int]:
    """Parent of every joint of ``keep`` as its nearest kept ancestor (an index into the full list, -1 if none)."""
    kept = set(keep)
    out = []
    for j in keep:
        p = parents[j]
        while p >= 0 and p not in kept:
            p = parents[p]
        out.append(p)
    return out


def bone_axes_consistent(parents: Sequence[int], positions: np.ndarray, axes: np.ndarray) -> bool:
    """Whether ``axes`` (J, 3) run along the bones: for most joints with one child, towards that child.

    Blender exports every bone with its local +Y from head to tail; other tools' joint axes say nothing.
    """
    P = np.asarray(positions, dtype=np.float64)
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        if p >= 0:
            children.setdefault(p, []).append(j)
    cos = []
    for j, kids in children.items():
        if len(kids) == 1:
            d = P[kids[0]] - P[j]
            n = float(np.linalg.norm(d))
            if n > 0:
                cos.append(float(d @ axes[j]) / (n * max(float(np.linalg.norm(axes[j])), 1e-12)))
    return len(cos) >= 5 and float(np.mean(np.array(cos) > 0.95)) >= 0.8


def virtual_parents(names: Sequence[str], parents: Sequence[int], positions: np.ndarray,
                    axes: np.ndarray | None = None) -> tuple[list[int], list[str]] | None:
    """A hierarchy for a skeleton whose chains hang apart (each its own root), from names and rest geometry.

    A Rigify export of its deform bones only puts ``DEF-thigh.L``, ``DEF-upper_arm.L``, ``DEF-shoulder.L``
    and ``DEF-spine`` directly under the armature: the chains keep their links, but nothing links the
    chains. The body's chain (the longest chain of centre joints, names without a side) is kept; every
    other chain is hung, nearest first (Prim's algorithm), on the joint it starts at. With bone ``axes``
    (J, 3) that run along the bones (:func:`bone_axes_consistent`), that is the linked bone whose tail (its
    child's head, or for a leaf its line) is nearest the chain's first joint (``DEF-shoulder.L`` ends where
    ``DEF-upper_arm.L`` starts); without, a chain running down (a leg) hangs on the body chain's first joint
    (the pelvis) and any other on the nearest linked joint not above its first joint or bone tail (a bone
    with one child ends at that child: a shoulder starting at the neck's head hangs on the chest). A chain
    is never hung on a joint of the other side.

    Returns:
        (parents, notes): the new parent of every joint (the chains' own links kept) and one note naming
        the links made; None when the skeleton has one root, or more roots than a third of its joints (loose
        points, not chains).
    """
    P = np.asarray(positions, dtype=np.float64)
    tree = _Tree(parents, P, names)
    roots = [j for j, p in enumerate(parents) if p < 0]
    if len(roots) < 2 or len(roots) > len(names) / 3 or sum(1 for r in roots if tree.children[r]) < 2:
        return None  # one hierarchy, or no chains at all (loose named points are not chains to link)
    use_axes = axes is not None and bone_axes_consistent(parents, P, axes)
    size = max(float(np.ptp(P, axis=0).max()), 1e-12)

    def chain_length(r: int) -> int:
        return max(tree.depth[j] for j in tree.subtree(r)) - tree.depth[r] + 1

    centre = [r for r in roots if side_of(strip_suffix(names[r])) is None and not is_helper(names[r])]
    main = max(centre or roots, key=lambda r: (chain_length(r), len(tree.subtree(r))))
    linked = set(tree.subtree(main))
    pending = [r for r in roots if r != main]
    tip = max(tree.subtree(main), key=lambda j: tree.dist[j])
    up = P[tip] - P[main]
    up = up / max(float(np.linalg.norm(up)), 1e-12)

    def hangs_down(r: int) -> bool:  # a leg: its chain runs down from its first joint
        return min(float((P[j] - P[r]) @ up) for j in tree.subtree(r)) < -0.25 * size
    new = list(parents)
    links: list[str] = []
    while pending:
        best = None
        for r in pending:
            side = side_of(strip_suffix(names[r]))
            down = not use_axes and hangs_down(r)
            for c in linked:
                other = side_of(strip_suffix(names[c]))
                if side is not None and other is not None and other != side:
                    continue
                if not use_axes and (c != main if down else float((P[c] - P[r]) @ up) > 0.02 * size):
                    continue  # no bone axes: legs hang on the body's first joint, the rest on a joint not above
                d = P[r] - P[c]
                cost = float(np.linalg.norm(d))
                if use_axes:  # Blender: a bone starting at another's tail is its child
                    a = axes[c] / max(float(np.linalg.norm(axes[c])), 1e-12)
                    along = [k for k in tree.children[c] if float((P[k] - P[c]) @ a) > 0.95 * float(
                        np.linalg.norm(P[k] - P[c]))]
                    if along:  # the tail is where the bone's child starts
                        cost = min(cost, float(np.linalg.norm(P[r] - P[along[0]])) - 1e-3 * size)
                    elif not tree.children[c] and float(d @ a) > 0:  # a leaf bone: its line
                        t = float(d @ a)
                        cost = min(cost, float(np.linalg.norm(d - t * a)) + 1e-3 * size)
                elif len(tree.children[c]) == 1:  # a bone's tail is its one child's head: a chain starting there
                    cost = min(cost, float(np.linalg.norm(P[r] - P[tree.children[c][0]])) - 1e-3 * size)
                if best is None or cost < best[0]:
                    best = (cost, r, c)
        if best is None:
            break
        _, r, c = best
        new[r] = c
        linked.update(tree.subtree(r))
        pending.remove(r)
        links.append(f"{names[r]} under {names[c]}")
    shown = ", ".join(links[:8]) + (f" and {len(links) - 8} more" if len(links) > 8 else "")
    note = (f"the chains hang apart ({len(roots)} roots, no parent links between them): a hierarchy built from "
            f"the names and rest geometry{' (bone axes)' if use_axes else ''}: {shown}")
    return new, [note]
