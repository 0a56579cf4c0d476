"""What the commands print, line by line: no blank first line (a progress bar with no terminal to draw on), the
foot contacts of an animated track per foot, the training bar before any evaluation, and a custom character's
skeleton record usable as a key (the editor caches each character's skeleton by it)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from typer.testing import CliRunner

from smplik.cli.main import app


@pytest.mark.parametrize("command", [["scene", "from-estimate"], ["scene", "animate"]])
def test_an_error_is_the_first_and_only_line(command, tmp_path):
    bad = tmp_path / "results.npz"
    bad.write_bytes(b"not a zip archive")
    res = CliRunner().invoke(app, [*command, str(bad), "--out", str(tmp_path / "out")])
    assert res.exit_code == 1
    assert res.stderr.splitlines() == [f"error: {bad}: not a readable zip archive (BadZipFile: File is not a zip "
                                       "file)."], res.stderr


def test_foot_contacts_are_counted_per_foot_not_feet_times_frames():
    from workflows.animation.cli import contact_summary

    contacts = np.zeros((537, 2), bool)
    contacts[:300, 0] = True
    contacts[100:537, 1] = True
    assert contact_summary(contacts) == "left foot in contact on 300 of 537 frames, right on 437"
    assert contact_summary(None) == "no foot contacts detected"


def test_the_training_bar_shows_a_dash_until_a_metric_exists():
    from smplik.train import progress_postfix

    assert progress_postfix(0.12345, float("nan"), 812.4) == {"loss": "0.1235", "mpjpe": "-", "samples_s": "812"}
    assert progress_postfix(0.5, 61.25, 90.0)["mpjpe"] == "61.2mm"


def test_a_skeleton_record_with_its_joint_map_is_a_key():
    from workflows.scene import SkeletonSource

    a = SkeletonSource("hero.bvh", joint_map={"pelvis": "Hips", "head": "Head"})
    b = SkeletonSource("hero.bvh", joint_map={"head": "Head", "pelvis": "Hips"})
    c = SkeletonSource("hero.bvh", joint_map={"pelvis": "Hips", "head": "Neck"})
    assert a == b and hash(a) == hash(b) and {a: 1}[b] == 1
    assert a != c and len({a, c, SkeletonSource("hero.bvh")}) == 3


def test_animate_a_bvh_character_to_bvh_and_glb(tmp_path, monkeypatch, best_solver):
    """``scene animate --character hero.bvh --export bvh,glb`` writes both files (the GLB: the character's
    SMPL-SI body, animated over the clip), says why the GLB is not the character's own mesh, and counts foot
    contacts per foot."""
    import pygltflib
    from animation_fixtures import video_motion
    from estimator_fixtures import write_aist

    from workflows.examples_gen import write_mixamo_character

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    aist = write_aist(tmp_path, *video_motion(16, seed=6, fmt="gvhmr"))
    hero = write_mixamo_character(tmp_path / "hero.bvh")
    res = CliRunner().invoke(app, ["scene", "animate", str(aist), "--out", str(tmp_path / "out"), "--character",
                                   str(hero), "--max-effectors", "2", "--export", "bvh,glb"])
    assert res.exit_code == 0, res.output
    lines = res.stderr.splitlines()
    assert lines[0].strip(), res.stderr  # no blank first line
    assert any(line.startswith("person_0: hero.bvh has no mesh; its GLB is the SMPL body") for line in lines)
    assert any(re.search(r"left foot in contact on \d+ of 16 frames, right on \d+$", line) for line in lines)
    assert (tmp_path / "out" / "person_0.bvh").is_file()
    glb = pygltflib.GLTF2.load_binary(str(tmp_path / "out" / "person_0.glb"))
    assert len(glb.skins[0].joints) == 24 and len(glb.animations) == 1
    times = glb.accessors[glb.animations[0].samplers[0].input]
    assert times.count == 16 and times.max[0] == pytest.approx(15 / 60, abs=1e-4)  # AIST++'s 60 frames/s
