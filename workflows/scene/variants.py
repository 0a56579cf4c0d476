"""Variants of a scene character: K alternative poses for its effectors (:mod:`smplik.variants`), each made
persistent as the scene with the character's effectors + the variant's guide effectors (``smplik scene variants``,
the editor's "Variants" control).

Spaces are those of :mod:`workflows.scene`: the character's effectors are in character space and are divided by
its ``scale`` for the solver (SMPL space); the guides come back in SMPL space and are multiplied by ``scale``. A
scene with a ground record (``--ground``) has its floor at y = 0: no variant puts a joint below it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from smplik.variants import Variant
from workflows.scene.characters import SceneCharacter, SceneError, scale_effector
from workflows.scene.document import Scene, save_scene


def character_variants(character: SceneCharacter, solver: Any, k: int = 4, *, seed: int = 0, candidates: int = 32,
                       floor: float | None = None) -> list[Variant]:
    """Up to ``k`` variants of one character's effectors (``solver``: an IKSolver); ``floor`` in character space.
    Returns them in SMPL space (see :func:`with_variant` to put one into the character)."""
    if not character.effectors:
        raise SceneError(f"{character.name}: has no effectors, so there is nothing to vary (add effectors first).")
    effectors = [scale_effector(e, 1.0 / character.scale) for e in character.effectors]
    return solver.sample_variants(effectors, k, betas=character.betas, gender=character.gender, seed=seed,
                                  candidates=candidates, floor=None if floor is None else floor / character.scale)


def with_variant(character: SceneCharacter, variant: Variant) -> SceneCharacter:
    """The character with the variant's guide effectors (character space) added after its own, posed as the
    variant."""
    guides = tuple(scale_effector(g, character.scale) for g in variant.guides)
    return dataclasses.replace(character, effectors=character.effectors + guides, pose=variant.pose)


def scene_variants(scene: Scene, solver: Any, *, k: int = 4, character: str | None = None, seed: int = 0,
                   candidates: int = 32) -> tuple[list[tuple[Scene, int, float]], str]:
    """The scene once per variant of one character (default: the first with effectors).

    Returns ``([(scene, number of guides, mean joint distance to variant 0 in metres), ...], character name)``."""
    names = [c.name for c in scene.characters]
    if character is None:
        index = next((i for i, c in enumerate(scene.characters) if c.effectors), None)
        if index is None:
            raise SceneError("no character of the scene has effectors, so there is nothing to vary.")
    elif character in names:
        index = names.index(character)
    else:
        raise SceneError(f"no character named {character!r:.60}; the scene has {', '.join(names)}.")
    c = scene.characters[index]
    floor = 0.0 if scene.ground is not None else None
    out = []
    for v in character_variants(c, solver, k, seed=seed, candidates=candidates, floor=floor):
        chars = list(scene.characters)
        chars[index] = with_variant(c, v)
        out.append((dataclasses.replace(scene, characters=tuple(chars)), len(v.guides), v.distance_m))
    return out, c.name


def write_variants(scenes: list[tuple[Scene, int, float]], out_dir: str | Path) -> list[Path]:
    """Write ``out_dir/variant_I.json`` for each scene of :func:`scene_variants` (atomically); returns the paths."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise SceneError(f"--out {out}: exists and is not a folder.")
    out.mkdir(parents=True, exist_ok=True)
    return [save_scene(s, out / f"variant_{i}.json") for i, (s, _, _) in enumerate(scenes)]
