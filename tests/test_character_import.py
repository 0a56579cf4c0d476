"""Real-layout character files (Mixamo/Rokoko/CMU BVH, Blender-style GLB and .gltf + .bin) give the same
SMPL-SI body as the same skeleton in plain metres; glTF safety; one set of character options."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from shape_inversion.options import CharacterOptions, CharacterOptionsError
from shape_inversion.skeleton_io import SkeletonError, read_character, read_gltf
from smplik.conventions import JOINT_NAMES
from smplik.units import UNIT_NAMES, detect_units
from workflows.layout_examples import (
    CMU_UNIT_M,
    smpl_rest,
    write_cmu_bvh,
    write_mixamo_bvh,
    write_mixamo_gltf,
    write_plain_json,
    write_rokoko_bvh,
)

PROPORTIONS = {"leg": 1.06, "arm": 0.95}


@pytest.fixture(scope="module")
def body():
    """A non-average skeleton (longer legs, shorter arms) from the built-in body, with its mesh."""
    J, V, F, W = smpl_rest()
    J = J.copy()
    for chain, k in (("knee", PROPORTIONS["leg"]), ("ankle", PROPORTIONS["leg"])):
        for side in ("left", "right"):
            j = JOINT_NAMES.index(f"{side}_{chain}")
            J[j] = J[j - 3] + k * (J[j] - J[j - 3])
    return J, V, F, W


@pytest.fixture(scope="module")
def estimator():
    from shape_inversion.estimator import ShapeEstimator
    from smplik.body_model import load_body_model

    return ShapeEstimator.build(load_body_model("neutral"))


@pytest.fixture(scope="module")
def files(body, tmp_path_factory):
    J, V, F, W = body
    d = tmp_path_factory.mktemp("chars")
    return {
        "plain": write_plain_json(d / "plain.json", J),
        "mixamo_bvh": write_mixamo_bvh(d / "mixamo.bvh", J),
        "rokoko_bvh": write_rokoko_bvh(d / "rokoko.bvh", J),
        "cmu_bvh": write_cmu_bvh(d / "cmu.bvh", J),
        "glb": write_mixamo_gltf(d / "mixamo.glb", J, (V, F, W)),
        "gltf_bin": write_mixamo_gltf(d / "sub" / "mixamo.gltf", J, external_bin=True)
        if (d / "sub").mkdir() is None else None,
    }


@pytest.mark.parametrize("layout", ["mixamo_bvh", "rokoko_bvh", "cmu_bvh", "glb", "gltf_bin"])
def test_real_layouts_give_the_plain_metres_body(files, estimator, layout):
    plain = read_character(files["plain"])
    for rest in ("frame0", "offsets"):
        char = read_character(files[layout], CharacterOptions(rest=rest))
        np.testing.assert_allclose(char.features, plain.features, atol=1e-5)
        assert 1.0 < char.head_ankle_height_m < 2.0
    a, b = estimator.estimate(char.features), estimator.estimate(plain.features)
    assert abs(a.scale - b.scale) <= max(b.scale_std, 1e-3)
    assert np.all(np.abs(a.betas - b.betas) <= np.maximum(b.betas_std, 1e-3))


def test_mixamo_position_channels_replace_offsets(files):
    """Per the BVH convention: with additive channels every bone would be doubled (0.9 m thighs)."""
    from smplik.data.bvh import read_bvh

    m = read_bvh(files["mixamo_bvh"])
    assert m.position_mode == "replace"
    np.testing.assert_allclose(m.local_translations[0, 1:], m.offsets[1:], atol=1e-9)
    doubled = read_bvh(files["mixamo_bvh"], position_mode="add")
    np.testing.assert_allclose(doubled.local_translations[0, 1:], 2 * m.offsets[1:], atol=1e-9)


def test_cmu_units_are_detected_without_the_cmu_preset(body, tmp_path):
    J = body[0]
    path = write_mixamo_bvh(tmp_path / "cmu_units.bvh", J * (0.01 / CMU_UNIT_M))  # Mixamo names, CMU units
    char = read_character(path)
    assert char.units_source == "detected" and char.units_m == pytest.approx(CMU_UNIT_M)
    assert detect_units(30.0) == "cmu" and detect_units(170.0) == "cm" and detect_units(17.0) == "dm"
    assert UNIT_NAMES["cmu"] == pytest.approx(0.0254 / 0.45)
    given = read_character(path, CharacterOptions(units="cmu"))
    np.testing.assert_allclose(given.features, char.features)


def test_glb_nodes_and_inverse_bind_agree_and_carry_the_mesh(files):
    a = read_gltf(files["glb"], bind="inverse_bind")
    b = read_gltf(files["glb"], bind="nodes")
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-5)
    assert a.names[0] == "mixamorig:Hips" and a.parents[0] == -1
    from workflows.character_mesh import skinned_mesh

    mesh = skinned_mesh(a.gltf)
    assert mesh is not None and mesh.faces.shape[1] == 3
    np.testing.assert_allclose(mesh.weights.sum(1), 1.0, atol=1e-5)


def _gltf_with_uri(tmp_path, uri: str):
    src = write_mixamo_gltf(tmp_path / "c.gltf", smpl_rest()[0], external_bin=True)
    data = json.loads(src.read_text())
    data["buffers"][0]["uri"] = uri
    src.write_text(json.dumps(data))
    return src


@pytest.mark.parametrize("uri", ["../../../../etc/passwd", "/etc/passwd", "http://example.com/a.bin",
                                 "file:///etc/passwd", "sub/../../c.bin", "C:\\\\x.bin"])
def test_gltf_buffer_uris_stay_inside_the_folder(tmp_path, uri):
    path = _gltf_with_uri(tmp_path, uri)
    with pytest.raises(SkeletonError, match="buffers\\[0\\]") as info:
        read_gltf(path)
    assert "\n" not in str(info.value)


def test_truncated_glb_is_refused(files, tmp_path):
    data = files["glb"].read_bytes()
    short = tmp_path / "short.glb"
    short.write_bytes(data[:-8])
    with pytest.raises(SkeletonError, match="byteLength|past the end|Cannot read"):
        read_gltf(short)
    # an accessor reaching past its buffer view (declared lengths consistent, count too large)
    import pygltflib

    g = pygltflib.GLTF2.load_binary(str(files["glb"]))
    g.accessors[g.skins[0].inverseBindMatrices].count += 1
    bad = tmp_path / "bad.glb"
    g.save_binary(str(bad))
    with pytest.raises(SkeletonError, match="past the end"):
        read_gltf(bad)
    assert struct.unpack("<I", bad.read_bytes()[:4])[0] == 0x46546C67


def test_character_options_validate_and_round_trip():
    o = CharacterOptions(rig="mixamo", units="cmu", up="-z", rest="offsets", bind="nodes", positions="add",
                         max_joints=50)
    assert CharacterOptions.from_dict(o.to_dict()) == o
    for bad in ({"units": "furlong"}, {"rest": "frame1"}, {"up": "w"}, {"max_joints": 0},
                {"rig": "mixamo", "map": "m.json"}, {"positions": "sum"}):
        with pytest.raises(CharacterOptionsError, match="character option"):
            CharacterOptions(**bad)
    with pytest.raises(CharacterOptionsError, match="unknown character option"):
        CharacterOptions.from_dict({"unit": "m"})


def test_scene_stores_the_character_options():
    from workflows.scene import SkeletonSource, scene_from_dict

    o = CharacterOptions(rig="cmu", units="cmu", rest="offsets")
    src = SkeletonSource.from_options("a.bvh", o)
    assert src.options == o
    scene = {"format": "smplik-scene", "version": 1, "characters": [
        {"name": "p", "skeleton": src.to_dict()}]}
    assert scene_from_dict(scene).characters[0].skeleton.options == o
    scene["characters"][0]["skeleton"]["rest"] = "frame9"
    with pytest.raises(ValueError, match="characters\\[0\\].skeleton: character option rest"):
        scene_from_dict(scene)


def test_invert_shape_and_from_estimate_read_the_rest_pose_alike(files, tmp_path):
    """Both commands take the same options; the character they build has the same features."""
    from typer.testing import CliRunner

    from shape_inversion import cli
    from workflows.character import load_character

    for rest in ("frame0", "offsets"):
        out = tmp_path / f"shape_{rest}.json"
        res = CliRunner().invoke(cli.app, [str(files["cmu_bvh"]), "--out", str(out), "--rest", rest,
                                           "--units", "cmu", "--bank-samples", "2000"])
        assert res.exit_code == 0, res.output
        shape = json.loads(out.read_text())
        assert shape["character"]["options"]["rest"] == rest
        char = load_character(files["cmu_bvh"], CharacterOptions(rest=rest, units="cmu"))
        np.testing.assert_allclose(shape["diagnostics"]["query_features_m"], char.character.features, atol=1e-9)


def test_one_preset_registry_for_data_build_and_invert_shape(files):
    """``data build`` retargets a Mixamo BVH (prefixed names, per-joint position channels) with the same preset."""
    from shape_inversion.rigs import available_presets
    from smplik.data.retarget import preset_names, retarget_bvh

    assert available_presets() == preset_names()
    assert {"cmu", "mixamo", "unity", "unreal", "makehuman"} <= set(preset_names())
    clip = retarget_bvh(files["mixamo_bvh"], preset="mixamo", rest="offsets")
    assert clip.num_frames == 2
    knee = JOINT_NAMES.index("right_knee") - 1
    assert np.linalg.norm(clip.body_pose[0, knee]) < 0.02  # the file's rest is SMPL's rest (within 1 deg)
    assert np.degrees(np.linalg.norm(clip.body_pose[1, knee])) == pytest.approx(40.0, abs=0.5)


def test_rig_without_preset_maps_by_name_and_topology(files, tmp_path):
    from shape_inversion.rigs import RigError, detect_rig
    from smplik.conventions import PARENTS

    char = read_character(files["rokoko_bvh"])
    assert char.rig.name == "auto" and char.smpl_joints["right_knee"] == char.skeleton.names.index("RightShin")
    assert "right_hip=RightThigh" in char.rig.description
    parts = {"hip": "Hip", "knee": "Knee", "ankle": "Ankle", "foot": "Toe", "collar": "Clavicle",
             "shoulder": "UpperArm", "elbow": "Elbow", "wrist": "Wrist", "hand": "HandTip"}
    middle = {"pelvis": "Pelvis", "spine1": "Spine", "spine2": "Spine1", "spine3": "Chest", "neck": "Neck",
              "head": "Head"}
    styles = {"L_Knee": lambda s, p: f"{s.upper()}_{p}", "Knee_l": lambda s, p: f"{p}_{s}",
              "Knee.L": lambda s, p: f"{p}.{s.upper()}",
              "LeftKnee": lambda s, p: f"{'Left' if s == 'l' else 'Right'}{p}"}
    for style, fmt in styles.items():
        names = []
        for n in JOINT_NAMES:
            side, _, part = n.partition("_")
            names.append(fmt(side[0], parts[part]) if side in ("left", "right") else middle[n])
        rig = detect_rig(names, PARENTS)
        mapped = dict(rig.joints)
        for n in ("left_knee", "right_elbow", "left_collar", "right_shoulder", "spine3", "right_foot"):
            assert mapped[n] == names[JOINT_NAMES.index(n)], (style, n, mapped)
    swapped = list(names)
    swapped[JOINT_NAMES.index("right_knee")], swapped[JOINT_NAMES.index("right_ankle")] = \
        swapped[JOINT_NAMES.index("right_ankle")], swapped[JOINT_NAMES.index("right_knee")]
    with pytest.raises(RigError, match="not an ancestor"):
        detect_rig(swapped, PARENTS)


def test_shared_cmu_and_makehuman_map_by_name_without_a_preset(shared_data):
    """The CMU skeleton renamed to another scheme (no preset fits) maps to the same joints as the cmu preset."""
    from shape_inversion.rigs import detect_rig, load_preset
    from shape_inversion.skeleton_io import read_bvh

    sk = read_bvh(shared_data.cmu("01_01.bvh"))
    cmu = dict(load_preset("cmu").joints)
    auto = dict(detect_rig([n.replace("Left", "L_").replace("Right", "R_") for n in sk.names], sk.parents).joints)
    for smpl in ("left_hip", "right_knee", "left_ankle", "right_shoulder", "left_elbow", "right_wrist", "head"):
        assert auto[smpl] == cmu[smpl].replace("Left", "L_").replace("Right", "R_"), smpl
    mh = shared_data.root / "data" / "custom-characters" / "mh_default_tpose.bvh" if shared_data.root else None
    if mh is not None and mh.is_file():
        skm = read_bvh(mh)
        assert skm.bvh.position_mode == "add"  # MakeHuman's zero position channels beside full OFFSETs
        char = read_character(mh)
        assert char.rig.name == "makehuman" and 1.3 < char.head_ankle_height_m < 1.6
