"""One rig reader for every command (issue #42): every rig ``invert-shape`` reads also goes through
``scene from-estimate --character`` and, for motion files, ``data build`` and ``data preview``, with no option
and no traceback.

The rigs: every human of the committed real-rig corpus (``tests/data/rigs/manifest.json``), a meshopt-compressed
glTF-Transform file (``tests/data/meshopt``), the shared MakeHuman BVH when ``../shared`` is there, and two
producers' layouts written from committed real rigs (``tests/rig_layouts.py``): a Sketchfab download of a rig
with IK helper bones and numeric name tags (``GLTF_created_0_rootJoint``, ``hips_IK_110``, ``leg_upper.L_105``)
and a UE4 mannequin with its ``ik_foot_root`` / ``ik_hand_root`` hierarchies listed first in the skin.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))

RIGS = TESTS / "data" / "rigs"
MANIFEST = json.loads((RIGS / "manifest.json").read_text())
SHARED = Path(os.environ.get("SMPLIK_SHARED_DIR", TESTS.parent.parent / "shared"))
SHARED_BVH = SHARED / "data" / "custom-characters" / "mh_default_tpose.bvh"

CASES = {e["id"]: RIGS / e["file"] for e in MANIFEST["rigs"]}
CASES["meshopt_gltf_transform"] = TESTS / "data" / "meshopt" / "RiggedFigure_gltf_transform.glb"
CASES["shared_makehuman_bvh"] = SHARED_BVH
CASES["sketchfab_ik_helpers"] = "sketchfab"
CASES["ue4_mannequin_ik_roots"] = "ue4"


@pytest.fixture(scope="module")
def estimate(tmp_path_factory) -> Path:
    from estimator_fixtures import framing, people, write_romp

    folder = tmp_path_factory.mktemp("estimate")
    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    return write_romp(folder, aa, transl, betas).path


def _rig(case: str, tmp_path: Path) -> Path:
    from rig_layouts import write_sketchfab_ik_rig, write_ue4_mannequin

    source = CASES[case]
    if source == "sketchfab":
        return write_sketchfab_ik_rig(tmp_path / "sketchfab_ik.glb")
    if source == "ue4":
        return write_ue4_mannequin(tmp_path / "SK_Mannequin.glb")
    if not Path(source).is_file():
        pytest.skip(f"{source} is not here (the shared data folder ../shared or $SMPLIK_SHARED_DIR)")
    return Path(source)


def _ok(res) -> None:
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert res.exit_code == 0, res.output[-2000:]


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_rig_goes_through_every_command(case, tmp_path, estimate):
    from typer.testing import CliRunner

    from smplik.cli.main import app
    from smplik.data.bvh import read_bvh

    rig = _rig(case, tmp_path)
    runner = CliRunner()
    res = runner.invoke(app, ["invert-shape", str(rig), "--out", str(tmp_path / "shape.json")])
    _ok(res)
    shape = json.loads((tmp_path / "shape.json").read_text())
    assert 0.5 < shape["scale"] < 1.6 and np.all(np.abs(shape["betas"]) <= 5.0)  # a human of its own size
    mapped = shape["character"]["joint_map"]
    assert {"pelvis", "head", "left_wrist", "right_ankle"} <= set(mapped)

    res = runner.invoke(app, ["scene", "from-estimate", str(estimate), "--out", str(tmp_path / "scene"),
                              "--character", str(rig), "--no-previews", "--max-effectors", "2"])
    _ok(res)
    scene = json.loads((tmp_path / "scene" / "scene.json").read_text())
    assert len(scene["characters"]) == 1
    posed = read_bvh(tmp_path / "scene" / "person_0.bvh")  # the pose on the rig's own skeleton
    assert set(mapped.values()) <= set(posed.joint_names)
    assert np.isfinite(posed.positions).all()

    if rig.suffix.lower() == ".bvh":  # a motion file: training data and its preview
        from helpers import can_render

        from smplik.data.dataset import load_cache

        res = runner.invoke(app, ["data", "build", "--bvh", str(rig), "--out", str(tmp_path / "data.npz"),
                                  "--fps", "10"])
        _ok(res)
        cache = load_cache(tmp_path / "data.npz")
        assert len(cache) >= 1 and np.isfinite(cache.pose.numpy()).all()
        if can_render():
            res = runner.invoke(app, ["data", "preview", str(rig), "--out", str(tmp_path / "strip.png"),
                                      "--frames", "2", "--panel", "100"])
            _ok(res)
            assert (tmp_path / "strip.png").stat().st_size > 1000


def test_a_ue4_mannequin_with_ik_roots_exports_its_own_mesh(tmp_path, estimate):
    """The UE4 layout's body ``JOINTS_0`` indices lie past the IK joints listed first in the skin: the exported
    GLB is the mannequin's own skinned mesh, every vertex bound to a body joint."""
    import pygltflib
    from typer.testing import CliRunner

    from smplik.cli.main import app

    rig = _rig("ue4_mannequin_ik_roots", tmp_path)
    runner = CliRunner()
    _ok(runner.invoke(app, ["scene", "from-estimate", str(estimate), "--out", str(tmp_path / "scene"), "--character",
                            str(rig), "--no-previews", "--max-effectors", "2"]))
    _ok(runner.invoke(app, ["scene", "export", str(tmp_path / "scene" / "scene.json"), "--out", str(tmp_path / "x")]))
    glb = pygltflib.GLTF2.load_binary(tmp_path / "x" / "person_0.glb")
    names = {n.name for n in glb.nodes}
    assert {"pelvis", "thigh_l", "ik_foot_root", "vanguard_Mesh"} <= names  # its own node tree and mesh
