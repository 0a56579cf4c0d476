"""BVH files in the layout of real producers (:mod:`tests.bvh_producers`: Perception Neuron / Axis Neuron,
video2bvh's Human3.6M skeleton, a MediaPipe-to-BVH tool) through ``invert-shape``, ``data build`` and
``data preview`` with no options, each command reading the same rig map (issue 42, item 3)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from bvh_producers import write_axis_neuron_bvh, write_mediapipe_bvh, write_video2bvh_bvh  # noqa: E402


def _walk(T: int = 8) -> np.ndarray:
    """(T, 22, 3): SMPL joints (y up, metres) of our body swinging its legs and arms, feet on the ground."""
    from scipy.spatial.transform import Rotation

    from workflows.animation.clips import joints_of, rest_joints

    phase = 2 * np.pi * np.arange(T) / T
    aa = np.zeros((T, 24, 3))
    aa[:, 1, 0], aa[:, 2, 0] = 0.4 * np.sin(phase), -0.4 * np.sin(phase)
    aa[:, 4, 0], aa[:, 5, 0] = 0.4 * (1 + np.sin(phase)), 0.4 * (1 - np.sin(phase))
    aa[:, 16, 2], aa[:, 17, 2] = -1.1, 1.1
    J = rest_joints(np.zeros(10), "neutral")
    transl = np.stack([np.zeros(T), np.full(T, -J[:, 1].min()), 0.04 * np.arange(T)], 1)
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    return joints_of(R, transl, J)[:, :22]


PRODUCERS = {
    "axis_neuron": lambda p: write_axis_neuron_bvh(p / "neuron.bvh"),
    "axis_neuron_no_displacement": lambda p: write_axis_neuron_bvh(p / "neuron.bvh", displacement=False),
    "video2bvh": lambda p: write_video2bvh_bvh(p / "video2bvh.bvh"),
    "mediapipe": lambda p: write_mediapipe_bvh(p / "mediapipe.bvh", _walk()),
}


def _cli(*args):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.parametrize("producer", sorted(PRODUCERS))
def test_invert_shape_and_data_build_read_the_same_map(producer, tmp_path):
    """``invert-shape`` succeeds with no option, and ``data build``'s retarget map is the one it prints."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.retarget import read_motion, resolve_joint_names

    path = PRODUCERS[producer](tmp_path)
    res = _cli("invert-shape", path, "--out", tmp_path / "shape.json")
    assert res.exit_code == 0, res.output
    shape_map = json.loads((tmp_path / "shape.json").read_text())["character"]["joint_map"]
    motion = read_motion(path)
    preset = auto_preset(motion)
    build_map = {k: motion.joint_names[i] for k, i in resolve_joint_names(preset.joints, motion.joint_names).items()}
    assert build_map == shape_map
    assert set(build_map) >= {"pelvis", "left_hip", "right_knee", "left_ankle", "head", "right_wrist", "spine1"}


def test_axis_neuron_maps_its_four_spine_joints_where_its_arms_branch(tmp_path):
    """Axis Neuron's ``Spine .. Spine3``: spine3 is ``Spine3`` (the arms' parent) in every command, not the
    Mixamo preset's ``Spine2``; no toe joints: the feet are the last leg joints."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.retarget import read_motion

    preset = auto_preset(read_motion(write_axis_neuron_bvh(tmp_path / "n.bvh")))
    assert preset.joints["spine3"] == "Spine3" and preset.joints["spine1"] == "Spine"
    assert preset.joints["left_ankle"] == "LeftFoot" and "left_foot" not in preset.joints


def test_video2bvh_has_no_head_joint_the_neck_stands_for_it(tmp_path):
    """video2bvh writes the head as the neck's End Site: the map's head is the last joint of the head chain."""
    from shape_inversion.skeleton_io import read_character

    char = read_character(write_video2bvh_bvh(tmp_path / "v.bvh"))
    assert char.up == "z" and char.joint_map["head"] == "Neck" and char.joint_map["spine3"] == "Thorax"
    assert 1.4 < char.height_m < 2.1


@pytest.mark.parametrize("producer", sorted(PRODUCERS))
def test_data_build_keeps_every_frame(producer, tmp_path):
    import typer
    from typer.testing import CliRunner

    from shape_inversion.data_build_cli import build
    from smplik.data.bvh import read_bvh
    from smplik.data.dataset import load_cache

    folder = tmp_path / "clips"
    folder.mkdir()
    path = PRODUCERS[producer](folder)
    frames, fps = read_bvh(path).num_frames, 1 / read_bvh(path).frame_time
    app = typer.Typer()
    app.command()(build)
    out = tmp_path / "cache.npz"
    res = CliRunner().invoke(app, ["--bvh", str(folder), "--out", str(out), "--fps", str(fps)])
    assert res.exit_code == 0, res.output
    cache = load_cache(out)
    assert len(cache) == frames and cache.clip_names == (path.name,)
    assert np.isfinite(cache.pose.numpy()).all() and float(cache.pose.abs().max()) > 0.05


@pytest.mark.parametrize("producer", sorted(PRODUCERS))
def test_data_preview_draws_it(producer, tmp_path):
    from helpers import can_render

    if not can_render():
        pytest.skip("no offscreen rendering (EGL/OSMesa) here")
    path = PRODUCERS[producer](tmp_path)
    out = tmp_path / "strip.png"
    res = _cli("data", "preview", path, "--out", out, "--frames", "2", "--panel", "160")
    assert res.exit_code == 0, res.output
    from PIL import Image

    img = np.asarray(Image.open(out).convert("RGB"), dtype=np.int16)
    drawn = np.abs(img - img[0, 0]).sum(-1) > 30  # not the background
    red = (img[..., 0] > 150) & (img[..., 1] < 110)  # the source skeleton
    # body and skeleton at the same size, both in view: neither a dot nor off the panel
    assert 0.03 < drawn.mean() < 0.5 and red.mean() > 0.001, (drawn.mean(), red.mean())
