"""Journey: one humanoid BVH through the README's "Custom characters" commands, ``smplik invert-shape hero.bvh
--out hero_shape.json --render hero.png`` then ``smplik data build --bvh HERO_DIR --fps 30 --out hero.npz``.

Both read the same rig with no options; the seam holds when the shape SMPL-SI found, posed by the pose data build
retargeted, puts the SMPL joints on the file's own joints. The comparison picture names its colours in a legend,
and the summary line keeps each number next to its unit in an 80-column terminal.
"""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest


@pytest.fixture(scope="module")
def hero(demo, smplik, tmp_path_factory):
    """The demo's Mixamo-named BVH character, alone in a folder, run through both commands."""
    cwd = tmp_path_factory.mktemp("hero")
    (cwd / "hero_bvh").mkdir()
    shutil.copy(demo.out / "examples" / "mixamo_character.bvh", cwd / "hero_bvh" / "hero.bvh")
    shape = smplik("invert-shape", "hero_bvh/hero.bvh", "--out", "hero_shape.json", "--render", "hero.png", cwd=cwd)
    data = smplik("data", "build", "--bvh", "hero_bvh", "--fps", "30", "--out", "hero.npz", cwd=cwd)
    return cwd, shape, data


def test_invert_shape_prints_whole_lines_and_a_picture_with_a_legend(hero):
    from PIL import Image

    from shape_inversion.preview import LEGEND

    cwd, shape, _ = hero
    summary = [line for line in shape.output.splitlines() if "feature residual" in line]
    assert len(summary) == 1, shape.output  # one line, however long: an 80-column wrap once cut "24.65 \nmm"
    assert re.search(r"^rig mixamo, .* max feature residual \d+\.\d+ mm, effective samples [\d.]+ -> hero_shape\.json$",
                     summary[0]), summary[0]
    payload = json.loads((cwd / "hero_shape.json").read_text())
    assert len(payload["betas"]) == 10 and 0.5 < payload["scale"] < 2.0
    with Image.open(cwd / "hero.png") as image:
        pixels = np.asarray(image.convert("RGB"))
    corner = pixels[:80, :300].reshape(-1, 3).astype(int)
    for _, colour in LEGEND:  # every colour of the picture has its swatch in the legend's corner
        swatch = np.round(np.asarray(colour[:3]) * 255)
        assert np.abs(corner - swatch).max(axis=1).min() <= 2, colour


def test_data_build_retargets_onto_the_shape_invert_shape_found(hero):
    import torch

    from smplik.body_model import load_body_model
    from smplik.conventions import JOINT_NAMES
    from smplik.data.bvh import read_bvh

    cwd, _, data = hero
    shape = json.loads((cwd / "hero_shape.json").read_text())
    cache = np.load(cwd / "hero.npz")
    source = read_bvh(cwd / "hero_bvh" / "hero.bvh")
    assert len(cache["pose"]) == source.num_frames and re.search(rf"{source.num_frames} frames", data.output)
    rig, units = shape["character"]["joint_map"], shape["character"]["units_m"]
    assert shape["character"]["up"] == "y"  # the file's frame is the body's: joints compare directly
    model = load_body_model(shape["gender"])
    pose = torch.from_numpy(cache["pose"][:1])
    smpl = model.joints(pose[:, 0], pose[:, 1:], torch.from_numpy(cache["transl"][:1]),
                        torch.tensor([shape["betas"]], dtype=torch.float32))[0].double().numpy() * shape["scale"]
    own = np.array([source.positions[0, source.index(rig[name])] for name in JOINT_NAMES]) * units
    distance = np.linalg.norm((smpl - smpl[0]) - (own - own[0]), axis=1)  # pelvis-relative
    assert distance.mean() < 0.02 and distance.max() < 0.04, \
        dict(zip(JOINT_NAMES, np.round(distance * 1000), strict=True))
