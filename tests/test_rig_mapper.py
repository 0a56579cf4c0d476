"""The rig mapper on real rigs and on synthetic variations of them, each asserting the exact map.

Real rigs: the two VRM 1.0 samples of ``tests/data/rigs/`` (their own humanoid tables are the expected maps),
the CMU BVH and the CMU dance (DAZ/Poser-style) BVH of ``../shared/data`` (shared_data fixture).
Variations of the 53-bone VRM humanoid: renamed joints in other tools' conventions, names removed (sides
from the rest geometry), children reordered, extra twist/IK/helper bones, several roots, a mirrored rig,
scaled armatures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shape_inversion.rig_mapper import RigMappingError, map_skeleton, side_of
from shape_inversion.rigs import detect_rig
from shape_inversion.skeleton_io import read_character, read_skeleton

RIGS = Path(__file__).resolve().parent / "data" / "rigs"
HUMANOID = RIGS / "VRMC_materials_mtoon_UV_Animation_Test.vrm"
BLOCKS = RIGS / "VRMC_vrm_expressions_isBinary_Overridden.vrm"


def _names_map(names, mapping) -> dict[str, str]:
    return {s: names[j] for s, j in mapping.joints.items()}


@pytest.fixture(scope="module")
def humanoid():
    sk = read_skeleton(HUMANOID)
    return list(sk.names), list(sk.parents), sk.positions.copy(), dict(sk.humanoid)


@pytest.mark.parametrize("path", [HUMANOID, BLOCKS], ids=lambda p: p.stem)
def test_vrm_table_is_read_and_the_mapper_reproduces_it(path):
    sk = read_skeleton(path)
    assert sk.gltf is not None and sk.gltf.skin == -1  # a humanoid on plain nodes, no skin
    assert sk.humanoid["pelvis"] in ("hips", "Hips") and sk.humanoid["left_shoulder"] in ("upper_arm.L", "UpperArm.L")
    char = read_character(path)
    assert char.rig.name == "vrm" and char.joint_map == {s: sk.humanoid[s] for s in char.joint_map}
    mapping = map_skeleton(sk.names, sk.parents, sk.positions)  # the table ignored: topology + geometry + names
    assert _names_map(sk.names, mapping) == sk.humanoid
    assert mapping.warnings == char.rig.warnings == VRM_DOUBTS[path.name]  # the same doubts for table and mapper


VRM_DOUBTS = {  # the chains of the two VRM samples that are shorter than SMPL's
    HUMANOID.name: ("the spine 'hips' (pelvis) -> 'chest' (spine3) is too short for SMPL's spine1, spine2, spine3 "
                    "(joints between: 'spine' (spine1)): spine2 unmapped",),
    BLOCKS.name: ("no finger joint after the left wrist 'Hand.L' (left_wrist): left_hand unmapped",
                  "no finger joint after the right wrist 'Hand.R' (right_wrist): right_hand unmapped"),
}


def test_vrm_extension_and_table_win_over_detection(tmp_path, humanoid):
    copy = tmp_path / "avatar.glb"
    copy.write_bytes(HUMANOID.read_bytes())
    assert read_character(copy).rig.name == "vrm"  # the table is read whatever the extension


# ----------------------------------------------------------------------------- synthetic variations

CONVENTIONS = {  # (side, part) -> name; parts of the 53-bone VRM rig
    "J_Bip": lambda side, part: f"J_Bip_{side.upper()}_{part.title().replace('_', '')}",
    "Bip01": lambda side, part: f"Bip01 {side.upper()} {part.title().replace('_', '')}",
    "daz": lambda side, part: f"{side}{part.title().replace('_', '')}",
    "ue": lambda side, part: f"{part.replace('_', '').lower()}_{side}",
    "Left": lambda side, part: f"{'Left' if side == 'l' else 'Right'}{part.title().replace('_', '')}",
}


def _rename(names: list[str], convention: str) -> list[str]:
    out = []
    for n in names:
        if n.endswith((".L", ".R")):
            side = n[-1].lower()
            out.append(CONVENTIONS[convention](side, n[:-2].replace(".", "_")))
        else:
            out.append(n)
    return out


def _expected(base: dict[str, str], names: list[str], renamed: list[str]) -> dict[str, str]:
    index = {n: k for k, n in enumerate(names)}
    return {s: renamed[index[n]] for s, n in base.items()}


@pytest.mark.parametrize("convention", sorted(CONVENTIONS))
def test_renamed_joints_in_other_conventions_map_exactly(humanoid, convention):
    names, parents, P, table = humanoid
    renamed = _rename(names, convention)
    assert side_of(renamed[names.index("upper_leg.L")]) == "left"
    assert side_of(renamed[names.index("hand.R")]) == "right"
    mapping = map_skeleton(renamed, parents, P)
    assert _names_map(renamed, mapping) == _expected(table, names, renamed)


def test_names_removed_sides_come_from_the_geometry_with_a_warning(humanoid):
    names, parents, P, table = humanoid
    anonymous = [f"bone{k:03d}" for k in range(len(names))]
    mapping = map_skeleton(anonymous, parents, P)
    assert _names_map(anonymous, mapping) == _expected(table, names, anonymous)
    assert any("rest geometry" in w for w in mapping.warnings)


def test_mirrored_rig_names_decide_the_side_and_without_names_the_geometry(humanoid):
    names, parents, P, table = humanoid
    mirrored = P * np.array([-1.0, 1.0, 1.0])  # left joints now at -x: the names still say which is left
    assert _names_map(names, map_skeleton(names, parents, mirrored)) == table
    anonymous = [f"bone{k:03d}" for k in range(len(names))]
    got = _names_map(anonymous, map_skeleton(anonymous, parents, mirrored))
    swapped = {s.replace("left", "tmp").replace("right", "left").replace("tmp", "right"): n for s, n in table.items()}
    assert got == _expected(swapped, names, anonymous)  # a mirrored body has its left on the other side


def _reindex(names, parents, P, order):
    """The skeleton with its joints listed in ``order`` (parents still first)."""
    new = {j: k for k, j in enumerate(order)}
    return [names[j] for j in order], [new[parents[j]] if parents[j] >= 0 else -1 for j in order], P[order]


def test_reordered_children_map_exactly(humanoid):
    names, parents, P, table = humanoid
    depth = [0] * len(names)
    for j, p in enumerate(parents):
        depth[j] = 0 if p < 0 else depth[p] + 1
    rng = np.random.default_rng(0)
    order = sorted(range(len(names)), key=lambda j: (depth[j], rng.random()))  # siblings shuffled
    n2, p2, P2 = _reindex(names, parents, P, order)
    assert n2 != names
    assert _names_map(n2, map_skeleton(n2, p2, P2)) == table


def _add(names, parents, P, name, parent, position):
    names.append(name)
    parents.append(-1 if parent is None else names.index(parent))
    P = np.vstack([P, position])
    return P


def test_extra_twist_ik_and_helper_bones_do_not_change_the_map(humanoid):
    names, parents, P, table = list(humanoid[0]), list(humanoid[1]), humanoid[2].copy(), humanoid[3]
    at = {n: P[k] for k, n in enumerate(names)}
    for side in "LR":
        P = _add(names, parents, P, f"upper_arm_twist.{side}", f"upper_arm.{side}",
                 (at[f"upper_arm.{side}"] + at[f"lower_arm.{side}"]) / 2)
        P = _add(names, parents, P, f"thigh_twist.{side}", f"upper_leg.{side}",
                 (at[f"upper_leg.{side}"] + at[f"lower_leg.{side}"]) / 2)
        P = _add(names, parents, P, f"ik_foot.{side}", "root", at[f"foot.{side}"])  # IK targets under the root
        P = _add(names, parents, P, f"ik_hand.{side}", "root", at[f"hand.{side}"])
    P = _add(names, parents, P, "prop_weapon", "hand.R", at["hand.R"] + np.array([0.0, -0.4, 0.3]))
    P = _add(names, parents, P, "skirt_helper", "hips", at["hips"] + np.array([0.0, -0.3, 0.1]))
    assert _names_map(names, map_skeleton(names, parents, P)) == table


def test_several_roots_pick_the_body_and_root_overrides(humanoid):
    names, parents, P, table = list(humanoid[0]), list(humanoid[1]), humanoid[2].copy(), humanoid[3]
    at = {n: P[k] for k, n in enumerate(names)}
    P = _add(names, parents, P, "ik_hand_root", None, np.zeros(3))  # UE-style extra roots
    for side in "LR":
        P = _add(names, parents, P, f"ik_hand.{side}", "ik_hand_root", at[f"hand.{side}"])
        P = _add(names, parents, P, f"ik_foot.{side}", "ik_hand_root", at[f"foot.{side}"])
    mapping = map_skeleton(names, parents, P)
    assert names[mapping.root] == "Armature" and _names_map(names, mapping) == table
    assert _names_map(names, map_skeleton(names, parents, P, root="Armature")) == table
    with pytest.raises(RigMappingError, match="no humanoid"):
        map_skeleton(names, parents, P, root="ik_hand_root")
    with pytest.raises(RigMappingError, match="not a joint"):
        map_skeleton(names, parents, P, root="nope")
    rig = detect_rig(names, parents, P)
    assert rig.name == "auto" and rig.root == "Armature"


@pytest.mark.parametrize("scale", [0.01, 100.0, 2.54])
def test_scaled_armatures_map_exactly(humanoid, scale):
    names, parents, P, table = humanoid
    z_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # and turned z-up
    assert _names_map(names, map_skeleton(names, parents, scale * P @ z_up.T)) == table


def test_prefixless_mixamo_names_choose_the_mixamo_preset_not_cmu(tmp_path):
    """A Ready Player Me / prefix-less Mixamo rig used to be detected as 'cmu' (spine1 and neck unmapped)."""
    from workflows.examples_gen import write_mixamo_character

    sk = read_skeleton(write_mixamo_character(tmp_path / "rpm.bvh", prefix=""))
    rig = detect_rig(sk.names, sk.parents, sk.positions)
    assert rig.name == "mixamo"
    char = read_character(tmp_path / "rpm.bvh")
    assert char.rig.name == "mixamo" and len(char.smpl_joints) == 24
    assert char.joint_map["spine1"] == "Spine" and char.joint_map["neck"] == "Neck"


def test_a_non_humanoid_is_refused_in_one_line():
    names = ["root", "spine", "neck", "head", "tail"] + [f"leg{k}_{s}" for k in range(4) for s in ("a", "b")]
    parents = [-1, 0, 1, 2, 0, 0, 5, 1, 7, 0, 9, 1, 11]
    P = np.array([[0, 1, 0], [0, 1, 1], [0, 1.2, 1.5], [0, 1.3, 1.8], [0, 1, -1],
                  [0.2, 0.5, 0], [0.2, 0, 0], [0.2, 0.5, 1], [0.2, 0, 1],
                  [-0.2, 0.5, 0], [-0.2, 0, 0], [-0.2, 0.5, 1], [-0.2, 0, 1]], dtype=float)  # a quadruped
    with pytest.raises(RigMappingError) as err:
        map_skeleton(names, parents, P)
    assert "\n" not in str(err.value) and "no humanoid" in str(err.value)


# ----------------------------------------------------------------------------- shared real data


def test_cmu_bvh_maps_exactly_as_the_cmu_preset(shared_data):
    from shape_inversion.rigs import load_preset

    sk = read_skeleton(shared_data.cmu("01_01.bvh"))
    got = _names_map(sk.names, map_skeleton(sk.names, sk.parents, sk.positions))
    assert got == dict(load_preset("cmu").joints)


def test_cmu_dance_daz_skeleton_maps_by_topology(shared_data):
    sk = read_skeleton(shared_data.file("data/cmu-dance/salsa_01.bvh"), rest="offsets")
    got = _names_map(sk.names, map_skeleton(sk.names, sk.parents, sk.positions))
    sided = {"hip": "Thigh", "knee": "Shin", "ankle": "Foot", "collar": "Collar", "shoulder": "Shldr",
             "elbow": "ForeArm", "wrist": "Hand", "hand": "Mid1"}
    expected = {"pelvis": "hip", "spine1": "abdomen", "spine3": "chest", "neck": "neck", "head": "head"}
    expected |= {f"{side}_{role}": f"{side[0]}{part}" for side in ("left", "right") for role, part in sided.items()}
    assert got == expected


# ----------------------------------------------------------------------------- rest pose and fit quality


def test_bvh_whose_frame0_is_motion_uses_the_offsets_and_says_so(tmp_path):
    """A clip starting mid-motion (knees and elbows bent in frame 0): ``rest=auto`` takes the OFFSET pose."""
    from shape_inversion.options import CharacterOptions
    from smplik.data.bvh import read_bvh as parse
    from workflows.examples_gen import write_mixamo_character

    src = write_mixamo_character(tmp_path / "t.bvh")
    motion = parse(src)
    text = src.read_text()
    head, _, _ = text.partition("MOTION")
    values = np.zeros(sum(len(c) for c in motion.channels))
    col = 0
    for name, chans in zip(motion.joint_names, motion.channels, strict=True):
        for c in chans:
            if (name.endswith("Leg") and not name.endswith("UpLeg") and c == "Xrotation") or \
                    (name.endswith("ForeArm") and c == "Yrotation"):
                values[col] = 70.0
            col += 1
    bent = tmp_path / "bent.bvh"
    bent.write_text(head + "MOTION\nFrames: 1\nFrame Time: 0.0333333\n" + " ".join(f"{v:g}" for v in values) + "\n")
    char = read_character(bent)  # rest="auto" by default
    assert char.skeleton.rest.startswith("offsets (frame 0 is not a rest pose")
    assert any(line.startswith("rest pose: offsets") for line in char.map_report())
    as_frame0 = read_character(bent, CharacterOptions(rest="frame0"))
    assert as_frame0.skeleton.rest == "frame0"
    np.testing.assert_allclose(char.features, read_character(src).features, atol=1e-9)  # the OFFSET skeleton
    assert not np.allclose(as_frame0.features, char.features, atol=1e-3)


def test_a_weak_inversion_is_reported(bodies):
    from shape_inversion.bank import BankConfig
    from shape_inversion.estimator import ShapeEstimator

    sk = read_character(BLOCKS)  # a block figure: limbs far from human proportions
    est = ShapeEstimator.build(bodies["neutral"], BankConfig(num_samples=4000))
    with pytest.warns(UserWarning, match="weak shape inversion"):
        estimate = est.estimate(sk.features)
    assert any("weak shape inversion" in w for w in estimate.warnings)


def test_3ds_max_biped_names_with_spaces_parse_and_map(humanoid, tmp_path):
    """3ds Max writes ``JOINT Bip01 L Thigh``: the BVH reader keeps the whole name, the mapper maps it."""
    from smplik.data.bvh import format_bvh
    from smplik.data.bvh import read_bvh as parse

    names, parents, P, table = humanoid
    renamed = _rename(names, "Bip01")
    offsets = np.array([P[k] if p < 0 else P[k] - P[p] for k, p in enumerate(parents)]) * 100.0
    channels = [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation") if p < 0
                else ("Zrotation", "Xrotation", "Yrotation") for p in parents]
    values = np.zeros((1, sum(len(c) for c in channels)))
    path = tmp_path / "biped.bvh"
    path.write_text(format_bvh(renamed, parents, offsets, channels, values, 1 / 30))
    motion = parse(path)
    assert "Bip01 L UpperLeg" in motion.joint_names
    char = read_character(path)
    assert char.joint_map == _expected(table, names, renamed) and char.units_m == pytest.approx(0.01)


def test_a_gltf_without_skin_or_humanoid_table_is_read_from_its_node_tree(tmp_path):
    """An animation-only glTF (Mixamo clips exported by Blender: no skin, no mesh) is its largest node tree."""
    import pygltflib

    g = pygltflib.GLTF2.load_binary(str(HUMANOID))
    table = read_skeleton(HUMANOID).humanoid
    g.extensions, g.extensionsUsed = {}, []  # the VRM table removed: a plain glTF of nodes
    path = tmp_path / "plain.glb"
    g.save_binary(str(path))
    char = read_character(path)
    assert char.skeleton.humanoid is None and char.rig.name == "auto"
    assert char.joint_map == table  # mapped by topology to exactly the avatar's own table


def test_several_roots_keep_the_body_hierarchy_for_retargeting(tmp_path):
    """UE-style extra roots (IK targets) no longer stop ``--character``: the body's hierarchy is kept and named."""
    import json

    from shape_inversion.bank import BankConfig
    from shape_inversion.estimator import ShapeEstimator
    from smplik.body_model import load_body_model
    from smplik.conventions import JOINT_NAMES
    from workflows.character import build_character
    from workflows.layout_examples import smpl_rest

    J = smpl_rest()[0]
    joints = {n: J[k].tolist() for k, n in enumerate(JOINT_NAMES)}
    joints |= {"ik_hand_l": J[JOINT_NAMES.index("left_wrist")].tolist(), "ik_foot_r": [0.1, 0.0, 0.1]}
    path = tmp_path / "roots.json"
    path.write_text(json.dumps({"units": "m", "joints": joints}))  # the two IK joints are roots of their own
    char = read_character(path)
    assert char.rig.root == "pelvis" and len(char.skeleton.names) == 24 and "ik_hand_l" not in char.skeleton.names
    estimate = ShapeEstimator.build(load_body_model("neutral"), BankConfig(num_samples=2000)).estimate(char.features)
    custom = build_character(char.skeleton, estimate, rig=char.rig)
    assert custom.parents[0] == -1 and sum(p < 0 for p in custom.parents) == 1
    assert any("hierarchy of root joint 'pelvis'" in line for line in char.map_report())


# ----------------------------------------------------------------------------- glTF ancestor transforms


def _wrapped_gltf(src: Path, out: Path, *, scale: float, z_up: bool, skin: str | None) -> Path:
    """``src`` re-exported as Blender/Mixamo do: the scene's roots under one armature node with ``scale``
    (bones then in 1/scale units, e.g. centimetres under 0.01) and, with ``z_up``, a rotation taking the
    armature's z-up axes to glTF's y-up (the content below it is z-up). Every node keeps its world position.

    ``skin``: None (unskinned nodes, as the source), ``"world"`` (a skin over the skeleton whose inverse bind
    matrices are in world space, as the glTF spec and Blender's exporter write them) or ``"armature"``
    (relative to the armature node: FBX2glTF-style files whose bind space is the armature's cm, z-up frame).
    """
    import pygltflib
    from scipy.spatial.transform import Rotation

    from shape_inversion.gltf_io import load_gltf

    g = pygltflib.GLTF2.load_binary(str(src))
    R = Rotation.from_euler("x", -90, degrees=True) if z_up else Rotation.identity()  # z-up -> y-up
    for node in g.nodes:
        if node.translation is not None:
            node.translation = [float(x) / scale for x in node.translation]
    roots = list(g.scenes[g.scene].nodes)
    for r in roots:  # the content below the armature is expressed in its z-up frame
        node = g.nodes[r]
        q = Rotation.from_quat(node.rotation) if node.rotation is not None else Rotation.identity()
        node.rotation = list((R.inv() * q).as_quat())
        node.translation = list(R.inv().apply(node.translation or [0.0, 0.0, 0.0]))
    g.nodes.append(pygltflib.Node(name="Armature.001", children=roots, rotation=list(R.as_quat()),
                                  scale=[scale] * 3))
    g.scenes[g.scene].nodes = [len(g.nodes) - 1]
    g.save_binary(str(out))
    if skin is None and g.skins:  # the source's own skin: its IBMs follow the bones into 1/scale units
        doc = load_gltf(out)
        for sk in g.skins:
            acc = g.accessors[sk.inverseBindMatrices]
            view = g.bufferViews[acc.bufferView]
            ibm = doc.accessor(sk.inverseBindMatrices)
            ibm[:, :3, :] /= scale  # IBM' = S(1/scale) IBM: the same mesh under joints scaled by `scale`
            data = ibm.transpose(0, 2, 1).astype(np.float32).tobytes()
            blob = bytearray(g.binary_blob())
            start = (view.byteOffset or 0) + (acc.byteOffset or 0)
            assert view.byteStride in (None, 64) and len(data) == 64 * acc.count
            blob[start:start + len(data)] = data
            g.set_binary_blob(bytes(blob))
        g.save_binary(str(out))
    if skin is None:
        return out
    doc = load_gltf(out)
    top = next(n for n in range(len(g.nodes)) if g.nodes[n].name in ("root", "Hips"))  # the first bone
    joints, stack = [], [top]
    while stack:
        n = stack.pop()
        joints.append(n)
        stack.extend(g.nodes[n].children or [])
    ibm = np.linalg.inv(doc.world[joints])  # world space
    if skin == "armature":
        ibm = ibm @ doc.world[len(g.nodes) - 1]  # relative to the armature node (bind space = its frame)
    blob = bytearray(g.binary_blob())
    while len(blob) % 4:
        blob.append(0)
    data = ibm.transpose(0, 2, 1).astype(np.float32).tobytes()  # glTF matrices are column-major
    g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
    blob.extend(data)
    g.accessors.append(pygltflib.Accessor(bufferView=len(g.bufferViews) - 1, componentType=5126, count=len(joints),
                                          type="MAT4"))
    g.buffers[0].byteLength = len(blob)
    g.set_binary_blob(bytes(blob))
    g.skins = [pygltflib.Skin(joints=joints, inverseBindMatrices=len(g.accessors) - 1, skeleton=top)]
    g.save_binary(str(out))
    return out


@pytest.fixture(scope="module")
def small_estimator(bodies):
    from shape_inversion.bank import BankConfig
    from shape_inversion.estimator import ShapeEstimator

    return ShapeEstimator.build(bodies["neutral"], BankConfig(num_samples=2000))


def _exported_joint_world(path: Path, estimator, out: Path) -> dict[str, np.ndarray]:
    """The example reach pose retargeted onto the character and exported as GLB: joint name -> world position."""
    import dataclasses
    import warnings

    from shape_inversion.gltf_io import load_gltf
    from workflows.character import build_character, smpl_to_custom
    from workflows.examples_gen import example_poses
    from workflows.scene.export import posed_character_glb

    char = read_character(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the block figure is a weak inversion (tested elsewhere)
        cc = build_character(char.skeleton, estimator.estimate(char.features), rig=char.rig)
    pose = dataclasses.replace(example_poses()[1].pose, betas=cc.betas, gender=cc.gender)
    out.write_bytes(posed_character_glb(cc, [smpl_to_custom(pose, cc)]))
    doc = load_gltf(out)
    return {doc.gltf.nodes[n].name: doc.world[n, :3, 3] for n in cc.skeleton.gltf.joint_nodes}


@pytest.mark.parametrize("skin", [None, "world", "armature"])
@pytest.mark.parametrize("z_up", [False, True], ids=["scale0.01", "scale0.01+z-up"])
@pytest.mark.parametrize("path", [HUMANOID, BLOCKS], ids=lambda p: p.stem[:12])
def test_an_armature_scaled_and_turned_inverts_like_the_unwrapped_file(tmp_path, small_estimator, path, z_up, skin):
    """Mixamo/Blender exports: the skeleton under an armature node scaled 0.01 (bones in cm), maybe z-up.

    Same map, same stature, same SMPL-SI scale as the unwrapped file; the exported GLB (scene world frame)
    puts every joint where the unwrapped file's export does.
    """
    import warnings

    wrapped = _wrapped_gltf(path, tmp_path / "wrapped.glb", scale=0.01, z_up=z_up, skin=skin)
    a, b = read_character(path), read_character(wrapped)
    assert b.rig.name == "vrm" and b.joint_map == a.joint_map
    assert (b.skeleton.gltf.skin == 0) == (skin is not None)
    sk = b.skeleton
    mapping = map_skeleton(sk.names, sk.parents, sk.positions)  # the mapper alone, the table ignored
    assert _names_map(sk.names, mapping) == sk.humanoid
    assert b.units_m == a.units_m == 1.0
    assert b.head_ankle_height_m == pytest.approx(a.head_ankle_height_m, rel=1e-5)
    np.testing.assert_allclose(b.features, a.features, atol=1e-5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scale_a, scale_b = small_estimator.estimate(a.features).scale, small_estimator.estimate(b.features).scale
    assert scale_b == pytest.approx(scale_a, rel=1e-4)
    if skin == "armature":
        want = _exported_joint_world(path, small_estimator, tmp_path / "a.glb")
        got = _exported_joint_world(wrapped, small_estimator, tmp_path / "b.glb")
        assert set(a.joint_map.values()) <= set(want) & set(got)  # the unskinned file also poses 'Armature'
        for name in set(want) & set(got):
            np.testing.assert_allclose(got[name], want[name], atol=1e-5, err_msg=name)


# ----------------------------------------------------------------------------- doubts name the joints


def _insert(names, parents, P, name, parent, child, at):
    """A joint ``name`` at ``at`` between ``parent`` and its child ``child`` (appended: children may come first)."""
    names, parents = list(names), list(parents)
    names.append(name)
    parents.append(names.index(parent))
    parents[names.index(child)] = len(names) - 1
    return names, parents, np.vstack([P, at])


def test_an_arm_without_collar_maps_with_a_warning_naming_the_joints(humanoid):
    names, parents, P, table = list(humanoid[0]), list(humanoid[1]), humanoid[2], humanoid[3]
    parents[names.index("upper_arm.L")] = names.index("chest")  # shoulder.L removed from the chain
    names[names.index("shoulder.L")] = "unused_helper"
    parents[names.index("unused_helper")] = names.index("hips")
    P = P.copy()
    P[names.index("unused_helper")] = P[names.index("hips")] + np.array([0.0, -0.2, 0.05])  # a skirt-like helper
    mapping = map_skeleton(names, parents, P)
    assert _names_map(names, mapping) == {s: n for s, n in table.items() if s != "left_collar"}
    assert ("the left arm has no joint between the spine 'chest' (spine3) and the shoulder 'upper_arm.L' "
            "(left_shoulder): left_collar unmapped") in mapping.warnings


def test_extra_spine_and_neck_joints_left_unmapped_are_warned_by_name(humanoid):
    names, parents, P, table = humanoid
    at = {n: P[k] for k, n in enumerate(names)}
    step = (at["chest"] - at["spine"]) / 3
    n2, p2, P2 = _insert(names, parents, P, "spine.001", "spine", "chest", at["spine"] + step)
    n2, p2, P2 = _insert(n2, p2, P2, "spine.002", "spine.001", "chest", at["spine"] + 2 * step)
    n2, p2, P2 = _insert(n2, p2, P2, "neck.001", "neck", "head", (at["neck"] + at["head"]) / 2)
    mapping = map_skeleton(n2, p2, P2)
    got = _names_map(n2, mapping)
    assert {s: got[s] for s in got if not s.startswith("spine") and s != "neck"} == \
        {s: n for s, n in table.items() if not s.startswith("spine") and s != "neck"}
    assert got["spine1"] == "spine" and got["spine3"] == "chest" and got["spine2"] in ("spine.001", "spine.002")
    left_out = ({"spine.001", "spine.002"} - {got["spine2"]}).pop()
    assert (f"spine joint(s) {left_out!r} left unmapped on the spine 'hips' (pelvis) -> 'chest' (spine3)"
            in mapping.warnings)
    neck_left_out = ({"neck", "neck.001"} - {got["neck"]}).pop()
    assert (f"neck joint(s) {neck_left_out!r} left unmapped between 'chest' (spine3) and 'head' (head)"
            in mapping.warnings)
    assert not any("too short" in w for w in mapping.warnings)  # spine2 is mapped now


def test_a_preset_map_leaving_a_spine_joint_out_is_warned(tmp_path):
    """A preset (or a humanoid table) that skips a joint of the rig's spine gets the same doubt."""
    from workflows.examples_gen import write_mixamo_character

    sk = read_skeleton(write_mixamo_character(tmp_path / "m.bvh"))
    names, parents, P = list(sk.names), list(sk.parents), sk.positions
    i_spine2, i_neck = names.index("mixamorig:Spine2"), names.index("mixamorig:Neck")
    names, parents, P = _insert(names, parents, P, "mixamorig:Spine3", "mixamorig:Spine2", "mixamorig:Neck",
                                (P[i_spine2] + P[i_neck]) / 2)
    rig = detect_rig(names, parents, P)
    assert rig.name == "mixamo"
    assert ("neck joint(s) 'mixamorig:Spine3' left unmapped between 'mixamorig:Spine2' (spine3) and "
            "'mixamorig:Head' (head)") in rig.warnings


# ----------------------------------------------------------------------------- Khronos samples (real glTF files)

RIGGED_FIGURE = RIGS / "RiggedFigure.glb"
FOX = RIGS / "Fox.glb"


def test_collada2gltf_figure_with_numbered_names_under_a_z_up_node_maps_exactly():
    """Cesium's RiggedFigure: names say no role (``leg_joint_L_5``), the skin sits under a ``Z_UP`` node; the
    short last leg bone (``leg_joint_L_3`` -> ``_5``, down to the sole) is the foot, not the shin."""
    char = read_character(RIGGED_FIGURE)
    sided = {"hip": "leg_joint_{}_1", "knee": "leg_joint_{}_2", "ankle": "leg_joint_{}_3", "foot": "leg_joint_{}_5",
             "shoulder": "arm_joint_{}_1", "elbow": "arm_joint_{}_2", "wrist": "arm_joint_{}_3"}
    expected = {"pelvis": "torso_joint_1", "spine1": "torso_joint_2", "spine3": "torso_joint_3",
                "neck": "neck_joint_1", "head": "neck_joint_2"}
    expected |= {f"{side}_{role}": name.format(side[0].upper()) for side in ("left", "right")
                 for role, name in sided.items()}
    assert char.rig.name == "auto" and char.joint_map == {s: expected[s] for s in char.joint_map}
    assert set(char.joint_map) == set(expected)
    assert char.up == "y" and char.units_m == 1.0 and 1.2 < char.head_ankle_height_m / 0.84 < 1.6
    warnings = "\n".join(char.rig.warnings)
    assert "'arm_joint_L_1' (left_shoulder): left_collar unmapped" in warnings
    assert "'leg_joint_L_3' (left_ankle)" not in warnings  # the foot is there


def test_collada2gltf_figure_wrapped_again_under_an_armature_scaled_0_01_maps_the_same(tmp_path):
    wrapped = _wrapped_gltf(RIGGED_FIGURE, tmp_path / "wrapped.glb", scale=0.01, z_up=True, skin=None)
    a, b = read_character(RIGGED_FIGURE), read_character(wrapped)
    assert b.joint_map == a.joint_map and b.units_m == a.units_m
    np.testing.assert_allclose(b.features, a.features, atol=1e-5)


def test_a_real_quadruped_is_refused_in_one_line():
    """The Khronos Fox (front legs named UpperArm/ForeArm/Hand, a tail): no humanoid, one line."""
    from shape_inversion.rigs import RigError

    with pytest.raises(RigError) as err:
        read_character(FOX)
    assert "\n" not in str(err.value) and "no humanoid found" in str(err.value)


def test_ik_driven_feet_hanging_on_the_root_map_with_a_warning(humanoid):
    """Game rigs (bevy_make_human's main_skeleton.glb, Blender export): the leg chain ends at the shin and the
    foot bones hang on the root, driven by IK; each foot is read as its shin's child, with a warning."""
    names, parents, P, table = list(humanoid[0]), list(humanoid[1]), humanoid[2], humanoid[3]
    for side in "LR":
        parents[names.index(f"foot.{side}")] = names.index("root")
    mapping = map_skeleton(names, parents, P)
    assert _names_map(names, mapping) == table
    assert ("the ankle 'foot.L' hangs on 'root', not on the shin 'lower_leg.L' (an IK-driven foot): mapped as the "
            "shin's child for the shape; retargeted poses leave it where the IK puts it") in mapping.warnings
    assert parents[names.index("foot.L")] == names.index("root")  # the caller's hierarchy is untouched


def _ready_player_me_half_body() -> tuple[list[str], list[int], np.ndarray]:
    """The skeleton of a Ready Player Me half-body (VR) avatar GLB (``asset.generator: "Ready Player Me"``), as its
    38 joints read: Hips, Spine, Neck, Head, the eyes, and the hands hanging on the Spine with five 3-joint fingers;
    no legs, no arm bones (positions in metres, rounded)."""
    names = ["Hips", "Spine", "Neck", "Head", "LeftEye", "RightEye"]
    parents = [-1, 0, 1, 2, 3, 3]
    P = [[0, 0, 0], [0, 0.33, 0], [0, 0.473, 0], [0, 0.564, 0], [0.03, 0.646, 0.055], [-0.03, 0.646, 0.055]]
    fingers = {"Index": (0.741, 0.773, 0.795, 0.03), "Middle": (0.747, 0.78, 0.803, 0.009),
               "Ring": (0.744, 0.772, 0.795, -0.01), "Pinky": (0.735, 0.766, 0.783, -0.03),
               "Thumb": (0.677, 0.703, 0.727, 0.05)}
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        names.append(f"{side}Hand")
        parents.append(1)
        P.append([sign * 0.658, 0.33, 0.0])
        for finger, (*xs, z) in fingers.items():
            for k, x in enumerate(xs):
                names.append(f"{side}Hand{finger}{k + 1}")
                parents.append(names.index(f"{side}Hand") if k == 0 else len(names) - 2)
                P.append([sign * x, 0.33 - 0.011 * k, z])
    return names, parents, np.array(P, dtype=float)


def test_a_half_body_avatar_is_refused_not_read_with_fingers_as_legs():
    """Ready Player Me half-body avatars have no legs: two fingers of one hand must not pass for two legs."""
    names, parents, P = _ready_player_me_half_body()
    with pytest.raises(RigMappingError) as err:
        map_skeleton(names, parents, P)
    assert "no humanoid found" in str(err.value) and "\n" not in str(err.value)


def test_a_univrm_vrm0_avatar_with_spaced_names_maps_like_its_table():
    """A real VRM 0.x export of UniVRM (Unity): a skin of 57 joints named ``Left leg``, ``Left knee``, ..."""
    path = RIGS / "cryptovoxels.vrm"
    sk = read_skeleton(path)
    assert sk.gltf.skin == 0 and sk.humanoid["left_hip"] == "Left leg" and sk.humanoid["left_hand"] == "MiddleFinger1_L"
    char = read_character(path)
    assert char.rig.name == "vrm" and char.joint_map == sk.humanoid
    mapping = map_skeleton(sk.names, sk.parents, sk.positions)  # the table ignored
    assert _names_map(sk.names, mapping) == sk.humanoid
    assert mapping.warnings == ("the spine 'Hips' (pelvis) -> 'Chest' (spine3) is too short for SMPL's spine1, "
                                "spine2, spine3 (joints between: 'Spine' (spine1)): spine2 unmapped",)


def test_a_skin_bound_at_a_scaled_mesh_node_with_an_animated_default_pose_reads_the_bind_pose(tmp_path):
    """three.js's GLTFExporter (RobotExpressive re-exported): the IBMs are relative to the skinned mesh's node
    (scaled 100), and the default node pose is an animation frame (here the figure turned half around), so the
    nodes do not show the bind pose. The bind pose must come out at the nodes' size, not 100 x smaller."""
    import pygltflib
    from scipy.spatial.transform import Rotation

    from shape_inversion.gltf_io import load_gltf

    g = pygltflib.GLTF2.load_binary(str(RIGGED_FIGURE))
    doc = load_gltf(RIGGED_FIGURE)
    skin = g.skins[0]
    T_joint = doc.world[skin.joints]  # the true bind pose (the sample's nodes are at bind)
    mesh = next(i for i, n in enumerate(g.nodes) if n.skin == 0)
    g.nodes[mesh].scale = [100.0, 100.0, 100.0]
    M = doc.world[mesh] @ np.diag([100.0, 100.0, 100.0, 1.0])  # the mesh node's new world transform
    ibm = np.linalg.inv(T_joint) @ M  # IBMs relative to the mesh node: M inv(IBM) = T_joint
    acc = g.accessors[skin.inverseBindMatrices]
    view = g.bufferViews[acc.bufferView]
    blob = bytearray(g.binary_blob())
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    data = ibm.transpose(0, 2, 1).astype(np.float32).tobytes()
    blob[start:start + len(data)] = data
    g.set_binary_blob(bytes(blob))
    root = g.nodes[skin.skeleton]  # the default pose: an animation frame, the figure turned around
    root.rotation = list((Rotation.from_euler("z", 180, degrees=True) * Rotation.from_quat(root.rotation)).as_quat())
    path = tmp_path / "threejs_export.glb"
    g.save_binary(str(path))
    a, b = read_character(RIGGED_FIGURE), read_character(path)
    assert b.joint_map == a.joint_map and b.units_m == a.units_m == 1.0
    np.testing.assert_allclose(b.skeleton.positions, a.skeleton.positions, atol=1e-4)
    np.testing.assert_allclose(b.features, a.features, atol=1e-5)
