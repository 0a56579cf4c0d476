"""FBX characters and animations (:mod:`smplik.data.fbx`, ufbx) through every command that takes a character or a BVH.

The files are real (``tests/data/fbx``, see its README): a Maya HumanIK skeleton saved as ASCII and as binary
FBX 7.4 (centimetres, a 5 s take, no bind pose) and a Kenney game character saved by Maya as binary FBX 7.7
(skinned, IK control bones, about 3 m tall in its own units). The files are written by Autodesk's FBX SDK
(``Creator: "FBX SDK/FBX Plugins version 2020.x"``), the producer of nearly every FBX in circulation.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ufbx", reason="the FBX reader needs ufbx (pip install -e '.[fbx]')")

FBX = Path(__file__).resolve().parent / "data" / "fbx"
HUMAN_IK_ASCII = FBX / "maya_human_ik_7400_ascii.fbx"
HUMAN_IK_BINARY = FBX / "maya_human_ik_7400_binary.fbx"
KENNEY = FBX / "maya_kenney_character_7700_binary.fbx"


def test_ascii_and_binary_fbx_give_the_same_skeleton_and_take_in_metres_y_up():
    from smplik.data.fbx import read_fbx_info

    a, info_a = read_fbx_info(HUMAN_IK_ASCII)
    b, info_b = read_fbx_info(HUMAN_IK_BINARY)
    assert info_a.ascii and not info_b.ascii and info_a.version == 7400
    assert info_a.unit_m == pytest.approx(0.01) and info_a.up == "y" and info_a.take == "Take 001"
    assert a.joint_names == b.joint_names and a.parents == b.parents
    assert a.num_frames == b.num_frames == 120 and a.fps == pytest.approx(24.0)  # 5 s at 24 fps
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-6)
    hips, head = a.joint_names.index("Character1_Hips"), a.joint_names.index("Character1_Head")
    _, rest = a.rest_pose()
    assert 1.2 < rest[head, 1] - rest[:, 1].min() < 2.0  # a human in metres, y up (the file is in cm)
    assert rest[head, 1] > rest[hips, 1]


def test_motion_from_world_reproduces_every_joint_position_and_rests_on_the_bind_pose():
    """The BVH an FBX becomes: its FK gives back the file's joint positions, its OFFSET pose is the rest."""
    from scipy.spatial.transform import Rotation

    from smplik.data.fbx import motion_from_world

    rng = np.random.default_rng(0)
    parents = (-1, 0, 1, 1, 3)
    J, T = len(parents), 7
    local = np.broadcast_to(np.eye(4), (T + 1, J, 4, 4)).copy()
    local[..., :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.6, (T + 1, J, 3)).reshape(-1, 3)).as_matrix().reshape(
        T + 1, J, 3, 3) * 0.01  # a uniform 0.01 scale, as a centimetre file's root adds
    local[..., :3, 3] = rng.normal(0, 20, (J, 3))
    local[1:, 4, :3, 3] += rng.normal(0, 5, (T, 3))  # an animated translation on a non-root joint
    world = np.empty_like(local)
    for j, p in enumerate(parents):
        world[:, j] = local[:, j] if p < 0 else world[:, p] @ local[:, j]
    motion = motion_from_world("x.fbx", [f"j{k}" for k in range(J)], parents, world[0], world[1:], 1 / 30)
    np.testing.assert_allclose(motion.positions, world[1:, :, :3, 3], atol=1e-7)
    _, rest = motion.rest_pose()
    np.testing.assert_allclose(rest, world[0, :, :3, 3], atol=1e-12)
    assert motion.channels[4][:3] == ("Xposition", "Yposition", "Zposition") and len(motion.channels[2]) == 3


def test_an_fbx_character_reads_with_no_options_like_a_bvh():
    from shape_inversion.skeleton_io import read_character

    char = read_character(HUMAN_IK_ASCII)
    assert char.skeleton.format == "fbx" and char.units_m == 1.0 and char.units_source == "file" and char.up == "y"
    m = char.joint_map
    assert m["pelvis"] == "Character1_Hips" and m["left_knee"] == "Character1_LeftLeg"
    assert m["right_elbow"] == "Character1_RightForeArm" and m["head"] == "Character1_Head" and len(m) >= 22
    assert 1.5 < char.head_ankle_height_m / 0.84 < 2.1
    assert "FBX 7400 ASCII" in char.skeleton.rest and "no bind pose" in char.skeleton.rest


def test_a_skinned_game_character_with_ik_controls_is_read_at_its_own_size(capsys):
    """The Kenney character's bind pose comes from its skin clusters; its controls take no SMPL role; at about
    3 m it is read at its own size (scale has no bank range), said in one warning."""
    from shape_inversion.skeleton_io import _neutral_estimator, read_character

    char = read_character(KENNEY)
    m = char.joint_map
    assert m["pelvis"] == "Hips" and m["left_ankle"] == "LeftFoot" and m["right_wrist"] == "RightHand"
    assert not any("Ctrl" in n or "Roll" in n or n.endswith("IK") for n in m.values())
    assert "bind pose (skin clusters" in char.skeleton.rest
    stature = char.head_ankle_height_m / 0.84
    assert stature > 2.6
    with pytest.warns(UserWarning, match="read at its own size"):
        est = _neutral_estimator().estimate(char.features, char.mapped_rest())
    assert est.scale > 2.0  # beyond the bank's 0.2-2
    assert est.max_feature_residual_m < 0.1 * stature


@pytest.mark.parametrize("factor", [0.1, 12.0])
def test_a_figurine_or_a_giant_gets_the_shape_of_the_same_character_at_human_size(factor):
    from shape_inversion.skeleton_io import _neutral_estimator, read_character

    char = read_character(HUMAN_IK_ASCII)
    est = _neutral_estimator()
    human = est.estimate(char.features, char.mapped_rest())
    rest = char.mapped_rest()
    with pytest.warns(UserWarning, match="read at its own size"):
        scaled = est.estimate(char.features * factor, dataclasses.replace(rest, positions=rest.positions * factor))
    assert scaled.scale == pytest.approx(human.scale * factor, rel=0.03)
    np.testing.assert_allclose(scaled.betas, human.betas, atol=0.3)


def test_a_posed_fbx_character_lands_near_its_smpl_pose():
    from shape_inversion.skeleton_io import _neutral_estimator, read_character
    from workflows.character import build_character, retarget_error_m
    from workflows.examples_gen import example_poses

    char = read_character(HUMAN_IK_BINARY)
    estimator = _neutral_estimator()
    cc = build_character(char.skeleton, estimator.estimate(char.features, char.mapped_rest()), rig=char.rig)
    stature = char.head_ankle_height_m / 0.84
    for person in example_poses():
        pose = dataclasses.replace(person.pose, betas=cc.betas, gender=cc.gender)
        assert 100 * retarget_error_m(pose, cc).mean() / stature <= 3.0


def test_invert_shape_scene_and_export_take_an_fbx_character(tmp_path):
    import sys

    from typer.testing import CliRunner

    sys.path.insert(0, str(Path(__file__).parent))
    from estimator_fixtures import framing, people, write_romp

    from smplik.cli.main import app
    from smplik.data.bvh import read_bvh

    runner = CliRunner()
    res = runner.invoke(app, ["invert-shape", str(HUMAN_IK_ASCII), "--out", str(tmp_path / "shape.json")])
    assert res.exit_code == 0, res.output
    shape = json.loads((tmp_path / "shape.json").read_text())
    assert shape["character"]["joint_map"]["pelvis"] == "Character1_Hips"
    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    w = write_romp(tmp_path, aa, transl, betas)
    res = runner.invoke(app, ["scene", "from-estimate", str(w.path), "--out", str(tmp_path / "scene"), "--character",
                              str(HUMAN_IK_ASCII), "--no-previews", "--max-effectors", "2"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["scene", "export", str(tmp_path / "scene" / "scene.json"), "--out",
                              str(tmp_path / "exp")])
    assert res.exit_code == 0, res.output
    assert "maya_human_ik_7400_ascii.fbx has no skinned mesh; its GLB is the SMPL body" in res.output
    bvh = read_bvh(tmp_path / "exp" / "person_0.bvh")  # the FBX character's own skeleton, re-read as BVH
    assert "Character1_LeftUpLeg" in bvh.joint_names and bvh.num_frames >= 1


def test_data_build_turns_a_folder_of_fbx_clips_into_training_data(tmp_path):
    import typer
    from typer.testing import CliRunner

    from shape_inversion.auto_preset import auto_preset
    from shape_inversion.data_build_cli import build
    from smplik.data.dataset import load_cache
    from smplik.data.retarget import bone_direction_errors, read_motion, retarget_bvh

    clip = retarget_bvh(read_motion(HUMAN_IK_ASCII), preset="auto", fps=24, rig_mapper=auto_preset)
    errors = bone_direction_errors(clip, frames=slice(0, None, 10))
    assert errors.mean() < 1.0, errors.group_means()
    folder = tmp_path / "clips"
    folder.mkdir()
    (folder / "a.fbx").symlink_to(HUMAN_IK_ASCII)
    (folder / "b.fbx").symlink_to(HUMAN_IK_BINARY)
    app = typer.Typer()
    app.command()(build)
    out = tmp_path / "fbx.npz"
    result = CliRunner().invoke(app, ["--bvh", str(folder), "--out", str(out), "--fps", "12"])
    assert result.exit_code == 0, result.output
    cache = load_cache(out)
    assert cache.clip_names == ("a.fbx", "b.fbx") and abs(len(cache) - 2 * 60) <= 4  # 120 frames at 24 -> 12 fps
    assert np.isfinite(cache.pose.numpy()).all() and float(cache.pose.abs().max()) > 0.1


def test_a_bvh_without_toe_joints_builds_with_the_preset_it_nearly_fits(tmp_path):
    """A Perception-Neuron-like Mixamo-named BVH without toes: ``data build`` once refused it (``preset 'mixamo'
    names source joints the file does not have: left_foot -> mixamorig:LeftToeBase``)."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.retarget import read_motion, retarget_bvh
    from workflows.examples_gen import write_mixamo_character

    text = write_mixamo_character(tmp_path / "m.bvh").read_text()
    head, motion_part = text.split("MOTION")
    out, depth, skipping = [], 0, False
    for line in head.splitlines():  # drop the toe joints (and their End Sites) from the hierarchy
        if "ToeBase" in line:
            skipping, depth = True, 0
        if skipping:
            depth += line.count("{") - line.count("}")
            if depth == 0 and "}" in line:
                skipping = False
            continue
        out.append(line)
    hierarchy = "\n".join(out)
    channels = sum(int(n) for n in __import__("re").findall(r"CHANNELS\s+(\d+)", hierarchy))
    frames = [ln for ln in motion_part.splitlines() if ln.strip()][:2]  # "Frames: 1", "Frame Time: ..."
    (tmp_path / "notoes.bvh").write_text(hierarchy + "\nMOTION\n" + "\n".join(frames) + "\n"
                                         + " ".join(["0"] * channels) + "\n")
    motion = read_motion(tmp_path / "notoes.bvh")
    assert not any("Toe" in n for n in motion.joint_names)
    clip = retarget_bvh(motion, preset="auto", rig_mapper=auto_preset)
    assert clip.num_frames == motion.num_frames and np.isfinite(clip.body_pose).all()


def test_a_file_that_is_not_fbx_is_refused_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    bad = tmp_path / "broken.fbx"
    bad.write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + b"\xff" * 64)
    res = CliRunner().invoke(app, ["invert-shape", str(bad), "--out", str(tmp_path / "s.json")])
    assert res.exit_code == 1
    assert "Traceback" not in res.output and "broken.fbx" in res.output
    assert res.output.strip().splitlines()[-1].startswith("error:")
    assert not (tmp_path / "s.json").exists()


def _rigify_control_bvh(path: Path) -> Path:
    """A Blender Rigify control rig exported as BVH (Blender's ``export_anim_bvh``: every bone, ``DEF-`` deform
    bones beside ``MCH-`` mechanism bones), the deform bones on the example Mixamo body, three frames."""
    from smplik.conventions import JOINT_NAMES, PARENTS
    from smplik.data.bvh import format_bvh
    from workflows.examples_gen import MIXAMO_NAMES, mixamo_rest_joints

    J = mixamo_rest_joints() * 100.0
    names = ["DEF-" + MIXAMO_NAMES[n] for n in JOINT_NAMES]
    parents, pos = list(PARENTS), [J[j] for j in range(24)]
    for j in range(24):  # a mechanism bone on every deform bone: the End Sites hang on them
        names.append(f"MCH-{MIXAMO_NAMES[JOINT_NAMES[j]]}_ik")
        parents.append(j)
        pos.append(J[j] + np.array([0.0, 0.0, 5.0]))
    offsets = np.array([pos[k] if parents[k] < 0 else pos[k] - pos[parents[k]] for k in range(len(names))])
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation") if p < 0
                else ("Zrotation", "Yrotation", "Xrotation") for p in parents]
    values = np.zeros((3, sum(len(c) for c in channels)))
    values[1:, 3:] = np.random.default_rng(1).normal(0, 15, (2, values.shape[1] - 3))
    path.write_text(format_bvh(names, parents, offsets, channels, values, 1 / 30))
    return path


def test_a_rigify_control_rig_goes_through_from_estimate_and_exports_its_deform_bones(tmp_path):
    """Regression: ``scene from-estimate --character`` on a Rigify control rig ended in ``IndexError: index 128 is
    out of bounds for axis 0 with size 35`` (the deform-bone skeleton kept the whole rig's BVH motion, whose End
    Sites index the whole rig)."""
    import sys

    from typer.testing import CliRunner

    sys.path.insert(0, str(Path(__file__).parent))
    from estimator_fixtures import framing, people, write_romp

    from smplik.cli.main import app
    from smplik.data.bvh import read_bvh

    rig = _rigify_control_bvh(tmp_path / "rigify.bvh")
    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    w = write_romp(tmp_path, aa, transl, betas)
    runner = CliRunner()
    res = runner.invoke(app, ["scene", "from-estimate", str(w.path), "--out", str(tmp_path / "scene"), "--character",
                              str(rig), "--no-previews", "--max-effectors", "2"])
    assert res.exit_code == 0 and "Traceback" not in res.output, res.output
    res = runner.invoke(app, ["scene", "export", str(tmp_path / "scene" / "scene.json"), "--out", str(tmp_path / "x")])
    assert res.exit_code == 0, res.output
    out = read_bvh(tmp_path / "x" / "person_0.bvh")
    assert len(out.joint_names) == 24 and all(n.startswith("DEF-") for n in out.joint_names)
    assert out.num_frames == 1 + 3  # the pose, then the rig's own three frames
    src = read_bvh(rig)
    idx = [src.joint_names.index(n) for n in out.joint_names]
    rel = lambda p: p - p[:, :1]  # noqa: E731 - the source frames keep every deform joint where the rig had it
    np.testing.assert_allclose(rel(out.positions[1:]), rel(src.positions[:, idx]) / 100.0 * 1.0, atol=0.02)


def test_a_glb_skin_read_in_part_poses_its_mesh_with_the_joints_it_kept():
    """Regression: ``scene from-estimate --character`` on a UE4 mannequin re-exported by Blender ended in
    ``IndexError: index 221 is out of bounds for axis 0 with size 93``: the skin's joint indices (``JOINTS_0``,
    221 joints with the ``ik_*`` hierarchies) were remapped through an array of the 93 joints kept."""
    from shape_inversion.skeleton_io import read_skeleton, subset_skeleton
    from workflows.character_mesh import pose_mesh, skinned_mesh

    sk = read_skeleton(Path(__file__).parent / "data" / "rigs" / "threejs_Soldier.glb")
    leaves = {j for j in range(len(sk.names)) if j not in set(sk.parents)}
    keep = [j for j in range(len(sk.names)) if j not in leaves]  # parents first, a whole hierarchy
    sub = subset_skeleton(sk, keep)
    full_mesh, mesh = skinned_mesh(sk.gltf), skinned_mesh(sub.gltf)
    assert mesh is not None and mesh.joints.max() < len(keep)
    for k, j in enumerate(keep):  # a vertex of a kept joint keeps it; one of a dropped leaf takes its parent
        assert np.all(mesh.joints[full_mesh.joints == j] == k)
    for j in leaves:
        on = full_mesh.joints == j
        assert np.all(mesh.joints[on] == keep.index(sk.parents[j]))
    R = np.broadcast_to(np.eye(3), (len(keep), 3, 3))
    posed = pose_mesh(mesh, sub.gltf, R, sub.gltf.T_world_joint_bind[:, :3, 3])
    np.testing.assert_allclose(posed, mesh.vertices_world, atol=1e-9)  # the bind pose gives the bind mesh


def _with_required_extension(src: Path, out: Path, name: str, fallback_buffer: bool) -> Path:
    """``src`` (a GLB) re-saved as glTF-Transform / gltfpack write a compressed file: the extension in
    ``extensionsUsed`` and ``extensionsRequired`` and, for meshopt, a fallback buffer without a uri
    (``{"byteLength": n, "extensions": {"EXT_meshopt_compression": {"fallback": true}}}``, glTF-Transform's
    ``EXTMeshoptCompression`` writer)."""
    import pygltflib

    doc = pygltflib.GLTF2.load_binary(src)
    doc.extensionsUsed = sorted(set(doc.extensionsUsed or []) | {name})
    doc.extensionsRequired = sorted(set(doc.extensionsRequired or []) | {name})
    if fallback_buffer:
        doc.buffers.append(pygltflib.Buffer(byteLength=1024, extensions={name: {"fallback": True}}))
    doc.save_binary(str(out))
    return out


@pytest.mark.parametrize("ext", ["EXT_unknown_future", "KHR_texture_procedurals"])  # meshopt: test_meshopt.py
def test_a_gltf_requiring_an_extension_it_cannot_decode_is_refused_in_one_line_naming_it(tmp_path, ext):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    src = Path(__file__).parent / "data" / "rigs" / "RiggedFigure.glb"
    f = _with_required_extension(src, tmp_path / "packed.glb", ext, fallback_buffer="meshopt" in ext)
    res = CliRunner().invoke(app, ["invert-shape", str(f), "--out", str(tmp_path / "s.json")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    line = res.output.strip().splitlines()[-1]
    assert line.startswith("error:") and ext in line and "has no uri" not in line


def test_a_gltf_requiring_ktx_textures_or_quantization_still_reads(tmp_path):
    from shape_inversion.skeleton_io import read_character

    src = Path(__file__).parent / "data" / "rigs" / "RiggedFigure.glb"
    plain = read_character(src)
    for ext in ("KHR_texture_basisu", "KHR_mesh_quantization"):
        f = _with_required_extension(src, tmp_path / f"{ext}.glb", ext, fallback_buffer=False)
        char = read_character(f)
        assert char.joint_map == plain.joint_map
        np.testing.assert_allclose(char.positions, plain.positions)


def test_an_fbx_animation_pack_becomes_one_clip_per_animated_take(tmp_path, monkeypatch):
    """A Unity / Blender export of several actions in one FBX (``Armature|Idle``, ``Armature|Walk``): each animated
    take is a clip (``pack.fbx#Armature|Walk``); a Mixamo file's empty ``Take 001`` is no clip."""
    import smplik.data.fbx as fbx
    from shape_inversion.auto_preset import auto_preset
    from smplik.data.dataset import find_sources, read_source
    from smplik.data.fbx import FbxTake, read_fbx, read_fbx_takes

    assert [t.name for t in read_fbx_takes(HUMAN_IK_ASCII)] == ["Take 001"]
    folder = tmp_path / "clips"
    folder.mkdir()
    (folder / "pack.fbx").symlink_to(HUMAN_IK_ASCII)
    (folder / "single.fbx").symlink_to(HUMAN_IK_BINARY)
    pack = [FbxTake("Take 001", 0.0, 5.0, 242), FbxTake("empty", 0.0, 1.0, 0), FbxTake("Armature|Walk", 0.0, 2.0, 9)]
    real = fbx.read_fbx_takes
    monkeypatch.setattr(fbx, "read_fbx_takes", lambda p: pack if Path(p).name == "pack.fbx" else real(p))
    sources = find_sources(folder, "bvh")
    assert [(s.name, s.take) for s in sources] == [("pack.fbx#Take 001", "Take 001"),
                                                  ("pack.fbx#Armature|Walk", "Armature|Walk"), ("single.fbx", None)]
    seq = read_source(sources[0], rig_mapper=auto_preset)  # the named take is read
    assert seq.num_frames == read_fbx(HUMAN_IK_ASCII, take="Take 001").num_frames
    with pytest.raises(ValueError, match=re.escape("no take 'Armature|Walk'; takes: 'Take 001'")):
        read_source(sources[1], rig_mapper=auto_preset)  # (one take: the error names the take and the file's takes)


def test_scene_animate_takes_an_fbx_character_and_writes_its_own_skeleton(tmp_path, monkeypatch, best_solver):
    """``scene animate --character`` reads the FBX with the same reader as ``invert-shape`` (one rig reader)."""
    import sys

    from typer.testing import CliRunner

    sys.path.insert(0, str(Path(__file__).parent))
    from animation_fixtures import video_motion
    from estimator_fixtures import write_aist

    from smplik.data.bvh import read_bvh
    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    aa, tr = video_motion(8, seed=6, fmt="gvhmr")
    aist = write_aist(tmp_path, aa, tr)
    res = CliRunner().invoke(scene_app, ["animate", str(aist), "--out", str(tmp_path / "a"), "--character",
                                         str(HUMAN_IK_BINARY), "--max-effectors", "2"])
    assert res.exit_code == 0, res.output
    bvh = read_bvh(tmp_path / "a" / "person_0.bvh")
    assert bvh.num_frames == 8 and "Character1_Hips" in bvh.joint_names
    stature = float(np.ptp(bvh.positions[0][:, 1]))
    assert 1.2 < stature < 2.2  # the scene's world frame: metres


def test_a_truncated_fbx_and_a_missing_reader_are_one_line_each(tmp_path, monkeypatch):
    import smplik.data.fbx as fbx
    from smplik.data.fbx import FbxError, read_fbx

    cut = tmp_path / "cut.fbx"
    cut.write_bytes(KENNEY.read_bytes()[:300_000])  # a download cut short
    with pytest.raises(FbxError, match=r"cut\.fbx: not a readable FBX file") as err:
        read_fbx(cut)
    assert "\n" not in str(err.value)
    shadow = tmp_path / "shadow"  # an environment without ufbx: an import of it fails in the child process
    shadow.mkdir()
    (shadow / "ufbx.py").write_text("raise ImportError('no ufbx here')\n")
    env = fbx._worker_env()
    monkeypatch.setattr(fbx, "_worker_env", lambda: {**env, "PYTHONPATH": f"{shadow}{os.pathsep}{env['PYTHONPATH']}"})
    with pytest.raises(FbxError, match=r"pip install 'smplik\[fbx\]'"):
        read_fbx(HUMAN_IK_ASCII)


def test_sketchfab_names_with_ik_helpers_and_numeric_tags_match_by_name():
    """Sketchfab's converter tags every name (``leg_upper.L_6``), adds ``GLTF_created_0_rootJoint`` above the
    skeleton, and rigs carry IK helpers named like the joints (``hips_IK_28`` beside ``hips_2``): the name matcher
    (the rig mapper's fallback) reads the reversed compounds and ranks a helper after the joint of its name."""
    from shape_inversion.rig_names import match_humanoid
    from shape_inversion.skeleton_io import read_skeleton

    sk = read_skeleton(Path(__file__).parent / "data" / "rigs" / "VRMC_materials_mtoon_UV_Animation_Test.vrm")
    words = {"upper_leg": "leg_upper", "lower_leg": "leg_lower", "upper_arm": "arm_upper", "lower_arm": "arm_lower"}
    renamed = []
    for k, n in enumerate(sk.names):
        base, dot, side = n.rpartition(".")
        renamed.append(f"{words.get(base, base)}.{side}_{k}" if dot else f"{n}_{k}")
    names = ["GLTF_created_0_rootJoint", *renamed]
    parents = [-1, *(p + 1 if p >= 0 else 0 for p in sk.parents)]
    hips = names.index(next(n for n in names if n.startswith("hips_")))
    names.append(f"hips_IK_{len(names)}")  # an IK control of the hips, a leaf on the root
    parents.append(0)
    found = {s: names[j] for s, j in match_humanoid(names, parents).items()}
    expected = {s: renamed[sk.names.index(n)] for s, n in sk.humanoid.items()}
    assert found["pelvis"] == names[hips] and found["left_hip"] == expected["left_hip"]
    for s in ("left_knee", "right_hip", "left_elbow", "right_shoulder", "head", "left_ankle"):
        assert found[s] == expected[s], s


def test_data_preview_draws_an_fbx_clip(tmp_path):
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from helpers import can_render

    if not can_render():
        pytest.skip("no offscreen rendering (EGL/OSMesa) here")
    from typer.testing import CliRunner

    from smplik.cli.main import app

    out = tmp_path / "strip.png"
    res = CliRunner().invoke(app, ["data", "preview", str(HUMAN_IK_BINARY), "--out", str(out), "--frames", "3",
                                   "--panel", "120"])
    assert res.exit_code == 0, res.output
    assert out.is_file() and "of 120" in res.output and "rest pose offsets" in res.output


def test_a_skinned_fbx_character_exports_its_own_mesh_posed_with_its_take_kept(tmp_path, monkeypatch):
    """``scene export`` of the Kenney FBX: the GLB is the file's own skinned mesh (not the SMPL body), its joints
    named as in the file, posed like the exported BVH (the same joints at the same world positions), with the
    file's take as a clip beside ``pose``; a vertex bound to one joint keeps its distance to it."""
    import sys

    import pygltflib
    from scipy.spatial.transform import Rotation
    from typer.testing import CliRunner

    sys.path.insert(0, str(Path(__file__).parent))
    from estimator_fixtures import framing, people, write_romp

    from smplik.cli.main import app
    from smplik.data.bvh import read_bvh

    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    w = write_romp(tmp_path, aa, transl, betas)
    runner = CliRunner()
    res = runner.invoke(app, ["scene", "from-estimate", str(w.path), "--out", str(tmp_path / "s"), "--character",
                              str(KENNEY), "--no-previews", "--max-effectors", "2"])
    assert res.exit_code == 0, res.output
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")  # the scene's relative skeleton path resolves against the scene file
    res = runner.invoke(app, ["scene", "export", str(tmp_path / "s" / "scene.json"), "--out", str(tmp_path / "x")])
    assert res.exit_code == 0, res.output
    assert "SMPL body" not in res.output  # no note: the GLB is the character's own mesh
    g = pygltflib.GLTF2.load(str(tmp_path / "x" / "person_0.glb"))
    assert [a.name for a in g.animations] == ["maya_kenney_character_7700_binary take", "pose"]
    bvh = read_bvh(tmp_path / "x" / "person_0.bvh")

    def acc(i):
        a, v = g.accessors[i], g.bufferViews[g.accessors[i].bufferView]
        n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
        dt = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}[a.componentType]
        raw = g.binary_blob()[(v.byteOffset or 0) + (a.byteOffset or 0):]
        return np.frombuffer(raw, dtype=dt, count=a.count * n).reshape(a.count, n).astype(np.float64)

    skin = g.skins[0]
    J = len(skin.joints)
    local = np.broadcast_to(np.eye(4), (len(g.nodes), 4, 4)).copy()
    for k, node in enumerate(g.nodes):
        if node.rotation is not None:
            local[k, :3, :3] = Rotation.from_quat(node.rotation).as_matrix()
        if node.translation is not None:
            local[k, :3, 3] = node.translation
    parent = {c: k for k, node in enumerate(g.nodes) for c in (node.children or [])}
    world = local.copy()
    for k in range(len(g.nodes)):  # the joint nodes are written parents first
        if k in parent:
            world[k] = world[parent[k]] @ local[k]
    names = [g.nodes[j].name for j in skin.joints]
    glb_joints = world[skin.joints, :3, 3]
    assert sorted(names) == sorted(bvh.joint_names)
    order = [bvh.joint_names.index(n) for n in names]
    np.testing.assert_allclose(glb_joints, bvh.positions[0][order], atol=1e-3)  # posed like the BVH, frame 0
    ibm = acc(skin.inverseBindMatrices).reshape(J, 4, 4).transpose(0, 2, 1)
    prim = g.meshes[0].primitives[0]
    V, Jv, Wv = acc(prim.attributes.POSITION), acc(prim.attributes.JOINTS_0).astype(int), acc(prim.attributes.WEIGHTS_0)
    assert len(V) == 804
    rigid = Wv[:, 0] > 0.999
    k = Jv[rigid, 0]
    M = world[np.asarray(skin.joints)[k]] @ ibm[k]
    posed = np.einsum("vab,vb->va", M[:, :3, :3], V[rigid]) + M[:, :3, 3]
    bind_joint = -ibm[k][:, :3, 3]  # bind rotations are identity: the IBM is a translation
    np.testing.assert_allclose(np.linalg.norm(posed - glb_joints[k], axis=1),
                               np.linalg.norm(V[rigid] - bind_joint, axis=1), atol=1e-4)
    assert np.abs(posed - V[rigid]).max() > 0.05  # and the mesh did move with the pose
