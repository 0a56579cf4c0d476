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

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from shape_inversion.features import REQUIRED_JOINTS
from smplik.conventions import JOINT_NAMES
from smplik.data.retarget import PRESET_DIR, preset_names
from smplik.data.rig_names import NameMatchError, match_humanoid


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
        raise RigError(f"Rig map {name}: unknown SMPL joint names {', '.join(map(repr, unknown))}; "
                       f"valid names: {', '.join(JOINT_NAMES)}.")
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
    """Indices of the rig's joints in ``names``.

    Returns:
        ``{smpl_name: index into names}`` for every mapped joint found, and how many matched exactly.
    """
    names = list(names)
    exact = {n: i for i, n in enumerate(names)}
    loose: dict[str, int] = {}
    for i, n in enumerate(names):
        loose.setdefault(_normalise(n), i)
    found: dict[str, int] = {}
    n_exact = 0
    for smpl, rig_name in rig.joints:
        if rig_name in exact:
            found[smpl] = exact[rig_name]
            n_exact += 1
        elif _normalise(rig_name) in loose:
            found[smpl] = loose[_normalise(rig_name)]
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


def detect_rig(names: Iterable[str], parents: Sequence[int] | None = None) -> RigMap:
    """The preset that best matches the joint ``names``; else, with ``parents``, a map matched by name and topology.

    Preset score: required joints found, then exact matches, then all mapped joints found. When no
    preset provides every required joint, :func:`smplik.data.rig_names.match_humanoid` matches the
    names across the common naming schemes and checks the match against the hierarchy; the map it
    chose is the returned :class:`RigMap` named ``"auto"`` (its ``description`` lists it).

    Raises:
        RigError: neither works (names the closest preset and what it lacks, and why name matching failed).
    """
    names = list(names)
    scored = []
    for preset in available_presets():
        rig = load_preset(preset)
        found, n_exact = match_joints(rig, names)
        n_required = len(REQUIRED_JOINTS) - len(missing_required(rig, found))
        scored.append(((n_required, n_exact, len(found)), rig, found))
    scored.sort(key=lambda t: t[0], reverse=True)
    (n_required, _, _), best, found = scored[0]
    if n_required < len(REQUIRED_JOINTS):
        why = "no hierarchy given"
        if parents is not None:
            try:
                matched = match_humanoid(names, parents, REQUIRED_JOINTS)
                pairs = tuple((s, names[matched[s]]) for s in JOINT_NAMES if s in matched)
                return RigMap("auto", pairs, "matched by name and topology: "
                              + ", ".join(f"{s}={r}" for s, r in pairs))
            except NameMatchError as exc:
                why = str(exc)
        sample = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
        raise RigError(f"Could not detect the rig from the joint names ({sample}); presets: "
                       f"{', '.join(available_presets())}; name matching: {why}. Closest preset: "
                       + missing_message(best, found) + " Or choose a preset with --rig.")
    return best
