"""SMPL-IK network: shapes, permutation and translation invariance, conditioning, learning."""

import dataclasses

import pytest
import torch

from smplik.conventions import JOINT_INDEX, PARENTS, EffectorType
from smplik.data.effector_sampling import EffectorSamplingConfig, sample_effectors
from smplik.effectors import Effector, EffectorBatch, pack_effectors
from smplik.kinematics import forward_kinematics
from smplik.losses import LossConfig, lookat_angle, protores_loss
from smplik.network import NetworkConfig, ProtoResIK
from smplik.rotations import axis_angle_to_matrix

SMALL = NetworkConfig(width=64, encoder_blocks=2, decoder_blocks=2, layers_per_block=2)


@pytest.fixture(scope="module", params=[False, True], ids=["paper", "effector_slots"])
def model(bodies, request):
    torch.manual_seed(0)
    return ProtoResIK(dataclasses.replace(SMALL, effector_slots=request.param), bodies.J_template,
                      bodies.J_dirs).eval()


def ground_truth(bodies, B=8, seed=0):
    g = torch.Generator().manual_seed(seed)
    R_local = axis_angle_to_matrix(torch.randn(B, 24, 3, generator=g) * 0.3)
    betas = torch.randn(B, 10, generator=g)
    gender = torch.randint(0, 3, (B,), generator=g)
    J_rest = bodies.rest_joints(betas, gender)
    R_world, p_world = forward_kinematics(R_local, J_rest, torch.randn(B, 3, generator=g))
    return R_local, R_world, p_world, betas, gender, g


def test_output_shapes(model, bodies):
    R_local, R_world, p_world, betas, gender, g = ground_truth(bodies)
    eff = sample_effectors(p_world, R_world, EffectorSamplingConfig(), g, num_effectors=7).effectors
    out = model(eff, betas, gender)
    assert out.R_local.shape == (8, 24, 3, 3) and out.R_world.shape == (8, 24, 3, 3)
    assert out.p_world.shape == (8, 24, 3) and out.draft.shape == (8, 24, 3) and out.transl.shape == (8, 3)
    eye = torch.eye(3).expand(8, 24, 3, 3)
    torch.testing.assert_close(out.R_local.transpose(-1, -2) @ out.R_local, eye, atol=1e-5, rtol=0)


def test_effector_permutation_invariance(model, bodies):
    R_local, R_world, p_world, betas, gender, g = ground_truth(bodies)
    eff = sample_effectors(p_world, R_world, EffectorSamplingConfig(), g, num_effectors=9).effectors
    perm = torch.randperm(9, generator=g)
    shuffled = EffectorBatch(eff.joint[:, perm], eff.type[:, perm], eff.data[:, perm], eff.tolerance[:, perm],
                             eff.mask[:, perm])
    a, b = model(eff, betas, gender), model(shuffled, betas, gender)
    torch.testing.assert_close(a.p_world, b.p_world, atol=1e-5, rtol=0)
    torch.testing.assert_close(a.R_local, b.R_local, atol=1e-5, rtol=0)


def test_translation_invariance(model, bodies):
    R_local, R_world, p_world, betas, gender, g = ground_truth(bodies)
    eff = sample_effectors(p_world, R_world, EffectorSamplingConfig(), g, num_effectors=10).effectors
    shift = torch.tensor([1.5, -0.3, 2.0])
    moves = (eff.type != int(EffectorType.ROTATION)).float()[..., None] * shift
    moved = dataclasses.replace(eff, data=torch.cat([eff.data[..., :3] + moves, eff.data[..., 3:]], -1))
    a, b = model(eff, betas, gender), model(moved, betas, gender)
    torch.testing.assert_close(b.p_world, a.p_world + shift, atol=1e-5, rtol=0)
    torch.testing.assert_close(b.R_local, a.R_local, atol=1e-5, rtol=0)


def test_no_position_effector_gives_finite_output(model, bodies):
    eff = pack_effectors([Effector.rotation("pelvis", torch.eye(3).numpy()),
                          Effector.look_at("head", [0, 1.6, 3.0], [0, 0, 1])])
    out = model(eff, torch.zeros(1, 10), torch.zeros(1, dtype=torch.long))
    assert torch.isfinite(out.p_world).all()


def test_beta_and_gender_change_bone_lengths(model, bodies):
    eff = pack_effectors([Effector.position("pelvis", [0, 1, 0])] * 1)
    eff = EffectorBatch(*(x.expand(3, *x.shape[1:]) for x in (eff.joint, eff.type, eff.data, eff.tolerance,
                                                                 eff.mask)))
    betas = torch.zeros(3, 10)
    betas[1, 0], betas[2, 0] = 3.0, -3.0  # stature component
    out = model(eff, betas, torch.zeros(3, dtype=torch.long))
    knee, ankle = JOINT_INDEX["left_knee"], JOINT_INDEX["left_ankle"]
    shin = (out.p_world[:, knee] - out.p_world[:, ankle]).norm(dim=-1)
    assert shin[1] > shin[0] > shin[2]
    by_gender = model(EffectorBatch(eff.joint, eff.type, eff.data, eff.tolerance, eff.mask), torch.zeros(3, 10),
                      torch.tensor([0, 1, 2]))
    shin_g = (by_gender.p_world[:, knee] - by_gender.p_world[:, ankle]).norm(dim=-1)
    expected = (bodies.J_template[:, knee] - bodies.J_template[:, ankle]).norm(dim=-1)
    torch.testing.assert_close(shin_g, expected, atol=1e-5, rtol=0)
    assert shin_g[1] > shin_g[2]  # male shin longer than female


def test_effector_slots_hold_exact_values():
    from smplik.network import SLOT_FEATURES, effector_slots

    eff = pack_effectors([Effector.position("left_wrist", [0.5, 1.2, 0.1], tolerance=0.2),
                          Effector.position("left_wrist", [0.7, 1.0, 0.1], tolerance=0.4),
                          Effector.look_at("head", [0, 1.6, 2.0], [0, 0, 1])])
    slots = effector_slots(eff, eff.data).view(24, SLOT_FEATURES)
    wrist, head = slots[JOINT_INDEX["left_wrist"]], slots[JOINT_INDEX["head"]]
    torch.testing.assert_close(wrist[:5], torch.tensor([0.6, 1.1, 0.1, 1.0, 0.3]))  # averaged duplicates
    assert wrist[5:].abs().sum() == 0
    torch.testing.assert_close(head[13:21], torch.tensor([0, 1.6, 2.0, 0, 0, 1, 1.0, 0.0]))
    assert slots[JOINT_INDEX["pelvis"]].abs().sum() == 0


@pytest.mark.parametrize("slots", [False, True])
def test_a_few_steps_reduce_the_loss_on_a_fixed_batch(bodies, slots):
    torch.manual_seed(0)
    net = ProtoResIK(dataclasses.replace(SMALL, effector_slots=slots), bodies.J_template, bodies.J_dirs)
    R_local, R_world, p_world, betas, gender, g = ground_truth(bodies, B=32)
    sampled = sample_effectors(p_world, R_world, EffectorSamplingConfig(), g, num_effectors=8)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    losses = []
    for _ in range(30):
        out = net(sampled.effectors, betas, gender)
        loss, _ = protores_loss(out, R_local, R_world, p_world, sampled.effectors, sampled.weight, LossConfig())
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


def test_effector_sampling_rules(bodies):
    _, R_world, p_world, *_ , g = ground_truth(bodies, B=256)
    s = sample_effectors(p_world, R_world, EffectorSamplingConfig(), g, num_effectors=16)
    eff = s.effectors
    assert (eff.type[:, 0] == 0).all()
    for t in range(3):  # joints are distinct within each type
        for row_j, row_t in zip(eff.joint, eff.type, strict=True):
            js = row_j[row_t == t]
            assert len(set(js.tolist())) == len(js)
    assert set(eff.type.unique().tolist()) == {0, 1, 2}
    assert (s.weight <= 1000).all() and (s.weight >= 10 - 1e-4).all()  # W = min(1000, 1/sigma), sigma <= 0.1
    low = eff.tolerance < 0.3  # sigma ~ 0: position data equals the joint
    pos = (eff.type == 0) & low
    bi = torch.arange(256)[:, None].expand_as(eff.joint)
    torch.testing.assert_close(eff.data[pos][:, :3], p_world[bi[pos], eff.joint[pos]], atol=1e-5, rtol=0)
    look = eff.type == 2  # look-at targets lie along the joint's world direction
    angle = lookat_angle(eff.data[look][:, :3], eff.data[look][:, 3:], p_world[bi[look], eff.joint[look]],
                         R_world[bi[look], eff.joint[look]])
    assert angle[eff.tolerance[look] < 0.3].max() < 1e-3


def test_effector_validation_errors():
    with pytest.raises(ValueError, match="Unknown joint 'left_wristt'.*valid names"):
        Effector.position("left_wristt", [0, 0, 0])
    with pytest.raises(ValueError, match="NaN or inf"):
        Effector.position("head", [0, float("nan"), 0])
    with pytest.raises(ValueError, match=r"tolerance 1.5 is outside \[0, 1\]"):
        Effector.position("head", [0, 0, 0], tolerance=1.5)
    with pytest.raises(ValueError, match="not a rotation matrix"):
        Effector.rotation("pelvis", [[1, 0, 0], [0, 1, 0], [0, 0, -1]])
    with pytest.raises(ValueError, match="zero vector"):
        Effector.look_at("head", [0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match=r"value: has shape \(2,\)"):
        Effector.position("head", [0, 0])


def test_bf16_autocast_runs_only_the_layers_in_low_precision(model, bodies):
    """Training with precision "bf16": the layers run in bfloat16, but the outputs are float32 and the
    rotations and FK run in float32 (orthonormal, bones of exactly the rest lengths), close to fp32."""
    R_local, R_world, p_world, betas, gender, g = ground_truth(bodies)
    eff = sample_effectors(p_world, R_world, EffectorSamplingConfig(), g, num_effectors=7).effectors
    with torch.no_grad():
        ref = model(eff, betas, gender)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            out = model(eff, betas, gender)
    for name in ("R_local", "R_world", "p_world", "draft", "transl"):
        assert getattr(out, name).dtype == torch.float32, name
    eye = torch.eye(3).expand(8, 24, 3, 3)
    torch.testing.assert_close(out.R_local.transpose(-1, -2) @ out.R_local, eye, atol=1e-5, rtol=0)
    J_rest = model.rest_joints(betas, gender)
    parents = list(PARENTS)
    bone = (J_rest[:, 1:] - J_rest[:, parents[1:]]).norm(dim=-1)
    posed = (out.p_world[:, 1:] - out.p_world[:, parents[1:]]).norm(dim=-1)
    torch.testing.assert_close(posed, bone, atol=1e-5, rtol=0)
    assert 0 < float((out.p_world - ref.p_world).abs().max()) < 0.05  # bfloat16 layers: close, not equal


def test_limb_first_layout(bodies):
    """limb_first = 1: the first min(N, 4) effectors are positions, one on a joint of each limb zone, and
    (joint, type) pairs stay unique; limb_first = 0 draws nothing extra (the paper's stream, bit for bit)."""
    from smplik.conventions import JOINT_NAMES, LIMB_ZONES, ZONES

    _, R_world, p_world, *_ = ground_truth(bodies, B=256)
    for n in (3, 4, 9, 16):
        eff = sample_effectors(p_world, R_world, EffectorSamplingConfig(limb_first=1.0),
                               torch.Generator().manual_seed(n), num_effectors=n).effectors
        for joints, kinds in zip(eff.joint.tolist(), eff.type.tolist(), strict=True):
            pairs = list(zip(joints, kinds, strict=True))
            assert len(set(pairs)) == n
            for (j, t), zone in zip(pairs[:4], LIMB_ZONES, strict=False):  # N = 3: three zones
                assert t == 0 and JOINT_NAMES[j] in ZONES[zone], (pairs, zone)
        hits = {JOINT_NAMES[j] for j in eff.joint[:, 0].tolist()}
        assert hits == set(ZONES["left_arm"])  # every joint of the zone is drawn
    paper = sample_effectors(p_world, R_world, EffectorSamplingConfig(), torch.Generator().manual_seed(5), 9)
    zero = sample_effectors(p_world, R_world, EffectorSamplingConfig(limb_first=0.0),
                            torch.Generator().manual_seed(5), 9)
    assert torch.equal(paper.effectors.joint, zero.effectors.joint)
    assert torch.equal(paper.effectors.data, zero.effectors.data)
    half = sample_effectors(p_world, R_world, EffectorSamplingConfig(limb_first=0.5), torch.Generator().manual_seed(6),
                            8).effectors
    layout = torch.stack([(half.type[:, k] == 0) & torch.isin(half.joint[:, k], torch.tensor(
        [JOINT_NAMES.index(n) for n in ZONES[z]])) for k, z in enumerate(LIMB_ZONES)], 1).all(1)
    assert 0.4 < layout.float().mean() < 0.65  # half the rows, plus the few the paper's sampling lays out so
