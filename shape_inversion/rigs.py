"""Joint-name maps from common rigs to SMPL's joints (one data file per rig in ``smplik/data/presets/``).

The presets are the one registry shared with ``smplik data build`` (:mod:`smplik.data.retarget`):
``cmu``, ``makehuman``, ``mixamo``, ``smpl``, ``unity``, ``unreal``. The retargeting keys of a
preset (``floor``, ``rest``, ``motion_start``, ``aim``) are ignored here.

A map file is JSON::

    {"name": "cmu", "description": "...", "units": 0.056444, "up": "y",
     "joints": {"right_hip": "RightUpLeg", "right_knee": "RightLeg", ...}}

``joints`` maps SMPL joint names (:data:`smplik.conventions.JOINT_NAMES`) to the rig's joint
names; ``units`` (metres per file unit) and ``up`` are optional hints used when the caller leaves
them on ``auto``. A user map file may use the same layout or be a bare ``{smpl_name: rig_name}``
object. Rig names match exactly first, then case-insensitively with any ``namespace:`` or
``path|`` prefix removed (``mixamorig1:RightUpLeg`` matches ``mixamorig:RightUpLeg``).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from shape_inversion.features import REQUIRED_JOINTS
from shape_inversion.rig_names import NameMatchError, match_humanoid
from smplik.conventions import JOINT_NAMES, unknown_joint
from smplik.data.retarget import PRESET_DIR, preset_names


class RigError(ValueError):
    """Unknown rig preset, malformed map file, or a skeleton lacking the joints SMPL-SI needs."""


@dataclass(frozen=True)
class RigMap:
    """A joint-name map.

    Attributes:
        name: preset name or the map file's path.
        joints: ``(smpl_name, rig_name)`` pairs, in SMPL order.
        description: free text.
        units: metres per file unit, when the rig has a conventional unit (hint).
        up: the rig's conventional up axis (hint), e.g. ``"y"`` or ``"z"``.
    """

    name: str
    joints: tuple[tuple[str, str], ...]
    description: str = ""
    units: float | None = None
    up: str | None = None
    warnings: tuple[str, ...] = ()
    """Doubts of the rig mapper, each naming the joints concerned."""
    root: str | None = None
    """The root joint of the hierarchy the map uses (rigs with several roots)."""

    @property
    def smpl_to_rig(self) -> dict[str, str]:
        return dict(self.joints)


def _normalise(name: str) -> str:
    """Lower-case name with any ``namespace:`` / ``path|`` prefix removed."""
    return name.rsplit("|", 1)[-1].rsplit(":", 1)[-1].strip().lower()


def rig_from_dict(data: Mapping, name: str) -> RigMap:
    """Build a :class:`RigMap` from a parsed map file (full layout or bare ``{smpl: rig}``)."""
    if not isinstance(data, Mapping):
        raise RigError(f"Rig map {name}: expected a JSON object, got {type(data).__name__}.")
    joints = data.get("joints", data)
    if not isinstance(joints, Mapping) or not all(isinstance(v, str) for v in joints.values()):
        raise RigError(f"Rig map {name}: 'joints' must map SMPL joint names to rig joint names (strings).")
    unknown = [k for k in joints if k not in JOINT_NAMES]
    if unknown:
        raise RigError(f"Rig map {name}: {unknown_joint(unknown[0])}")
    units = data.get("units") if "joints" in data else None
    up = data.get("up") if "joints" in data else None
    return RigMap(name=str(data.get("name", name)) if "joints" in data else name,
                  joints=tuple((s, joints[s]) for s in JOINT_NAMES if s in joints),
                  description=str(data.get("description", "")) if "joints" in data else "",
                  units=None if units is None else float(units), up=None if up is None else str(up))


def available_presets() -> tuple[str, ...]:
    """Names of the built-in presets (the one registry :data:`smplik.data.retarget.PRESET_DIR`), sorted."""
    return preset_names()


def load_preset(name: str) -> RigMap:
    """Load a built-in preset by name (case-insensitive); :class:`RigError` lists the presets otherwise."""
    key = name.strip().lower()
    presets = available_presets()
    if key not in presets:
        raise RigError(f"Unknown rig preset {name!r}; available presets: {', '.join(presets)} "
                       "(or pass a map file with --map).")
    text = (PRESET_DIR / f"{key}.json").read_text(encoding="utf-8")
    return rig_from_dict(json.loads(text), key)


def load_map_file(path: str | Path) -> RigMap:
    """Load a user map file (see the module docstring for the layout)."""
    path = Path(path)
    from smplik.validation import read_json

    data = read_json(path, RigError, what="rig map file")  # bounded read (smplik.limits.JSON_BYTES)
    return rig_from_dict(data, str(path))


def match_joints(rig: RigMap, names: Iterable[str]) -> tuple[dict[str, int], int]:
    """Indices of the rig's joints in ``names``: exact names, then without prefixes and case, then without
    exporter suffixes (``mixamorig:Hips_01``, ``Hips.001``) when one joint has that stem.

    Returns:
        ``{smpl_name: index into names}`` for every mapped joint found, and how many matched exactly.
    """
    names = list(names)
    exact = {n: i for i, n in enumerate(names)}
    from shape_inversion.rig_mapper import strip_suffix

    loose: dict[str, int] = {}
    stripped: dict[str, list[int]] = {}
    for i, n in enumerate(names):
        loose.setdefault(_normalise(n), i)
        stripped.setdefault(_normalise(strip_suffix(n)), []).append(i)
    found: dict[str, int] = {}
    n_exact = 0
    for smpl, rig_name in rig.joints:
        if rig_name in exact:
            found[smpl] = exact[rig_name]
            n_exact += 1
        elif _normalise(rig_name) in loose:
            found[smpl] = loose[_normalise(rig_name)]
        elif len(stripped.get(_normalise(rig_name), [])) == 1:  # Sketchfab's mixamorig:Hips_01: one joint only
            found[smpl] = stripped[_normalise(rig_name)][0]
    return found, n_exact


def missing_required(rig: RigMap, found: Mapping[str, int]) -> list[str]:
    """SMPL joints SMPL-SI needs that the skeleton lacks under ``rig``."""
    return [j for j in REQUIRED_JOINTS if j not in found]


def missing_message(rig: RigMap, found: Mapping[str, int], source: str = "the skeleton") -> str:
    """Error text naming the missing SMPL joints and the rig names the map expected for them."""
    expected = rig.smpl_to_rig
    parts = [f"{j} (map expects {expected[j]!r})" if j in expected else f"{j} (not in the map)"
             for j in missing_required(rig, found)]
    return (f"{source} lacks joints SMPL-SI needs under rig map {rig.name!r}: missing SMPL joints "
            f"{', '.join(parts)}. Pass --map with a file mapping these SMPL joints to your rig's names.")


def _best_preset(names: list[str]) -> tuple[RigMap, dict[str, int]]:
    """The preset finding the most joints (then the most exact names), with what it found."""
    scored = []
    for preset in available_presets():
        rig = load_preset(preset)
        found, n_exact = match_joints(rig, names)
        n_required = len(REQUIRED_JOINTS) - len(missing_required(rig, found))
        scored.append(((n_required, len(found), n_exact), rig, found))
    scored.sort(key=lambda t: t[0], reverse=True)
    return scored[0][1], scored[0][2]


def detect_rig(names: Iterable[str], parents: Sequence[int] | None = None, positions=None, *,
               root: str | None = None) -> RigMap:
    """The map of a skeleton's joints to SMPL's: the rig mapper's, or a preset's when that is as complete.

    With ``parents`` and ``positions`` (J, 3), :func:`shape_inversion.rig_mapper.map_skeleton` maps the
    skeleton by topology, geometry and names (``root`` picks the hierarchy); a preset is chosen only
    when it finds every required joint and every SMPL joint the mapper maps (and, with several roots,
    only joints of the mapper's hierarchy). The mapper's map is a :class:`RigMap` named
    ``"auto"`` whose ``description`` lists it and whose ``warnings`` hold its doubts. Without positions,
    the best preset, else :func:`shape_inversion.rig_names.match_humanoid` (names checked against the
    hierarchy).

    Raises:
        RigError: nothing works (names the closest preset and what it lacks, and why the mapper failed).
    """
    from shape_inversion.rig_mapper import RigMappingError, map_skeleton

    names = list(names)
    best, found = _best_preset(names)
    complete = not missing_required(best, found)
    why = "no hierarchy given"
    if parents is not None and positions is not None:
        try:
            mapping = map_skeleton(names, parents, positions, root=root)
        except RigMappingError as exc:
            why = f"rig mapper: {exc}"
        else:
            in_tree = {j for j in range(len(names)) if _root_of(parents, j) == mapping.root}
            root_name = names[mapping.root] if sum(p < 0 for p in parents) > 1 else None
            if complete and set(found) >= set(mapping.joints) and set(found.values()) <= in_tree:
                from shape_inversion.rig_mapper import map_doubts

                found, notes = _spine_to_arms_branch(best, found, mapping.joints, names, parents)
                return dataclasses.replace(best, root=root_name, joints=_pairs(names, found) if notes else best.joints,
                                           warnings=notes + tuple(map_doubts(names, parents, positions, found)))
            pairs = tuple((s, names[j]) for s, j in mapping.joints.items())
            return RigMap("auto", pairs, "matched by topology: " + ", ".join(f"{s}={r}" for s, r in pairs),
                          warnings=mapping.warnings, root=root_name)
        if root is not None:
            raise RigError(f"Could not map the skeleton under --root {root!r}: {why}")
    if complete:
        return best
    if parents is not None:
        try:
            matched = match_humanoid(names, parents, REQUIRED_JOINTS)
            pairs = tuple((s, names[matched[s]]) for s in JOINT_NAMES if s in matched)
            return RigMap("auto", pairs, "matched by name and topology: "
                          + ", ".join(f"{s}={r}" for s, r in pairs))
        except NameMatchError as exc:
            why = f"{why}; name matching: {exc}"
    if "not a human: " in why:  # the mapper saw a body and its geometry is not a human's: say so first
        feature = why.split("not a human: ", 1)[1].split(";", 1)[0]
        raise RigError(f"Not a human: {feature} (rig mapper: no humanoid found: no hierarchy has two legs and a "
                       "spine meeting at a pelvis with two arms branching from the spine).")
    sample = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
    raise RigError(f"Could not detect the rig from the joint names ({sample}); presets: "
                   f"{', '.join(available_presets())}; {why}. Closest preset: "
                   + missing_message(best, found) + " Or choose a preset with --rig.")


_SPINE = ("spine1", "spine2", "spine3")


def _pairs(names: Sequence[str], found: dict[str, int]) -> tuple[tuple[str, str], ...]:
    return tuple((s, names[found[s]]) for s in JOINT_NAMES if s in found)


def _spine_to_arms_branch(rig: RigMap, found: dict[str, int], mapped: dict[str, int], names: Sequence[str],
                          parents: Sequence[int]) -> tuple[dict[str, int], tuple[str, ...]]:
    """A preset's spine moved up to where the skeleton's arms branch, when the preset stops below it.

    SMPL's spine3 is the joint the neck and both collars hang from. A preset naming a lower joint (MakeHuman's
    ``spine02``, while the default skeleton's clavicles and neck hang from ``spine01``) leaves the upper chest
    unmapped and puts SMPL's spine a bone low: the chest, neck and arms of a retargeted pose then swing about
    the wrong joint. Then spine1..3 are taken from the rig mapper (``mapped``: SMPL joint -> index, its
    spine3 the arms' branch point), with one note naming both joints. Returns ``(found, notes)``.
    """
    from shape_inversion.rig_names import is_ancestor

    mine, theirs = found.get("spine3"), mapped.get("spine3")
    if mine is None or theirs is None or mine == theirs or not is_ancestor(mine, theirs, parents):
        return found, ()
    out = {s: j for s, j in found.items() if s not in _SPINE} | {s: mapped[s] for s in _SPINE if s in mapped}
    spine = ", ".join(f"{s}={names[out[s]]}" for s in _SPINE if s in out)
    return out, (f"preset {rig.name!r} puts spine3 at {names[mine]!r}, below {names[theirs]!r} where the neck and "
                 f"arms branch: spine from the skeleton ({spine})",)


def _root_of(parents: Sequence[int], j: int) -> int:
    while parents[j] >= 0:
        j = parents[j]
    return j
