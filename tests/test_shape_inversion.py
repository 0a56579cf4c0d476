"""SMPL-SI: features, bank, estimator, skeleton readers, rig maps and the CLI."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from shape_inversion.bank import BankConfig, bank_cache_path, load_or_build_bank, sample_bank
from shape_inversion.estimator import EstimatorConfig, ShapeEstimator, ShapeInversionError
from shape_inversion.features import FEATURE_PAIRS, REQUIRED_JOINTS, joints_to_features, named_joints_to_features
from shape_inversion.rigs import RigError, available_presets, detect_rig, load_preset
from shape_inversion.skeleton_io import SkeletonError, prepare_character, read_bvh, read_gltf, read_joint_json
from smplik.body_model import BodyModel
from smplik.conventions import JOINT_INDEX, JOINT_NAMES, NUM_BETAS, Gender

SMALL = BankConfig(num_samples=4000, seed=3)


def _fake_model(gender: Gender = Gender.NEUTRAL, bump: float = 0.0) -> BodyModel:
    """A tiny linear 'body model' with SMPL-like T-pose joints; only rest_joints/fingerprint are used."""
    J = np.zeros((24, 3))
    J[JOINT_INDEX["pelvis"]] = [0, 0.94, 0]
    for side, sx in (("left", 1), ("right", -1)):
        J[JOINT_INDEX[f"{side}_hip"]] = [sx * 0.07, 0.85, 0]
        J[JOINT_INDEX[f"{side}_knee"]] = [sx * 0.10, 0.49, 0]
        J[JOINT_INDEX[f"{side}_ankle"]] = [sx * 0.09, 0.09 + bump, 0]
        J[JOINT_INDEX[f"{side}_foot"]] = [sx * 0.11, 0.03, 0.08]
        J[JOINT_INDEX[f"{side}_collar"]] = [sx * 0.08, 1.35, 0]
        J[JOINT_INDEX[f"{side}_shoulder"]] = [sx * 0.16, 1.38, 0]
        J[JOINT_INDEX[f"{side}_elbow"]] = [sx * 0.41, 1.36, 0]
        J[JOINT_INDEX[f"{side}_wrist"]] = [sx * 0.65, 1.37, 0]
        J[JOINT_INDEX[f"{side}_hand"]] = [sx * 0.74, 1.36, 0]
    for name, y in (("spine1", 1.04), ("spine2", 1.18), ("spine3", 1.24), ("neck", 1.44), ("head", 1.52)):
        J[JOINT_INDEX[name]] = [0, y, 0]
    rng = np.random.default_rng(7)
    dirs = rng.normal(scale=0.006, size=(24, 3, NUM_BETAS))
    dirs[..., 0] += J[..., None][..., 0] * 0.04  # component 0 ~ stature
    arrays = {"v_template": J.copy(), "shapedirs": dirs, "J_regressor": np.eye(24)}
    model = BodyModel(gender, "fake", torch.tensor(J, dtype=torch.float32), torch.tensor(dirs, dtype=torch.float32),
                      arrays)
    return model


@pytest.fixture(scope="module")
def fake_estimator(tmp_path_factory) -> ShapeEstimator:
    return ShapeEstimator.build(_fake_model(), SMALL, cache_root=tmp_path_factory.mktemp("cache"))


# ----------------------------------------------------------------------------- features and bank


def test_features_on_known_skeleton():
    J = torch.zeros(24, 3)
    J[JOINT_INDEX["right_hip"]] = torch.tensor([0.0, 1.0, 0.0])
    J[JOINT_INDEX["right_knee"]] = torch.tensor([0.0, 0.6, 0.0])
    J[JOINT_INDEX["right_ankle"]] = torch.tensor([0.0, 0.2, 0.0])
    J[JOINT_INDEX["head"]] = torch.tensor([0.0, 1.7, 0.0])
    J[JOINT_INDEX["right_shoulder"]] = torch.tensor([-0.2, 1.4, 0.0])
    J[JOINT_INDEX["right_elbow"]] = torch.tensor([-0.5, 1.4, 0.0])
    J[JOINT_INDEX["right_wrist"]] = torch.tensor([-0.5, 1.4, 0.4])
    f = joints_to_features(J)
    expected = [0.4, 0.4, 1.5, np.linalg.norm([0.5, 0.3, 0.4]), 0.3, 0.4]
    np.testing.assert_allclose(f.numpy(), expected, atol=1e-6)
    named = {n: J[JOINT_INDEX[n]].numpy() for n in REQUIRED_JOINTS}
    np.testing.assert_allclose(named_joints_to_features(named), expected, atol=1e-6)
    assert len(FEATURE_PAIRS) == 6
    with pytest.raises(KeyError, match="right_wrist"):
        named_joints_to_features({k: v for k, v in named.items() if k != "right_wrist"})


def test_bank_is_deterministic_and_in_range():
    model = _fake_model()
    a, b = sample_bank(model, SMALL), sample_bank(model, SMALL)
    np.testing.assert_array_equal(a.features, b.features)
    assert a.betas.shape == (SMALL.num_samples, NUM_BETAS) and a.features.shape == (SMALL.num_samples, 6)
    assert np.abs(a.betas).max() <= 5 and 0.2 <= a.scales.min() and a.scales.max() <= 2
    c = sample_bank(model, BankConfig(num_samples=SMALL.num_samples, seed=4))
    assert not np.array_equal(a.betas, c.betas)


def test_bank_cache_keys(tmp_path):
    model = _fake_model()
    other = _fake_model(bump=0.01)
    assert model.fingerprint != other.fingerprint
    paths = {bank_cache_path(model.fingerprint, Gender.NEUTRAL, SMALL, tmp_path),
             bank_cache_path(other.fingerprint, Gender.NEUTRAL, SMALL, tmp_path),
             bank_cache_path(model.fingerprint, Gender.FEMALE, SMALL, tmp_path),
             bank_cache_path(model.fingerprint, Gender.NEUTRAL, BankConfig(4000, seed=9), tmp_path)}
    assert len(paths) == 4
    first = load_or_build_bank(model, SMALL, root=tmp_path)
    path = bank_cache_path(model.fingerprint, Gender.NEUTRAL, SMALL, tmp_path)
    assert path.is_file()
    again = load_or_build_bank(model, SMALL, root=tmp_path)
    np.testing.assert_array_equal(first.features, again.features)
    other_bank = load_or_build_bank(other, SMALL, root=tmp_path)
    assert not np.array_equal(first.features, other_bank.features)
    assert len(list((tmp_path / "shape_inversion").glob("*.npz"))) == 2


# ----------------------------------------------------------------------------- estimator


def test_recovers_in_range_body(fake_estimator):
    model = _fake_model()
    rng = np.random.default_rng(11)
    refined = ShapeEstimator(fake_estimator.bank, fake_estimator.tree, fake_estimator.pair_template,
                             fake_estimator.pair_dirs, EstimatorConfig(refine=True))
    for _ in range(5):
        betas = rng.uniform(-2, 2, NUM_BETAS)
        scale = float(rng.uniform(0.8, 1.3))
        f = joints_to_features(model.rest_joints(torch.tensor(betas)) * scale).numpy()
        plain = fake_estimator.estimate(f)
        assert plain.max_feature_residual_m < 0.05  # the paper's estimate: within ~h
        assert abs(plain.scale - scale) < 0.25
        est = refined.estimate(f)
        assert est.max_feature_residual_m < 0.003  # refined: a few mm at most
        assert est.gender is Gender.NEUTRAL and est.betas.shape == (NUM_BETAS,)
        assert est.effective_samples >= 1 and est.neighbours_used >= 1
        np.testing.assert_allclose(est.kernel_betas, plain.betas)
        payload = est.to_dict()
        assert len(payload["betas"]) == NUM_BETAS and "effective_samples" in payload["diagnostics"]


def test_stylised_proportions_fit_the_nearest_human_with_a_warning(fake_estimator):
    """Legs 0.3 x the rest body's (a stylised character): outside the human range but within the stylised band,
    so the estimate is the nearest human body and says so; the same legs at 0.05 x are refused."""
    f = joints_to_features(_fake_model().rest_joints(torch.zeros(NUM_BETAS))).numpy().astype(float)

    def short_legs(k: float) -> np.ndarray:
        g = f.copy()
        g[2] -= (1 - k) * (g[0] + g[1])  # head-ankle shrinks by what the legs lose
        g[:2] *= k
        return g

    cfg = fake_estimator.config
    with pytest.warns(UserWarning, match="stylised proportions"):
        est = fake_estimator.estimate(short_legs(0.3))
    assert cfg.max_nearest_distance < est.nearest_distance_m <= cfg.max_stylised_distance
    assert any(w.startswith("stylised proportions") for w in est.warnings)
    assert np.all(np.isfinite(est.betas)) and est.scale > 0
    with pytest.raises(ShapeInversionError, match="^Not a human: .*limit 300 mm"):
        fake_estimator.estimate(short_legs(0.05))


def test_inhuman_proportion_refused_at_any_size(fake_estimator):
    """Shins a fifth of the rest body's on a small skeleton (0.6 x): the feature distance to the bank shrinks with
    the size and stays under the limit, but the proportion is more than 2x outside the human range: refused,
    naming the bone; the same skeleton with 0.8 x shins is accepted."""
    f = 0.6 * joints_to_features(_fake_model().rest_joints(torch.zeros(NUM_BETAS))).numpy().astype(float)
    robot = f.copy()
    robot[1] *= 0.2  # right_knee-right_ankle
    nearest = float(fake_estimator.tree.query(robot[None], k=1)[0][0, 0])
    assert nearest < fake_estimator.config.max_stylised_distance  # the distance alone would accept it
    with pytest.raises(ShapeInversionError,
                       match="^Not a human: .*more than 2x outside the human range, at any size.*right_knee-right_"):
        fake_estimator.estimate(robot)
    human = f.copy()
    human[1] *= 0.8
    assert fake_estimator.estimate(human).scale > 0


def test_out_of_range_raises(fake_estimator):
    with pytest.raises(ShapeInversionError, match="^Not a human: .*outside the human range.*right_elbow-right_wrist"):
        fake_estimator.estimate(np.array([0.4, 0.4, 1.5, 0.9, 0.25, 0.9]))
    with pytest.raises(ShapeInversionError, match="human proportions but its units look wrong.*Try --units"):
        fake_estimator.estimate(np.array([40.0, 40, 150, 70, 25, 25]))  # a human in centimetres read as metres
    with pytest.raises(ShapeInversionError, match="^Not a human: .*check the units"):  # both: proportions first
        fake_estimator.estimate(np.array([40.0, 40, 150, 90, 25, 90]))
    with pytest.raises(ShapeInversionError, match="Degenerate"):
        fake_estimator.estimate(np.array([0.0, 0.4, 1.5, 0.7, 0.25, 0.25]))


# ----------------------------------------------------------------------------- skeleton inputs

_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT RightUpLeg
  {
    OFFSET -9 -5 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT RightLeg
    {
      OFFSET 0 -40 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT RightFoot
      {
        OFFSET 0 -40 0
        CHANNELS 3 Zrotation Yrotation Xrotation
        End Site
        {
          OFFSET 0 -5 10
        }
      }
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 9 -5 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT LeftLeg
    {
      OFFSET 0 -40 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT LeftFoot
      {
        OFFSET 0 -40 0
        CHANNELS 3 Zrotation Yrotation Xrotation
      }
    }
  }
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT Head
    {
      OFFSET 0 50 0
      CHANNELS 3 Zrotation Yrotation Xrotation
    }
    JOINT RightArm
    {
      OFFSET -18 33 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT RightForeArm
      {
        OFFSET -25 0 0
        CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT RightHand
        {
          OFFSET -24 0 0
          CHANNELS 3 Zrotation Yrotation Xrotation
        }
      }
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.0083333
""" + " ".join(["5", "90"] + ["0"] * 28 + ["-90"] + ["0"] * 8) + "\n"


def test_bvh_string_rest_sources_and_units():
    offsets = read_bvh(_BVH, rest="offsets")
    frame0 = read_bvh(_BVH, rest="frame0")
    names = list(offsets.names)
    assert names[:3] == ["Hips", "RightUpLeg", "RightLeg"] and len(names) == 12
    hand = names.index("RightHand")
    np.testing.assert_allclose(offsets.positions[hand], [-67, 43, 0], atol=1e-9)
    # frame 0 rotates RightArm by -90 deg about z: the arm points up
    np.testing.assert_allclose(frame0.positions[hand] - frame0.positions[names.index("RightArm")], [0, 49, 0],
                               atol=1e-6)
    char = prepare_character(offsets, units="cm")
    assert char.rig.name in ("cmu", "mixamo") and char.units_m == 0.01 and char.up == "y"
    np.testing.assert_allclose(char.features[:2], [0.40, 0.40], atol=1e-9)
    auto = prepare_character(offsets, rig="mixamo")  # decimal units detected from stature
    assert auto.units_m == 0.01 and auto.units_source == "detected"
    with pytest.raises(SkeletonError, match="missing MOTION"):
        read_bvh(_BVH.split("MOTION")[0], rest="frame0")


def test_json_units_up_and_errors(tmp_path):
    J = _fake_model().J_template.double().numpy()
    joints_zup = {n: [float(J[i, 0]) * 100, float(-J[i, 2]) * 100, float(J[i, 1]) * 100]
                  for i, n in enumerate(JOINT_NAMES)}
    path = tmp_path / "char.json"
    path.write_text(json.dumps({"units": "cm", "up": "z", "joints": joints_zup}))
    char = prepare_character(read_joint_json(path))
    assert char.rig.name == "smpl" and char.units_m == 0.01 and char.up == "z"
    np.testing.assert_allclose(char.joint("head")[1] - char.joint("right_ankle")[1], J[15, 1] - J[8, 1], atol=1e-9)
    np.testing.assert_allclose(char.features, joints_to_features(torch.tensor(J)).numpy(), atol=1e-9)
    # no units/up in the file: both detected
    path.write_text(json.dumps({"joints": joints_zup}))
    char2 = prepare_character(read_joint_json(path))
    assert char2.units_m == 0.01 and char2.up == "z" and char2.units_source == "detected"
    char3 = prepare_character(read_joint_json(path), units=0.01, up="z")
    np.testing.assert_allclose(char3.features, char.features)
    # missing joint: error names the SMPL joint and the map
    del joints_zup["right_elbow"]
    path.write_text(json.dumps({"joints": joints_zup}))
    with pytest.raises(RigError, match="right_elbow.*(smpl|preset)|smpl.*right_elbow"):
        prepare_character(read_joint_json(path), rig="smpl")
    with pytest.raises(RigError, match="right_elbow"):
        prepare_character(read_joint_json(path))


def test_unknown_rig_lists_presets():
    with pytest.raises(RigError) as info:
        load_preset("blender-rigify")
    for name in ("cmu", "makehuman", "mixamo", "unity", "unreal"):
        assert name in str(info.value)
    assert {"cmu", "makehuman", "mixamo", "unity", "unreal", "smpl"} <= set(available_presets())


def test_rig_detection_with_namespace():
    preset = load_preset("mixamo")
    names = [r.replace("mixamorig:", "mixamorig7:") for _, r in preset.joints]
    assert detect_rig(names).name == "mixamo"
    assert detect_rig([r for _, r in load_preset("unreal").joints]).name == "unreal"
    assert detect_rig([r for _, r in load_preset("unity").joints]).name == "unity"
    assert detect_rig([r for _, r in load_preset("cmu").joints]).name == "cmu"


def _write_glb(path: Path, names: list[str], parents: list[int], positions: np.ndarray, scale: float) -> None:
    """A minimal GLB: joint nodes with translations (parent-relative) and inverse bind matrices."""
    import pygltflib

    n = len(names)
    ibm = np.zeros((n, 4, 4), np.float32)
    for k in range(n):
        M = np.eye(4)
        M[:3, 3] = -positions[k] * scale
        ibm[k] = M.T  # column-major
    blob = ibm.tobytes()
    nodes = []
    for k in range(n):
        rel = positions[k] - (positions[parents[k]] if parents[k] >= 0 else 0)
        children = [c for c in range(n) if parents[c] == k]
        nodes.append(pygltflib.Node(name=names[k], translation=[float(x) for x in rel], children=children or None))
    root = pygltflib.Node(name="Armature", scale=[scale] * 3, children=[k for k in range(n) if parents[k] < 0])
    nodes.append(root)
    gltf = pygltflib.GLTF2(
        scenes=[pygltflib.Scene(nodes=[n])], scene=0, nodes=nodes,
        skins=[pygltflib.Skin(joints=list(range(n)), inverseBindMatrices=0)],
        accessors=[pygltflib.Accessor(bufferView=0, componentType=pygltflib.FLOAT, count=n, type="MAT4")],
        bufferViews=[pygltflib.BufferView(buffer=0, byteOffset=0, byteLength=len(blob))],
        buffers=[pygltflib.Buffer(byteLength=len(blob))],
    )
    gltf.set_binary_blob(blob)
    gltf.save_binary(str(path))
    assert struct.unpack("<I", path.read_bytes()[:4])[0] == 0x46546C67  # "glTF"


def test_generated_glb_both_bind_sources(tmp_path):
    preset = load_preset("unreal").smpl_to_rig
    J = _fake_model().J_template.double().numpy() * 100  # centimetres
    from smplik.conventions import PARENTS

    names = [preset[n] for n in JOINT_NAMES]
    path = tmp_path / "char.glb"
    _write_glb(path, names, list(PARENTS), J, scale=0.01)
    expected = joints_to_features(torch.tensor(J / 100)).numpy()
    for bind in ("inverse_bind", "nodes"):
        sk = read_gltf(path, bind=bind)
        assert sk.names[2] == "thigh_r" and sk.parents[2] == 0
        char = prepare_character(sk)
        assert char.rig.name == "unreal" and char.units_m == 1.0
        np.testing.assert_allclose(char.features, expected, atol=1e-5)


# ----------------------------------------------------------------------------- CLI and shared data


def test_cli_writes_shape_json(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from shape_inversion import cli

    monkeypatch.setenv("SMPLIK_CACHE_DIR", str(tmp_path / "cache"))
    model = _fake_model()
    monkeypatch.setattr("smplik.body_model.load_body_model", lambda gender, model_dir=None: model)
    bvh = tmp_path / "c.bvh"
    bvh.write_text(_BVH)
    out = tmp_path / "SHAPE.json"
    result = CliRunner().invoke(cli.app, [str(bvh), "--out", str(out), "--units", "cm", "--rest", "offsets",
                                          "--bank-samples", "4000"])
    assert result.exit_code == 0, result.output
    shape = json.loads(out.read_text())
    assert len(shape["betas"]) == NUM_BETAS and shape["gender"] == "neutral" and shape["scale"] > 0
    assert shape["character"]["units_m"] == 0.01 and "max_feature_residual_m" in shape["diagnostics"]
    bad = CliRunner().invoke(cli.app, [str(bvh), "--out", str(out), "--rig", "nope"])
    assert bad.exit_code == 1 and "available presets" in bad.output


def test_shared_characters_map_and_invert(fake_estimator, shared_data):
    mh = shared_data.file("data/custom-characters/mh_default_tpose.bvh")
    char = prepare_character(read_bvh(mh))
    assert char.rig.name == "makehuman" and char.units_m == 0.1 and char.up == "z"
    assert 1.3 < char.head_ankle_height_m < 1.6
    cmu = shared_data.cmu("01_01.bvh")
    c2 = prepare_character(read_bvh(cmu))
    assert c2.rig.name == "cmu" and c2.units_source == "rig" and 1.2 < c2.head_ankle_height_m < 1.6


def test_joint_fit_recovers_smpl_rest_joints_of_a_known_body():
    """Known truth: SMPL's own rest joints of random bodies (moved, not turned: smplik's frame). The joint fit
    puts every rest joint of its body within a few mm of the truth, far closer than the first stage. (Beta and
    scale are not told apart by the joints alone: SMPL's first shape directions also change the size, so the
    body, ``scale * J(beta)``, is what is compared.)"""
    from shape_inversion.joint_fit import MappedRest
    from shape_inversion.skeleton_io import _neutral_estimator
    from smplik.body_model import load_body_model
    from smplik.conventions import PARENTS

    estimator, model = _neutral_estimator(), load_body_model(Gender.NEUTRAL)
    rng = np.random.default_rng(5)
    for _ in range(4):
        betas, scale = rng.uniform(-2, 2, NUM_BETAS), float(rng.uniform(0.8, 1.2))
        J = scale * model.rest_joints(torch.tensor(betas)).double().numpy()
        rest = MappedRest.from_skeleton(J + rng.normal(size=3), PARENTS, {n: j for j, n in enumerate(JOINT_NAMES)})
        est = estimator.estimate(joints_to_features(torch.tensor(J)).numpy(), rest)
        got = est.scale * model.rest_joints(torch.tensor(est.betas)).double().numpy()
        first = est.kernel_scale * model.rest_joints(torch.tensor(est.kernel_betas)).double().numpy()
        err = np.linalg.norm(got - got[0] - (J - J[0]), axis=1)  # both bodies' pelvis at the origin
        assert est.joint_fit and est.rest_joint_residual_m < 0.002 < est.first_stage_rest_joint_residual_m
        assert err.max() < 0.01 and err.mean() < 0.003
        assert err.mean() < 0.5 * np.linalg.norm(first - first[0] - (J - J[0]), axis=1).mean()
        assert np.all(np.abs(est.betas) <= estimator.bank.config.beta_range)


def test_joint_fit_can_be_turned_off_and_never_makes_the_rest_residual_worse(fake_estimator):
    import dataclasses

    from shape_inversion.joint_fit import MappedRest
    from smplik.conventions import PARENTS

    model = _fake_model()
    J = 1.1 * model.rest_joints(torch.tensor(np.full(NUM_BETAS, 0.5))).double().numpy()
    f = joints_to_features(torch.tensor(J)).numpy()
    rest = MappedRest.from_skeleton(J, PARENTS, {n: j for j, n in enumerate(JOINT_NAMES)})
    on = fake_estimator.estimate(f, rest)
    off = dataclasses.replace(fake_estimator, config=EstimatorConfig(joint_fit=False)).estimate(f, rest)
    assert not off.joint_fit and off.rest_joint_residual_m == off.first_stage_rest_joint_residual_m
    np.testing.assert_allclose(off.betas, off.kernel_betas)
    assert on.rest_joint_residual_m <= on.first_stage_rest_joint_residual_m
    assert on.rest_joint_residual_m <= off.rest_joint_residual_m
    assert on.to_dict()["diagnostics"]["joint_fit"] == on.joint_fit
    assert np.isnan(fake_estimator.estimate(f).rest_joint_residual_m)  # no joints given: the first stage only


@pytest.mark.parametrize(("mapped", "aims"), [
    (("pelvis", "left_hip", "right_hip", "spine3", "neck", "left_collar"), {"pelvis": "spine3", "spine3": "neck"}),
    (("pelvis", "left_hip", "spine1", "spine3", "head", "left_collar"), {"pelvis": "spine1", "spine1": None,
                                                                          "spine3": "head"}),
    (("pelvis", "left_hip", "right_hip", "left_knee"), {"pelvis": "left_hip", "left_hip": "left_knee"}),
])
def test_the_pelvis_and_spine3_aim_up_the_trunk_through_unmapped_joints(mapped, aims):
    """The rest alignment's aim: a pelvis whose spine1-2 are unmapped aims at spine3 (not sideways at a hip), a
    spine3 without a neck at the head; a pelvis without any trunk joint at its first mapped child; a single-child
    joint whose child is unmapped (spine1 without spine2) has no aim, as before."""
    from shape_inversion.joint_fit import aim_children

    smpl = np.array([JOINT_INDEX[n] for n in mapped])
    aim = aim_children(smpl)
    got = {n: (mapped[aim[m]] if aim[m] >= 0 else None) for m, n in enumerate(mapped)}
    assert {n: got[n] for n in aims} == aims
