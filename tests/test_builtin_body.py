"""Tests of the built-in SMPL-format body model generator (smplik.builtin_body)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from smplik import builtin_body
from smplik.builtin_body import (
    BETA_DESCRIPTIONS,
    BUILTIN_VERSION,
    STATURE_BETA,
    builtin_cache_dir,
    builtin_model_path,
    generate_builtin_model,
)
from smplik.conventions import JOINT_INDEX, LEFT_RIGHT, NUM_BETAS, NUM_JOINTS, PARENTS, Gender

GENDERS = tuple(Gender)
J = JOINT_INDEX
CENTRAL = [j for j in range(NUM_JOINTS) if LEFT_RIGHT[j] == j]

# Real SMPL's neutral joints relative to the pelvis (left side), from DESIGN section 3.
SMPL_NEUTRAL_LEFT = {
    "left_hip": (0.07, -0.09, 0.0),
    "spine1": (0.0, 0.11, -0.02),
    "left_knee": (0.105, -0.47, 0.0),
    "spine2": (0.0, 0.25, -0.01),
    "left_ankle": (0.09, -0.88, -0.04),
    "spine3": (0.0, 0.31, 0.0),
    "left_foot": (0.12, -0.94, 0.08),
    "neck": (0.0, 0.52, -0.03),
    "left_collar": (0.08, 0.43, -0.01),
    "head": (0.0, 0.61, 0.02),
    "left_shoulder": (0.17, 0.46, -0.02),
    "left_elbow": (0.43, 0.44, -0.04),
    "left_wrist": (0.68, 0.45, -0.04),
    "left_hand": (0.77, 0.44, -0.05),
}


@pytest.fixture(scope="module")
def models() -> dict[Gender, dict[str, np.ndarray]]:
    return {g: generate_builtin_model(g) for g in GENDERS}


def rest_joints(model: dict[str, np.ndarray], betas: np.ndarray | None = None) -> np.ndarray:
    """J(beta) = J_regressor @ (v_template + shapedirs @ beta), (24, 3)."""
    return model["J_regressor"] @ shaped_vertices(model, betas)


def shaped_vertices(model: dict[str, np.ndarray], betas: np.ndarray | None = None) -> np.ndarray:
    v = model["v_template"]
    return v if betas is None else v + model["shapedirs"] @ betas


def stature(v: np.ndarray) -> float:
    return float(v[:, 1].max() - v[:, 1].min())


def unit_beta(k: int, value: float) -> np.ndarray:
    b = np.zeros(NUM_BETAS)
    b[k] = value
    return b


def mirror_perm(v: np.ndarray) -> np.ndarray:
    dist, idx = cKDTree(v).query(v * [-1.0, 1.0, 1.0])
    assert dist.max() < 1e-9
    return idx


# ---------------------------------------------------------------------------------------------- API


def test_beta_descriptions_state_what_the_model_does(models) -> None:
    """The per-unit amounts in BETA_DESCRIPTIONS (listed in the module docstring) are the model's."""
    doc = builtin_body.__doc__ or ""
    assert len(BETA_DESCRIPTIONS) == NUM_BETAS and all(d.split(":")[0] in doc for d in BETA_DESCRIPTIONS)
    assert BETA_DESCRIPTIONS[STATURE_BETA].startswith("stature")
    m = models[Gender.NEUTRAL]

    def stated(k: int) -> float:
        value, unit = re.search(r"\+([\d.]+) ?(m|cm|%)", BETA_DESCRIPTIONS[k]).groups()
        return float(value) * {"m": 1.0, "cm": 0.01, "%": 0.01}[unit]

    def chain(joints: np.ndarray, *names: str) -> float:
        return sum(bone(joints, a, b) for a, b in zip(names, names[1:], strict=False))

    def delta(k: int, measure) -> float:
        return measure(rest_joints(m, unit_beta(k, 1.0)), shaped_vertices(m, unit_beta(k, 1.0))) - measure(
            rest_joints(m), shaped_vertices(m))

    leg = ("left_hip", "left_knee", "left_ankle")
    arm = ("left_shoulder", "left_elbow", "left_wrist")
    measured = {
        STATURE_BETA: delta(STATURE_BETA, lambda j, v: stature(v)),
        2: delta(2, lambda j, v: chain(j, *leg)),
        3: delta(3, lambda j, v: chain(j, *arm) / chain(rest_joints(m), *arm)),
        4: delta(4, lambda j, v: j[J["left_shoulder"], 0]),
        9: delta(9, lambda j, v: j[J["head"], 1]),
    }
    for k, value in measured.items():
        assert value == pytest.approx(stated(k), rel=0.25), (BETA_DESCRIPTIONS[k], value)
    assert abs(delta(2, lambda j, v: stature(v))) < 1e-3  # leg-to-torso ratio keeps the stature


def test_unknown_gender_raises() -> None:
    with pytest.raises(ValueError, match="Unknown gender"):
        generate_builtin_model("robot")


@pytest.mark.parametrize("gender", GENDERS)
def test_layout_shapes_dtypes(models, gender: Gender) -> None:
    m = models[gender]
    n = m["v_template"].shape[0]
    expected = {
        "v_template": ((n, 3), np.float64),
        "shapedirs": ((n, 3, NUM_BETAS), np.float64),
        "posedirs": ((n, 3, 207), np.float64),
        "J_regressor": ((NUM_JOINTS, n), np.float64),
        "weights": ((n, NUM_JOINTS), np.float64),
        "kintree_table": ((2, NUM_JOINTS), np.int64),
    }
    for key, (shape, dtype) in expected.items():
        assert m[key].shape == shape, key
        assert m[key].dtype == dtype, key
        assert np.isfinite(m[key]).all(), key
    assert m["f"].dtype == np.int64 and m["f"].ndim == 2 and m["f"].shape[1] == 3
    assert m["f"].min() == 0 and m["f"].max() == n - 1
    assert m["kintree_table"][0, 0] == 4294967295
    assert list(m["kintree_table"][0, 1:]) == list(PARENTS[1:])
    assert list(m["kintree_table"][1]) == list(range(NUM_JOINTS))
    assert not m["posedirs"].any()
    assert m["gender"].shape == () and str(m["gender"]) == gender.value


def test_deterministic(models, tmp_path) -> None:
    builtin_body._neutral.cache_clear()
    for g in GENDERS:
        again = generate_builtin_model(g)
        assert again.keys() == models[g].keys()
        for key, value in models[g].items():
            assert np.array_equal(again[key], value), (g, key)
    a = builtin_model_path("female", tmp_path / "a").read_bytes()
    b = builtin_model_path("female", tmp_path / "b").read_bytes()
    assert a == b


# ---------------------------------------------------------------------------------------------- mesh


@pytest.mark.parametrize("gender", GENDERS)
def test_mesh_is_closed_and_outward(models, gender: Gender) -> None:
    m = models[gender]
    mesh = trimesh.Trimesh(m["v_template"], m["f"], process=False)
    assert 3000 <= len(mesh.vertices) <= 8000
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0.03  # outward winding, adult volume in m^3
    assert mesh.body_count == 1


def test_same_topology_for_all_genders(models) -> None:
    for key in ("f", "J_regressor", "weights"):
        assert np.array_equal(models[Gender.MALE][key], models[Gender.NEUTRAL][key])
        assert np.array_equal(models[Gender.FEMALE][key], models[Gender.NEUTRAL][key])
    assert not np.allclose(models[Gender.MALE]["v_template"], models[Gender.NEUTRAL]["v_template"])


@pytest.mark.parametrize("gender", GENDERS)
def test_weights_convex_smooth_and_on_their_bone(models, gender: Gender) -> None:
    m = models[gender]
    w, v = m["weights"], m["v_template"]
    assert (w >= 0).all()
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    # Smooth: neighbouring vertices have similar weights.
    edges = trimesh.Trimesh(v, m["f"], process=False).edges_unique
    assert np.abs(w[edges[:, 0]] - w[edges[:, 1]]).max() < 0.35
    # A vertex halfway along a bone is dominated by that bone's joint.
    joints = rest_joints(m)
    for joint, child in (
        ("left_shoulder", "left_elbow"),
        ("left_elbow", "left_wrist"),
        ("right_hip", "right_knee"),
        ("left_knee", "left_ankle"),
    ):
        mid = 0.5 * (joints[J[joint]] + joints[J[child]])
        nearest = cKDTree(v).query(mid, k=10)[1]
        assert (w[nearest].argmax(axis=1) == J[joint]).all(), joint
    head_top = v[:, 1].argmax()
    assert w[head_top].argmax() == J["head"]


@pytest.mark.parametrize("gender", GENDERS)
def test_regressor_rows_are_convex_vertex_averages(models, gender: Gender) -> None:
    reg = models[gender]["J_regressor"]
    assert (reg >= 0).all()
    np.testing.assert_allclose(reg.sum(axis=1), 1.0, atol=1e-12)
    support = (reg > 0).sum(axis=1)
    assert (support >= 8).all() and (support <= 600).all()  # a patch around the joint, not the whole mesh


# ---------------------------------------------------------------------------------------------- pose


@pytest.mark.parametrize("gender", GENDERS)
def test_rest_pose_is_a_t_pose_on_the_floor(models, gender: Gender) -> None:
    m = models[gender]
    v, joints = m["v_template"], rest_joints(m)
    assert abs(v[:, 1].min()) < 1e-9  # soles on the floor
    for side, s in (("left_", 1.0), ("right_", -1.0)):
        sh, el, wr, ha = (joints[J[side + n]] for n in ("shoulder", "elbow", "wrist", "hand"))
        # arms straight out along +-x (left at +x), at shoulder height
        assert 0 < s * sh[0] < s * el[0] < s * wr[0] < s * ha[0]
        assert abs(wr[1] - sh[1]) < 0.03 and abs(el[1] - sh[1]) < 0.03
        hip, knee, ankle, foot = (joints[J[side + n]] for n in ("hip", "knee", "ankle", "foot"))
        # legs straight down, slightly apart; the foot joint forward (+z) of the ankle
        assert hip[1] > knee[1] > ankle[1] > foot[1] > 0
        assert 0.03 < s * ankle[0] < 0.2
        assert foot[2] > ankle[2] + 0.05
    # the spine goes up to the head; the toes are the front-most points
    chain = [J[n] for n in ("pelvis", "spine1", "spine2", "spine3", "neck", "head")]
    assert np.all(np.diff(joints[chain, 1]) > 0)
    assert v[v[:, 2].argmax(), 1] < 0.1
    # the hands are the outermost points
    assert np.isclose(v[:, 0].max(), -v[:, 0].min())
    assert v[:, 0].max() > joints[J["left_hand"], 0]


def test_neutral_joints_resemble_smpl(models) -> None:
    joints = rest_joints(models[Gender.NEUTRAL])
    rel = joints - joints[J["pelvis"]]
    ref = np.zeros((NUM_JOINTS, 3))
    for name, xyz in SMPL_NEUTRAL_LEFT.items():
        ref[J[name]] = xyz
        if name.startswith("left_"):
            ref[J["right_" + name[5:]]] = (-xyz[0], xyz[1], xyz[2])
    scale = float((rel * ref).sum() / (ref * ref).sum())
    assert 0.9 < scale < 1.05
    np.testing.assert_allclose(rel, scale * ref, atol=2e-3)


# ---------------------------------------------------------------------------------------------- shape


def test_stature_per_gender(models) -> None:
    h = {g: stature(models[g]["v_template"]) for g in GENDERS}
    assert h[Gender.FEMALE] < h[Gender.NEUTRAL] < h[Gender.MALE]
    assert abs(h[Gender.NEUTRAL] - 1.70) < 0.01
    assert abs(h[Gender.MALE] - 1.78) < 0.01
    assert abs(h[Gender.FEMALE] - 1.64) < 0.01

    def hip_to_shoulder(g: Gender) -> float:
        joints = rest_joints(models[g])
        return (joints[J["left_hip"], 0] - joints[J["right_hip"], 0]) / (
            joints[J["left_shoulder"], 0] - joints[J["right_shoulder"], 0]
        )

    assert hip_to_shoulder(Gender.FEMALE) > hip_to_shoulder(Gender.NEUTRAL) > hip_to_shoulder(Gender.MALE)


@pytest.mark.parametrize("gender", GENDERS)
def test_stature_beta_is_monotonic_and_keeps_feet_on_floor(models, gender: Gender) -> None:
    m = models[gender]
    values = np.linspace(-3.0, 3.0, 13)
    heights = []
    for b in values:
        v = shaped_vertices(m, unit_beta(STATURE_BETA, b))
        heights.append(stature(v))
        assert abs(v[:, 1].min()) < 1e-3
    assert np.all(np.diff(heights) > 0)
    assert 1.40 <= heights[0] <= 1.60
    assert 1.80 <= heights[-1] <= 2.10


@pytest.mark.parametrize("gender", GENDERS)
def test_rest_joints_mirror_symmetric_for_any_beta(models, gender: Gender) -> None:
    m = models[gender]
    rng = np.random.default_rng(7)
    for betas in [np.zeros(NUM_BETAS), *rng.uniform(-3.0, 3.0, (5, NUM_BETAS))]:
        joints = rest_joints(m, betas)
        np.testing.assert_allclose(joints[list(LEFT_RIGHT)] * [-1.0, 1.0, 1.0], joints, atol=1e-6)
        np.testing.assert_allclose(joints[CENTRAL, 0], 0.0, atol=1e-6)


def test_mesh_and_shape_dirs_mirror_symmetric(models) -> None:
    m = models[Gender.NEUTRAL]
    perm = mirror_perm(m["v_template"])
    d = m["shapedirs"]
    np.testing.assert_allclose(d[perm] * np.array([-1.0, 1.0, 1.0])[:, None], d, atol=1e-12)
    np.testing.assert_allclose(m["weights"][perm][:, list(LEFT_RIGHT)], m["weights"], atol=1e-12)


def test_every_shape_direction_is_used_and_bounded(models) -> None:
    for g in GENDERS:
        d = models[g]["shapedirs"]
        per_component = np.linalg.norm(d, axis=1).max(axis=0)  # max displacement per unit beta (m)
        assert (per_component > 0.005).all()
        assert (per_component < 0.08).all()


def bone(joints: np.ndarray, a: str, b: str) -> float:
    return float(np.linalg.norm(joints[J[a]] - joints[J[b]]))


def test_shape_directions_do_what_they_say(models) -> None:
    m = models[Gender.NEUTRAL]
    j0 = rest_joints(m)

    def j(k: int, value: float = 2.0) -> np.ndarray:
        return rest_joints(m, unit_beta(k, value))

    # 0 stature: every bone scales up
    assert bone(j(0), "left_hip", "left_knee") > bone(j0, "left_hip", "left_knee")
    # 1 mass: volume grows, the skeleton barely moves
    vol = trimesh.Trimesh(shaped_vertices(m, unit_beta(1, 2.0)), m["f"], process=False).volume
    assert vol > 1.15 * trimesh.Trimesh(m["v_template"], m["f"], process=False).volume
    assert np.abs(j(1) - j0).max() < 0.02
    # 2 leg-to-torso: longer legs, stature almost kept
    assert bone(j(2), "left_hip", "left_ankle") > bone(j0, "left_hip", "left_ankle") + 0.02
    assert abs(stature(shaped_vertices(m, unit_beta(2, 2.0))) - stature(m["v_template"])) < 0.01
    # 3 arm length: upper arm and forearm both longer
    assert bone(j(3), "left_shoulder", "left_elbow") > bone(j0, "left_shoulder", "left_elbow") + 0.01
    assert bone(j(3), "left_elbow", "left_wrist") > bone(j0, "left_elbow", "left_wrist") + 0.01
    # 4 shoulder width, 5 hip width
    assert bone(j(4), "left_shoulder", "right_shoulder") > bone(j0, "left_shoulder", "right_shoulder") + 0.03
    assert bone(j(5), "left_hip", "right_hip") > bone(j0, "left_hip", "right_hip") + 0.02
    # 6 chest depth, 7 waist girth: the torso gets deeper at the chest / wider at the waist
    v0 = m["v_template"]
    chest = np.abs(v0[:, 1] - j0[J["spine3"], 1]) < 0.03

    def chest_depth(v: np.ndarray) -> float:
        return float(np.ptp(v[chest & (np.abs(v0[:, 0]) < 0.05), 2]))

    assert chest_depth(shaped_vertices(m, unit_beta(6, 2.0))) > chest_depth(v0) + 0.02
    waist = (np.abs(v0[:, 1] - j0[J["spine1"], 1]) < 0.03) & (np.abs(v0[:, 0]) < 0.25)

    def waist_width(v: np.ndarray) -> float:
        return float(np.ptp(v[waist, 0]))

    assert waist_width(shaped_vertices(m, unit_beta(7, 2.0))) > waist_width(v0) + 0.02
    # 8 head size: the top of the head rises; 9 neck length: head joint moves up
    assert stature(shaped_vertices(m, unit_beta(8, 2.0))) > stature(v0) + 0.01
    assert j(9)[J["head"], 1] > j0[J["head"], 1] + 0.015
    assert abs(j(9)[J["left_shoulder"], 1] - j0[J["left_shoulder"], 1]) < 1e-3


# ---------------------------------------------------------------------------------------------- files / smplx


def smpl_fk(joints_rest: np.ndarray, aa: np.ndarray) -> np.ndarray:
    """Reference skeleton FK (24, 3) from rest joints (24, 3) and axis-angles (24, 3)."""
    rot = Rotation.from_rotvec(aa).as_matrix()
    g_rot = np.zeros((NUM_JOINTS, 3, 3))
    g_pos = np.zeros((NUM_JOINTS, 3))
    for j, p in enumerate(PARENTS):
        if p < 0:
            g_rot[j], g_pos[j] = rot[j], joints_rest[j]
        else:
            g_rot[j] = g_rot[p] @ rot[j]
            g_pos[j] = g_pos[p] + g_rot[p] @ (joints_rest[j] - joints_rest[p])
    return g_pos


@pytest.mark.parametrize("gender", GENDERS)
def test_smplx_loads_written_file(tmp_path, gender: Gender) -> None:
    smplx = pytest.importorskip("smplx", reason="smplx is not installed (pip install -e .)")
    path = builtin_model_path(gender, tmp_path)
    arrays = dict(np.load(path))
    layer = smplx.SMPL(
        model_path="",
        data_struct=smplx.utils.Struct(**arrays),
        vertex_ids={k: 0 for k in smplx.vertex_ids.vertex_ids["smplh"]},
        use_hands=False,
        use_feet_keypoints=False,
        dtype=torch.float64,
    )
    rng = np.random.default_rng(3)
    betas = rng.uniform(-2.0, 2.0, NUM_BETAS)
    pose = rng.normal(0.0, 0.4, (NUM_JOINTS, 3))
    with torch.no_grad():
        rest = layer(betas=torch.from_numpy(betas)[None])
        posed = layer(
            betas=torch.from_numpy(betas)[None],
            global_orient=torch.from_numpy(pose[:1]).reshape(1, 3),
            body_pose=torch.from_numpy(pose[1:]).reshape(1, 69),
        )
    joints_rest = rest_joints(arrays, betas)
    np.testing.assert_allclose(rest.joints[0, :NUM_JOINTS].numpy(), joints_rest, atol=1e-5)
    np.testing.assert_allclose(rest.vertices[0].numpy(), shaped_vertices(arrays, betas), atol=1e-5)
    np.testing.assert_allclose(posed.joints[0, :NUM_JOINTS].numpy(), smpl_fk(joints_rest, pose), atol=1e-5)


def test_cache_path_atomic_write_and_reuse(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("SMPLIK_CACHE_DIR", str(tmp_path / "env"))
    path = builtin_model_path("male")
    assert path == builtin_cache_dir(tmp_path / "env") / "SMPL_MALE.npz"
    assert path.parent.name.startswith(f"builtin-{BUILTIN_VERSION}-")
    assert [p.name for p in path.parent.iterdir()] == ["SMPL_MALE.npz"]  # no temp file left
    stamp = path.stat().st_mtime_ns
    assert builtin_model_path(Gender.MALE) == path
    assert path.stat().st_mtime_ns == stamp  # reused, not rewritten
    # an explicit cache_dir wins over the environment
    other = builtin_model_path("neutral", tmp_path / "explicit")
    assert other.parent == builtin_cache_dir(tmp_path / "explicit")
    assert other.name == "SMPL_NEUTRAL.npz"
    with np.load(other) as data:
        assert str(data["gender"]) == "neutral"
        assert data["kintree_table"][0, 0] == 4294967295
