"""``smplik data build --bvh DIR`` with no map: the rig mapper maps each clip (CMU dance, a DAZ/Poser skeleton)."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner


def test_cmu_dance_builds_a_training_cache_with_no_map(shared_data, tmp_path):
    import typer

    from shape_inversion.auto_preset import auto_preset
    from shape_inversion.data_build_cli import build
    from smplik.data.bvh import read_bvh
    from smplik.data.dataset import load_cache
    from smplik.data.retarget import bone_direction_errors, retarget_bvh

    src = shared_data.file("data/cmu-dance/indian_04.bvh")
    motion = read_bvh(src)
    preset = auto_preset(motion)  # mapped by topology: no preset knows hip/abdomen/lThigh/rShin
    assert preset.joints["left_hip"] == "lThigh" and preset.joints["right_elbow"] == "rForeArm"
    assert preset.joints["spine3"] == "chest" and preset.up == "y" and preset.units == 0.01
    clip = retarget_bvh(motion, preset="auto", fps=30, rig_mapper=auto_preset)
    errors = bone_direction_errors(clip, frames=slice(0, None, 10))
    assert errors.mean() < 1.0, errors.group_means()  # the retargeted bones follow the dancer's

    folder = tmp_path / "dance"
    folder.mkdir()
    (folder / "indian_04.bvh").symlink_to(src)
    app = typer.Typer()
    app.command()(build)
    out = tmp_path / "dance.npz"
    result = CliRunner().invoke(app, ["--bvh", str(folder), "--out", str(out), "--fps", "10"])
    assert result.exit_code == 0, result.output
    cache = load_cache(out)
    assert abs(len(cache) - motion.num_frames / 12) <= 2  # 120 fps -> 10 fps, no rest frame dropped
    assert cache.clip_names == ("indian_04.bvh",) and cache.settings["preset"] == "auto"
    assert np.isfinite(cache.pose.numpy()).all() and float(cache.pose.abs().max()) > 0.1
