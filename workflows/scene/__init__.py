"""The scene stage: an estimator's output -> an editable scene of solved characters -> edits, previews, exports.

* :mod:`.document`: the scene file (``smplik-scene``: format, spaces, strict reader) and :class:`Scene`;
* :mod:`.characters`: one character's records (:class:`SceneCharacter`, :class:`SkeletonSource`) and its solve;
* :mod:`.pipeline`: ``scene from-estimate`` (estimate -> SMPL-SI -> retargeting -> effector recovery -> scene);
* :mod:`.recovery`: effectors recovered from a target pose; :mod:`.edits`: drags and scripted edits;
* :mod:`.previews`: rendered previews; :mod:`.export`: BVH / glTF export.

The scene API users import from here: ``from workflows.scene import load_scene, save_scene``.
"""

__all__ = ["MAX_CHARACTERS", "SCENE_FORMAT", "SCENE_VERSION", "GroundRecord", "Scene", "SceneCharacter", "SceneError",
           "SkeletonSource", "character_joints", "load_scene", "save_scene", "scale_effector", "scene_from_dict",
           "solve_character", "solve_scene"]

from workflows.scene.characters import (
    GroundRecord,
    SceneCharacter,
    SceneError,
    SkeletonSource,
    character_joints,
    scale_effector,
    solve_character,
)
from workflows.scene.document import (
    MAX_CHARACTERS,
    SCENE_FORMAT,
    SCENE_VERSION,
    Scene,
    load_scene,
    save_scene,
    scene_from_dict,
    solve_scene,
)
