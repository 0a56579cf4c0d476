"""HumanML3D joints ``(T, 22, 3)`` and 263-d features -> ``scene animate`` -> exported BVH and GLB, on SMPL and on a
``--character``, every frame kept (issue 42, item 4): the files a text-to-motion user takes to Blender."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from animation_fixtures import humanml3d_features, walking_joints


def _glb_frames(path: Path) -> dict[str, int]:
    """Keyframes per animation of a GLB (name -> count of the first sampler's input times)."""
    import pygltflib

    g = pygltflib.GLTF2.load_binary(str(path))
    return {a.name: g.accessors[a.samplers[0].input].count for a in g.animations}


def _bvh_root_path(path: Path) -> np.ndarray:
    from smplik.data.bvh import read_bvh

    m = read_bvh(path)
    return m.positions[:, 0]


@pytest.mark.parametrize("kind", ["joints", "features"])
def test_humanml3d_to_bvh_and_glb_on_smpl_keeps_every_frame(animate_shipped, tmp_path, kind):
    from smplik.data.bvh import read_bvh

    T = 33
    P = walking_joints(T)[:, :22]
    data = P.astype(np.float32) if kind == "joints" else humanml3d_features(P).astype(np.float32)
    np.save(tmp_path / "motion.npy", data)
    res = animate_shipped(tmp_path / "motion.npy", "--out", tmp_path / "out", "--export", "bvh,glb")
    assert res.exit_code == 0, res.output
    bvh = read_bvh(tmp_path / "out" / "person_0.bvh")
    assert bvh.num_frames == T and bvh.fps == pytest.approx(20.0)  # HumanML3D's rate
    assert bvh.joint_names[:2] == ("pelvis", "left_hip")  # SMPL's skeleton
    assert _glb_frames(tmp_path / "out" / "person_0.glb") == {"pose": T}
    # the BVH's root walks the way the joints walk (+z, 0.05 m a frame in walking_joints)
    root = _bvh_root_path(tmp_path / "out" / "person_0.bvh")
    travel = np.ptp(root, axis=0)
    assert travel[2] == pytest.approx(travel.max()) and travel[2] > 0


@pytest.mark.parametrize("kind", ["joints", "features"])
def test_humanml3d_to_bvh_and_glb_on_a_character_keeps_every_frame(animate_shipped, tmp_path, kind):
    from smplik.data.bvh import read_bvh
    from workflows.animation.clips import rest_joints
    from workflows.layout_examples import write_mixamo_bvh

    T = 27
    P = walking_joints(T)[:, :22]
    data = P.astype(np.float32) if kind == "joints" else humanml3d_features(P).astype(np.float32)
    np.save(tmp_path / "motion.npy", data)
    write_mixamo_bvh(tmp_path / "hero.bvh", rest_joints(np.zeros(10), "neutral") * 1.15)
    res = animate_shipped(tmp_path / "motion.npy", "--out", tmp_path / "out", "--character", tmp_path / "hero.bvh",
                  "--export", "bvh,glb")
    assert res.exit_code == 0, res.output
    bvh = read_bvh(tmp_path / "out" / "person_0.bvh")
    assert bvh.num_frames == T and bvh.joint_names[0].startswith("mixamorig:")  # the character's own skeleton
    assert _glb_frames(tmp_path / "out" / "person_0.glb") == {"pose": T}
