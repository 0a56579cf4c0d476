"""``scene export``: posed BVH/GLB per character read back to the solved joint positions (demo scene, after an
edit + ``scene solve``, a GLB character with its own mesh)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from shape_inversion.gltf_io import load_gltf
from smplik.data.bvh import read_bvh
from workflows.character import CharacterOptions, character_from_estimate, smpl_to_custom
from workflows.examples_gen import example_poses
from workflows.layout_examples import smpl_rest, write_mixamo_gltf
from workflows.scene import Scene, SceneCharacter, SkeletonSource, character_joints, load_scene
from workflows.scene.export import export_scene

MM = 1e-3


@pytest.fixture(scope="module")
def demo(tmp_path_factory, best_solver):
    from workflows.demo import run_demo

    return run_demo(tmp_path_factory.mktemp("demo"), best_solver, previews=False)


def _glb_joint_positions(path, names):
    doc = load_gltf(path)
    index = {n.name: i for i, n in enumerate(doc.gltf.nodes)}
    return np.stack([doc.world[index[n], :3, 3] for n in names])


def test_smpl_scene_exports_bvh_and_skinned_glb(demo, tmp_path):
    import trimesh

    scene = load_scene(demo.smpl.scene)
    files = export_scene(scene, tmp_path, formats=("bvh", "glb"))
    assert sorted(p.suffix for p in files) == [".bvh", ".bvh", ".glb", ".glb"]
    from smplik.conventions import JOINT_NAMES

    for c in scene.characters:
        joints = character_joints(c)
        bvh = read_bvh(tmp_path / f"{c.name}.bvh")
        assert sorted(bvh.joint_names) == sorted(JOINT_NAMES)  # written depth-first
        order = [bvh.index(n) for n in JOINT_NAMES]
        assert np.abs(bvh.positions[0, order] - joints).max() < MM
        glb = tmp_path / f"{c.name}.glb"
        assert np.abs(_glb_joint_positions(glb, JOINT_NAMES) - joints).max() < MM
        loaded = trimesh.load(glb, force="scene")
        assert sum(len(g.faces) for g in loaded.geometry.values()) == len(smpl_rest()[2])
        import pygltflib

        g = pygltflib.GLTF2.load_binary(str(glb))
        assert len(g.animations) == 1 and len(g.skins[0].joints) == 24


def test_character_scene_after_edit_and_solve_exports_the_solved_pose(demo, tmp_path):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    edited = demo.edited_scene  # the demo's edit, re-solved with scene solve's solve_scene
    res = CliRunner().invoke(scene_app, ["export", str(edited), "--out", str(tmp_path), "--format", "bvh,glb"])
    assert res.exit_code == 0, res.output
    scene = load_scene(edited)
    first = scene.characters[0]
    assert first.skeleton is not None and first.skeleton.rig == "mixamo"
    skeleton_file = edited.parent / first.skeleton.path  # scene.json stores it relative to itself
    char = character_from_estimate(skeleton_file, first.skeleton.options, first.betas, first.scale, first.gender)
    custom = smpl_to_custom(dataclasses.replace(first.pose, betas=first.betas), char)
    _, p_file = custom.positions(char)
    bvh = read_bvh(tmp_path / f"{first.name}.bvh")
    source = read_bvh(skeleton_file)
    assert bvh.joint_names == source.joint_names and bvh.channels == source.channels  # layout kept
    assert np.abs(bvh.positions[0] - char.file_to_canon_points(p_file)).max() < MM  # the scene's world, metres
    # the edit moved the right wrist: the exported character's wrist follows the solved SMPL wrist
    wrist = char.names.index(char.rig.smpl_to_rig["right_wrist"])
    solved = character_joints(first)[21]
    assert np.linalg.norm(bvh.positions[0, wrist] - solved) < 0.05
    # a BVH character has no mesh: its GLB is its SMPL-SI body (24-joint skin), said in one line
    body = pygltflib.GLTF2.load_binary(str(tmp_path / f"{first.name}.glb"))
    assert len(body.skins) == 1 and len(body.skins[0].joints) == 24 and body.meshes
    assert f"{first.name}: {Path(first.skeleton.path).name} has no mesh; its GLB is the SMPL body" in res.output


@pytest.fixture(scope="module")
def glb_scene(tmp_path_factory):
    J, V, F, W = smpl_rest()
    folder = tmp_path_factory.mktemp("glbchar")
    path = write_mixamo_gltf(folder / "hero.glb", J, (V, F, W))
    pose = example_poses()[0].pose
    from shape_inversion.estimator import ShapeEstimator
    from shape_inversion.skeleton_io import read_character
    from smplik.body_model import load_body_model

    est = ShapeEstimator.build(load_body_model("neutral")).estimate(read_character(path).features)
    c = SceneCharacter("hero", est.gender, est.betas, est.scale, SkeletonSource.from_options(str(path),
                       CharacterOptions()), (), dataclasses.replace(pose, betas=est.betas))
    return Scene((c,)), path


def test_glb_character_exports_its_own_posed_mesh(glb_scene, tmp_path):
    import trimesh

    scene, src = glb_scene
    files = export_scene(scene, tmp_path)
    assert {p.name for p in files} == {"hero.bvh", "hero.glb"}
    c = scene.characters[0]
    char = character_from_estimate(src, CharacterOptions(), c.betas, c.scale, c.gender)
    custom = smpl_to_custom(c.pose, char)
    _, p_file = custom.positions(char)
    got = _glb_joint_positions(tmp_path / "hero.glb", char.names)
    assert np.abs(got - char.file_to_canon_points(p_file)).max() < MM  # the scene's world frame
    mesh = trimesh.load(tmp_path / "hero.glb", force="scene")
    assert sum(len(g.faces) for g in mesh.geometry.values()) == len(smpl_rest()[2])
    bvh = read_bvh(tmp_path / "hero.bvh")  # the BVH lines up with the GLB: the scene's world frame
    assert np.abs(bvh.positions[0, [bvh.index(n) for n in char.names]] - got).max() < MM


def test_export_refuses_unknown_formats_and_missing_files(glb_scene, tmp_path):
    from workflows.scene.export import ExportError

    scene, _ = glb_scene
    with pytest.raises(ExportError, match="Unknown export format"):
        export_scene(scene, tmp_path, formats=("fbx",))
    c = scene.characters[0]
    gone = dataclasses.replace(c, skeleton=dataclasses.replace(c.skeleton, path=str(tmp_path / "nope.glb")))
    with pytest.raises(ExportError, match="not found"):
        export_scene(Scene((gone,)), tmp_path)


def test_glb_character_is_drawn_with_its_own_posed_mesh(glb_scene):
    """The fixture's mesh is SMPL's rest mesh: posed by its skin weights it lies on the posed SMPL body."""
    from workflows.character_mesh import scene_character_own_mesh
    from workflows.scene.previews import character_mesh, scene_items

    scene, _ = glb_scene
    c = scene.characters[0]
    own = scene_character_own_mesh(c)
    smpl = character_mesh(c)
    assert own is not None and own.vertices.shape == smpl.vertices.shape
    assert np.linalg.norm(own.vertices - smpl.vertices, axis=1).mean() < 0.03  # LBS without pose correctives
    meshes, _, _ = scene_items(scene)
    assert np.allclose(meshes[0].vertices, own.vertices)


def test_several_frames_export_as_one_animation(glb_scene, demo, tmp_path):
    import pygltflib

    scene, _ = glb_scene
    c = scene.characters[0]
    second = dataclasses.replace(c.pose, transl=np.asarray(c.pose.transl) + [0.0, 0.1, 0.0])
    files = export_scene(scene, tmp_path, poses={"hero": [c.pose, second]})
    g = pygltflib.GLTF2.load_binary(str(tmp_path / "hero.glb"))
    assert len(g.animations) == 1 and g.accessors[g.animations[0].samplers[0].input].count == 2
    bvh = read_bvh(tmp_path / "hero.bvh")
    assert bvh.num_frames == 2 and len(files) == 2
    lift = bvh.positions[1] - bvh.positions[0]
    char = character_from_estimate(c.skeleton.path, c.skeleton.options, c.betas, c.scale, c.gender)
    np.testing.assert_allclose(lift @ char.C_canon_file.T * char.units_m, np.tile([0, 0.1 * c.scale, 0], (24, 1)),
                               atol=1e-4)
    smpl = load_scene(demo.smpl.scene).characters[0]
    export_scene(Scene((smpl,)), tmp_path / "smpl", formats=("bvh",), poses={smpl.name: [smpl.pose, smpl.pose]})
    assert read_bvh(tmp_path / "smpl" / f"{smpl.name}.bvh").num_frames == 2


def test_scene_export_cli_error_is_one_line(demo, tmp_path):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    res = CliRunner().invoke(scene_app, ["export", str(demo.smpl.scene), "--out", str(tmp_path), "--format", "fbx"])
    assert res.exit_code == 1 and "Unknown export format" in res.output
    assert len(res.output.strip().splitlines()) == 1


def _turned_copy(src, dst):
    """The same GLB character with its root node turned half around the vertical (it faces the other way)."""
    import pygltflib
    from scipy.spatial.transform import Rotation

    g = pygltflib.GLTF2.load_binary(str(src))
    root = g.scenes[g.scene or 0].nodes[0]
    node = g.nodes[root]
    q = Rotation.from_euler("y", 180, degrees=True) * Rotation.from_quat(node.rotation or [0, 0, 0, 1])
    node.rotation = [float(x) for x in q.as_quat()]
    node.translation = [float(x) + d for x, d in zip(node.translation or [0, 0, 0], (0.7, 0.0, -0.3), strict=True)]
    g.save_binary(str(dst))
    return dst


def test_characters_of_a_scene_export_in_one_world_frame(glb_scene, tmp_path):
    """Two files of one character, one turned around and moved in its own file: exported, they line up."""
    scene, src = glb_scene
    c = scene.characters[0]
    turned = _turned_copy(src, tmp_path / "turned.glb")
    other = dataclasses.replace(c, name="turned", skeleton=dataclasses.replace(c.skeleton, path=str(turned)))
    export_scene(Scene((c, other)), tmp_path / "out", formats=("glb",))
    char = character_from_estimate(src, CharacterOptions(), c.betas, c.scale, c.gender)
    names = [n for n in char.names if n.endswith(("Hips", "Hand", "Foot", "Head"))]
    a = _glb_joint_positions(tmp_path / "out" / "hero.glb", names)
    b = _glb_joint_positions(tmp_path / "out" / "turned.glb", names)
    assert np.abs(a - b).max() < MM
    np.testing.assert_allclose(a, character_joints_world(c, char, names), atol=MM)


def character_joints_world(c, char, names):
    custom = smpl_to_custom(c.pose, char)
    _, p_file = custom.positions(char)
    return char.file_to_canon_points(p_file[[char.names.index(n) for n in names]])


def test_export_keeps_the_source_clips_and_adds_the_pose(glb_scene, tmp_path):
    import pygltflib

    scene, _ = glb_scene
    export_scene(scene, tmp_path / "first", formats=("glb",))  # a GLB with one clip, "pose"
    animated = tmp_path / "animated.glb"
    animated.write_bytes((tmp_path / "first" / "hero.glb").read_bytes())
    source_clip = pygltflib.GLTF2.load_binary(str(animated)).animations[0]
    c = scene.characters[0]
    again = dataclasses.replace(c, skeleton=dataclasses.replace(c.skeleton, path=str(animated)))
    export_scene(Scene((again,)), tmp_path / "second", formats=("glb", "bvh"))
    g = pygltflib.GLTF2.load_binary(str(tmp_path / "second" / "hero.glb"))
    assert [a.name for a in g.animations] == ["pose", "pose_1"]  # the source's clip kept, the pose added
    assert len(g.animations[0].channels) == len(source_clip.channels)
    times = g.accessors[g.animations[0].samplers[0].input]
    assert times.count == 1


def test_bvh_export_keeps_the_source_frames_after_the_pose(tmp_path):
    from workflows.examples_gen import write_mixamo_character

    src = write_mixamo_character(tmp_path / "hero.bvh")
    source = read_bvh(src)
    char = character_from_estimate(src, CharacterOptions(), np.zeros(10), 1.0, "neutral")
    c = SceneCharacter("hero", char.gender, np.zeros(10), 1.0, SkeletonSource.from_options(str(src),
                       CharacterOptions()), (), dataclasses.replace(example_poses()[1].pose, betas=np.zeros(10)))
    export_scene(Scene((c,)), tmp_path / "out", formats=("bvh",), bvh_frame="source")
    bvh = read_bvh(tmp_path / "out" / "hero.bvh")
    assert bvh.num_frames == 1 + source.num_frames
    np.testing.assert_allclose(bvh.values[1:], source.values, atol=1e-5)  # the source's own frames, unchanged
    _, p_file = smpl_to_custom(c.pose, char).positions(char)
    assert np.abs(bvh.positions[0] - p_file).max() < MM / char.units_m
    export_scene(Scene((c,)), tmp_path / "world", formats=("bvh",))  # the default: the scene's world frame
    world = read_bvh(tmp_path / "world" / "hero.bvh")
    assert world.num_frames == 1 + source.num_frames and world.channels == source.channels
    np.testing.assert_allclose(world.positions[0], char.file_to_canon_points(p_file), atol=MM)
    np.testing.assert_allclose(world.positions[1:], char.file_to_canon_points(source.positions), atol=MM)


def _turned_bvh(src, dst, R, units):
    """The BVH character ``src`` rewritten in other axes (``R``: its axes -> the new file's) and units (metres per
    unit): the same body, facing another way in its file. Written with smplik's BVH writer (``format_bvh``)."""
    from smplik.data.bvh import format_bvh
    from smplik.rotations import matrix_to_euler_deg_np

    m = read_bvh(src)
    k = 0.01 / units  # the source is in centimetres
    G = R @ m.global_rotations @ R.T
    local = np.stack([G[:, j] if p < 0 else np.swapaxes(G[:, p], -1, -2) @ G[:, j] for j, p in enumerate(m.parents)],
                     axis=1)
    rows = []
    for j, chans in enumerate(m.channels):
        order = "".join(c[0] for c in chans if c.endswith("rotation"))
        angles = dict(zip(order, np.moveaxis(matrix_to_euler_deg_np(local[:, j], order), -1, 0), strict=True))
        for c in chans:
            rows.append(k * (m.local_translations[:, j] @ R.T)[:, "XYZ".index(c[0])] if c.endswith("position")
                        else angles[c[0]])
    ends = {p: k * R @ o for p, o in zip(m.end_site_parents, m.end_site_offsets, strict=True)}
    dst.write_text(format_bvh(m.joint_names, m.parents, k * m.offsets @ R.T, m.channels, np.stack(rows, axis=1),
                              m.frame_time, ends))
    return dst


def test_bvh_characters_of_a_scene_export_in_one_world_frame(tmp_path):
    """Two BVH files of one character, the second turned half around, z-up and in metres: exported, their roots
    (and every joint) line up in the scene's world frame, floor and facing as the GLBs are."""
    from scipy.spatial.transform import Rotation

    from workflows.examples_gen import write_mixamo_character

    src = write_mixamo_character(tmp_path / "hero.bvh")  # centimetres, y-up, facing +z
    R = (Rotation.from_euler("x", 90, degrees=True) * Rotation.from_euler("y", 180, degrees=True)).as_matrix()
    turned = _turned_bvh(src, tmp_path / "turned.bvh", R, units=1.0)  # metres, z-up, facing -y
    a_char = character_from_estimate(src, CharacterOptions(), np.zeros(10), 1.0, "neutral")
    b_char = character_from_estimate(turned, CharacterOptions(), np.zeros(10), 1.0, "neutral")
    assert (a_char.units_m, b_char.units_m) == (0.01, 1.0) and b_char.skeleton.bvh is not None
    pose = dataclasses.replace(example_poses()[1].pose, betas=np.zeros(10))
    cs = [SceneCharacter(name, a_char.gender, np.zeros(10), 1.0, SkeletonSource.from_options(str(path),
          CharacterOptions()), (), pose) for name, path in (("hero", src), ("turned", turned))]
    export_scene(Scene(tuple(cs)), tmp_path / "out", formats=("bvh",))
    a, b = read_bvh(tmp_path / "out" / "hero.bvh"), read_bvh(tmp_path / "out" / "turned.bvh")
    assert a.joint_names == b.joint_names
    np.testing.assert_allclose(b.positions[0], a.positions[0], atol=MM)  # roots and every joint line up
    np.testing.assert_allclose(b.global_rotations[0], a.global_rotations[0], atol=1e-5)  # same facing
    _, p_file = smpl_to_custom(pose, a_char).positions(a_char)
    np.testing.assert_allclose(a.positions[0], a_char.file_to_canon_points(p_file), atol=MM)  # the scene's world
    assert a.positions[0, :, 1].min() == pytest.approx(a_char.file_to_canon_points(p_file)[:, 1].min(), abs=MM)
    # in their own files' frames the two would not line up (the old export)
    export_scene(Scene(tuple(cs)), tmp_path / "own", formats=("bvh",), bvh_frame="source")
    a0, b0 = read_bvh(tmp_path / "own" / "hero.bvh"), read_bvh(tmp_path / "own" / "turned.bvh")
    assert np.abs(a0.positions[0] * 0.01 - b0.positions[0]).max() > 0.5
