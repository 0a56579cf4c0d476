"""Every committed real FBX file (``tests/data/fbx``, sources and licences in its README) through every command a
user runs on it, with no option: ``invert-shape``, ``scene from-estimate --character``, ``scene export``, and, for
its take, ``data build`` + ``data preview``; posed on the example poses within 3 % of its height (feet to the top
of the head, :attr:`shape_inversion.skeleton_io.Character.height_m`) of its SMPL pose after alignment."""

from __future__ import annotations

import dataclasses
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data" / "fbx"
FILES = {  # file -> (height range in metres, frames of its take)
    "maya_human_ik_7400_ascii.fbx": ((1.75, 1.95), 120),
    "maya_human_ik_7400_binary.fbx": ((1.75, 1.95), 120),
    "maya_kenney_character_7700_binary.fbx": ((3.5, 3.9), 21),  # a big-headed game character, 3.7 m in cm units
}


def test_the_corpus_is_the_committed_folder():
    assert sorted(p.name for p in DATA.glob("*.fbx")) == sorted(FILES)


@pytest.mark.parametrize("name", sorted(FILES))
def test_posed_character_within_3_percent_of_its_height(name):
    from shape_inversion.skeleton_io import _neutral_estimator, read_character
    from workflows.character import build_character, retarget_error_m
    from workflows.examples_gen import example_poses

    char = read_character(DATA / name)
    (lo, hi), _ = FILES[name]
    assert lo < char.height_m < hi
    assert char.height_m > char.head_ankle_height_m  # the top of the head is above the head joint
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the Kenney character is read at its own size (said in a warning)
        est = _neutral_estimator().estimate(char.features, char.mapped_rest())
    cc = build_character(char.skeleton, est, rig=char.rig)
    for person in example_poses():
        pose = dataclasses.replace(person.pose, betas=cc.betas, gender=cc.gender)
        assert 100 * retarget_error_m(pose, cc).mean() / char.height_m <= 3.0, person.name


@pytest.mark.parametrize("name", sorted(FILES))
def test_every_command_takes_it_with_no_option(name, tmp_path):
    from typer.testing import CliRunner

    sys.path.insert(0, str(Path(__file__).parent))
    from estimator_fixtures import framing, people, write_romp
    from helpers import can_render

    from smplik.cli.main import app
    from smplik.data.bvh import read_bvh
    from smplik.data.dataset import load_cache

    path = DATA / name
    _, frames = FILES[name]
    runner = CliRunner()

    def run(*args):
        res = runner.invoke(app, [str(a) for a in args])
        assert res.exit_code == 0, res.output
        return res.output

    run("invert-shape", path, "--out", tmp_path / "shape.json")
    joint_map = json.loads((tmp_path / "shape.json").read_text())["character"]["joint_map"]
    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    romp = write_romp(tmp_path, aa, transl, betas).path
    run("scene", "from-estimate", romp, "--out", tmp_path / "scene", "--character", path, "--no-previews")
    run("scene", "export", tmp_path / "scene" / "scene.json", "--out", tmp_path / "exp")
    bvh = read_bvh(tmp_path / "exp" / "person_0.bvh")  # the file's own skeleton
    assert joint_map["pelvis"] in bvh.joint_names and joint_map["left_wrist"] in bvh.joint_names
    assert (tmp_path / "exp" / "person_0.glb").is_file()
    clips = tmp_path / "clips"
    clips.mkdir()
    (clips / name).symlink_to(path)
    run("data", "build", "--bvh", clips, "--out", tmp_path / "train.npz")  # 24 frames/s: kept at its own rate
    cache = load_cache(tmp_path / "train.npz")
    assert cache.clip_names == (name,) and abs(len(cache) - frames) <= 1
    assert np.isfinite(cache.pose.numpy()).all()
    if can_render():
        said = run("data", "preview", path, "--out", tmp_path / "strip.png", "--frames", "2", "--panel", "96")
        assert f"of {frames}" in said and (tmp_path / "strip.png").is_file()
