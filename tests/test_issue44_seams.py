"""Issue 44's smaller seams, each with the test that would have caught it: the grammar of the folder error, the
"did you mean" of a misspelled joint everywhere joint names are parsed, and the timeline header agreeing with its
keyframe dropdown. (scene.json's relative skeleton paths: tests/test_workflows_scene.py.)"""

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
