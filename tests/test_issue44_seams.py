"""Issue 44's smaller seams, each with the test that would have caught it: the grammar of the folder error, the
"did you mean" of a misspelled joint everywhere joint names are parsed, and the timeline header agreeing with its
keyframe dropdown, scene.json's skeleton paths relative to the scene file."""

from __future__ import annotations

import pytest

from smplik.conventions import joint_index, unknown_joint
from smplik.validation import article, read_text


def test_a_folder_given_for_a_file_reads_an_effector_file(tmp_path):
    with pytest.raises(ValueError, match=r"is a folder, not an effector file\."):
        read_text(tmp_path, what="effector file")
    with pytest.raises(ValueError, match=r"is a folder, not a scene file\."):
        read_text(tmp_path, what="scene file")
    assert [article(w) for w in ("effector file", "animation", "image", "output", "BVH file", "unit", "user")] == [
        "an", "an", "an", "an", "a", "a", "a"]


def test_a_misspelled_joint_gets_a_suggestion_everywhere_names_are_parsed():
    from smplik.effectors import Effector, EffectorError, parse_effector_dict

    assert "did you mean 'left_wrist'?" in unknown_joint("left_wirst")
    assert "did you mean 'right_elbow'?" in unknown_joint("Right_Elbow")
    assert "did you mean" not in unknown_joint("tail")  # nothing close: no guess
    with pytest.raises(ValueError, match="did you mean 'left_wrist'"):
        joint_index("left_wirst")
    with pytest.raises(EffectorError, match="did you mean 'head'"):
        Effector.position("haed", (0.0, 0.0, 0.0))
    with pytest.raises(Exception, match=r"joint: unknown joint 'rigth_ankle' \(did you mean 'right_ankle'\?\)"):
        parse_effector_dict({"joint": "rigth_ankle", "type": "position", "value": [0, 0, 0]}, "effectors[0]")
    from smplik.tracking.io import TRACKERS_FORMAT, TRACKERS_VERSION, signals_from_dict  # VR trackers

    with pytest.raises(Exception, match="did you mean 'head'"):
        signals_from_dict({"format": TRACKERS_FORMAT, "version": TRACKERS_VERSION, "fps": 30,
                           "trackers": {"hed": {"position": [[0, 1.6, 0]]}}})
    from shape_inversion.rigs import rig_from_dict  # a rig map file

    with pytest.raises(Exception, match="did you mean 'pelvis'"):
        rig_from_dict({"joints": {"pelvs": "Hips"}}, "my_rig")
    from smplik.data.retarget import load_preset  # a retarget preset

    with pytest.raises(Exception, match="did you mean 'left_hip'"):
        load_preset({"joints": {"left_hp": "LeftUpLeg", "pelvis": "Hips"}})


def test_scene_json_stores_skeleton_paths_relative_to_itself_so_a_moved_folder_works(shipped_solver, tmp_path):
    """Issue 44: ``scene.json`` stored the absolute skeleton path (``scene from-estimate --character`` and
    ``smplik edit --character`` resolve it), so moving the folder broke it. Now saved relative to the scene file;
    an old file's absolute path still reads."""
    import json
    import shutil

    import numpy as np

    from workflows.character import load_character
    from workflows.editor.state import EditorState
    from workflows.examples_gen import write_mixamo_character
    from workflows.scene import Scene, SceneCharacter, SkeletonSource, save_scene

    first = tmp_path / "project"
    bvh = write_mixamo_character(first / "chars" / "hero.bvh")
    char = load_character(bvh)
    c = SceneCharacter("hero", char.gender, np.asarray(char.betas), char.scale,
                       SkeletonSource(str(bvh.resolve()), "mixamo"))  # what the commands put in a scene
    save_scene(Scene((c,)), first / "scene.json")
    assert json.loads((first / "scene.json").read_text())["characters"][0]["skeleton"]["path"] == "chars/hero.bvh"
    moved = tmp_path / "elsewhere" / "moved"
    shutil.move(str(first), str(moved))
    solver = shipped_solver
    state = EditorState.open(moved / "scene.json", solver)
    assert state.skeleton_bones() is not None  # the skeleton is found in the moved folder
    old = json.loads((moved / "scene.json").read_text())  # an old file: the absolute path
    old["characters"][0]["skeleton"]["path"] = str((moved / "chars" / "hero.bvh").resolve())
    (moved / "old.json").write_text(json.dumps(old))
    assert EditorState.open(moved / "old.json", solver).skeleton_bones() is not None
