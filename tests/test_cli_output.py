"""What the commands print, line by line: no blank first line (a progress bar with no terminal to draw on), the
foot contacts of an animated track per foot, the training bar before any evaluation, and a custom character's
skeleton record usable as a key (the editor caches each character's skeleton by it)."""

from __future__ import annotations

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
    from workflows.animation_cli import contact_summary

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
