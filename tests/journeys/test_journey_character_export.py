"""Journey: an estimator's file on a custom character, as the README's "Custom characters" and "Pose estimator
-> editable scene" sections run it, on the files ``smplik demo`` generates for trying this:

``smplik scene from-estimate RESULTS --character hero.bvh --out hero_scene`` -> ``smplik scene solve
hero_scene/scene.json`` -> ``smplik scene export hero_scene/scene.json --out exported --format bvh,glb`` -> the
BVH and the GLB read back (smplik's BVH reader, pygltflib, trimesh), each body where the scene put it.

A BVH character has no mesh: ``--format bvh,glb`` once wrote the BVH alone and said nothing.
"""

from __future__ import annotations

import re

import numpy as np
import pytest


def gltf_channel(gltf, node: int, path: str) -> np.ndarray:
    """The keyframe values (K, 3 or 4) a GLB's first animation gives ``node``'s ``path`` (translation...)."""
    animation = gltf.animations[0]
    for channel in animation.channels:
        if channel.target.node == node and channel.target.path == path:
            accessor = gltf.accessors[animation.samplers[channel.sampler].output]
            view = gltf.bufferViews[accessor.bufferView]
            width = {"VEC3": 3, "VEC4": 4}[accessor.type]
            return np.frombuffer(gltf.binary_blob(), np.float32, accessor.count * width,
                                 view.byteOffset + (accessor.byteOffset or 0)).reshape(-1, width)
    raise AssertionError(f"no {path} animation of node {node}")


@pytest.fixture(scope="module")
def exported(demo, smplik):
    """The README's custom-character chain on the demo's generated inputs."""
    examples = demo.out / "examples"
    cwd = demo.cwd
    made = smplik("scene", "from-estimate", examples / "romp_two_people.npz", "--character",
                  examples / "mixamo_character.bvh", "--out", "hero_scene", "--no-previews", cwd=cwd)
    solved = smplik("scene", "solve", "hero_scene/scene.json", cwd=cwd)
    export = smplik("scene", "export", "hero_scene/scene.json", "--out", "exported", "--format", "bvh,glb", cwd=cwd)
    return cwd, made, solved, export


def test_every_step_prints_its_lines_and_no_blank_one(exported):
    _, *runs = exported
    for run in runs:
        lines = run.output.splitlines()
        assert lines and lines[0].strip(), f"a blank first line:\n{run.describe()}"
        assert "Traceback" not in run.output


def test_the_exported_bvh_is_the_characters_skeleton_posed_where_the_scene_puts_it(demo, exported):
    from smplik.conventions import JOINT_NAMES
    from smplik.data.bvh import read_bvh
    from workflows.scene import character_joints, load_scene

    cwd, *_ = exported
    source = read_bvh(demo.out / "examples" / "mixamo_character.bvh")
    scene = load_scene(cwd / "hero_scene" / "scene.json")
    assert len(scene.characters) == 2
    for character in scene.characters:
        bvh = read_bvh(cwd / "exported" / f"{character.name}.bvh")
        assert bvh.joint_names == source.joint_names  # its own skeleton, every joint
        assert bvh.num_frames == 1 + source.num_frames  # the solved pose, then the source's own frames
        rig = character.skeleton.joint_map
        posed = np.array([bvh.positions[0, bvh.index(rig[name])] for name in JOINT_NAMES])  # metres, world
        distance = np.linalg.norm(posed - character_joints(character), axis=1)
        assert distance.max() < 0.04, dict(zip(JOINT_NAMES, np.round(distance * 1000), strict=True))


def test_the_exported_glb_is_a_skinned_animated_body_placed_like_the_scene(exported):
    import pygltflib
    import trimesh

    from workflows.scene import character_joints, load_scene

    cwd, _, _, export = exported
    scene = load_scene(cwd / "hero_scene" / "scene.json")
    written = re.findall(r"wrote (\S+\.glb)", export.output)
    assert len(written) == len(scene.characters), export.output
    for character in scene.characters:
        note = rf"{character.name}: mixamo_character\.bvh has no mesh; its GLB is the SMPL body"
        assert re.search(note, export.output), export.output
        path = cwd / "exported" / f"{character.name}.glb"
        gltf = pygltflib.GLTF2().load(str(path))
        assert len(gltf.skins) == 1 and len(gltf.skins[0].joints) == 24 and len(gltf.animations) == 1
        pelvis = gltf.skins[0].joints[0]
        np.testing.assert_allclose(gltf_channel(gltf, pelvis, "translation")[0], character_joints(character)[0],
                                   atol=0.02)
        mesh = trimesh.load(path, force="mesh")  # trimesh reads the bind pose
        height = mesh.bounds[1, 1] - mesh.bounds[0, 1]
        assert 1.4 * character.scale < height < 2.1 * character.scale and len(mesh.faces) > 1000
