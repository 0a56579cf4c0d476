"""Bounded, seeded mutation fuzzing of the character readers (BVH, joints JSON, glTF/GLB, .gltf + .bin).

Contract: a mutated file either reads (and maps, or is refused by the rig mapper with RigError) or
raises the project's :class:`SkeletonError` with a one-line message; never another exception.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from shape_inversion.rigs import RigError
from shape_inversion.skeleton_io import SkeletonError, prepare_character, read_skeleton
from workflows.layout_examples import smpl_rest, write_cmu_bvh, write_mixamo_bvh, write_mixamo_gltf, write_plain_json

TOKENS = [b"nan", b"inf", b"-1", b"0", b"1e308", b"1e-320", b"{", b"}", b"CHANNELS 7", b"JOINT", b"ROOT X",
          b"End Site", b"OFFSET", b"Frames: 99999999", b"Frame Time: 0", b"[/red]", b"\x00", b"\xff\xfe"]


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(0, 5))
        i = int(rng.integers(0, max(len(b), 1)))
        n = int(rng.integers(1, 64))
        if op == 0:
            del b[i:i + n]
        elif op == 1:
            b[i:i] = b[i:i + n]
        elif op == 2:
            b[i:i] = TOKENS[int(rng.integers(len(TOKENS)))]
        elif op == 3 and b:
            b[i % len(b)] = int(rng.integers(0, 256))
        else:
            b = b[: i]
    return bytes(b)


def _check(path) -> str:
    try:
        sk = read_skeleton(path, max_joints=500)
    except SkeletonError as exc:
        msg = str(exc)
        assert msg and "\n" not in msg, msg
        return "refused"
    try:
        prepare_character(sk)
    except (SkeletonError, RigError) as exc:
        assert "\n" not in str(exc)
        return "refused"
    return "ok"


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    J = smpl_rest()[0]
    d = tmp_path_factory.mktemp("seeds")
    return {
        "bvh": [write_mixamo_bvh(d / "m.bvh", J).read_bytes(), write_cmu_bvh(d / "c.bvh", J).read_bytes()],
        "json": [write_plain_json(d / "p.json", J).read_bytes()],
        "glb": [write_mixamo_gltf(d / "g.glb", J).read_bytes()],
        "gltf": [write_mixamo_gltf(d / "g.gltf", J, external_bin=True).read_bytes()],
        "bin": (d / "g.bin").read_bytes(),
    }


@pytest.mark.parametrize("kind,count", [("bvh", 100), ("json", 60), ("glb", 60), ("gltf", 40)])
def test_mutated_character_files_fail_cleanly(seeds, tmp_path, kind, count):
    rng = np.random.default_rng({"bvh": 1, "json": 2, "glb": 3, "gltf": 4}[kind])
    if kind == "gltf":
        (tmp_path / "g.bin").write_bytes(seeds["bin"])
    outcomes = {"ok": 0, "refused": 0}
    for k in range(count):
        base = seeds[kind][k % len(seeds[kind])]
        path = tmp_path / f"f{k}.{kind}"
        if kind == "gltf":
            path = tmp_path / f"f{k}.gltf"
            data = json.loads(base)
            data["buffers"][0]["uri"] = "g.bin"
            base = json.dumps(data).encode()
        path.write_bytes(_mutate(base, rng))
        outcomes[_check(path)] += 1
    assert outcomes["refused"] > 0  # the mutations do reach the validation


def test_structured_json_mutations(tmp_path):
    J = smpl_rest()[0]
    base = json.loads(write_plain_json(tmp_path / "p.json", J).read_text())
    bad_values = [None, "x", [], [1, 2], [1, 2, 3, 4], [float("nan")] * 3, [1e400] * 3, {"a": 1}, True, [[1], 2, 3]]
    for k, v in enumerate(bad_values):
        data = json.loads(json.dumps(base))
        data["joints"]["head"] = v
        path = tmp_path / f"j{k}.json"
        path.write_text(json.dumps(data))
        with pytest.raises(SkeletonError, match="joints.head"):
            read_skeleton(path)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(SkeletonError):
        read_skeleton(deep)
    many = tmp_path / "many.json"
    many.write_text(json.dumps({"joints": {f"j{i}": [0, 0, 0] for i in range(20_001)}}))
    with pytest.raises(SkeletonError, match="more than the limit 10000"):
        read_skeleton(many)


def test_bvh_size_and_value_limits(tmp_path):
    from smplik.data.bvh import BVHError, parse_bvh

    def siblings(n: int) -> str:
        return "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n" + "".join(
            f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n}}\n" for i in range(n)) + "}\nMOTION\nFrames: 1\n" \
            "Frame Time: 0.1\n0 0 0\n"

    with pytest.raises(BVHError, match="more than 10000 joints"):
        parse_bvh(siblings(30_000))
    assert parse_bvh(siblings(12_000), max_joints=12_001).num_joints == 12_001  # a legitimate big file: raise the cap
    chain = "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n" + "".join(
        f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n" for i in range(5000)) + "}\n" * 5001 + \
        "MOTION\nFrames: 1\nFrame Time: 0.1\n0 0 0\n"
    assert parse_bvh(chain).positions[0, -1, 1] == pytest.approx(5000.0)  # 5000-deep chain: no RecursionError
    small = write_mixamo_bvh(tmp_path / "m.bvh", smpl_rest()[0]).read_text()
    for old, new, what in (("Frame Time: 0.0333333", "Frame Time: 0", "Frame Time"),
                           ("Frame Time: 0.0333333", "Frame Time: 1e-308", "Frame Time"),
                           ("Frame Time: 0.0333333", "Frame Time: -1", "Frame Time"),
                           ("Frame Time: 0.0333333", "Frame Time: nan", "Frame Time"),
                           ("CHANNELS 6 Xposition", "CHANNELS 2 Xposition", "CHANNELS declares 2"),
                           ("JOINT mixamorig:Spine1", "JOINT mixamorig:Spine", "duplicate joint name"),
                           ("ROOT", "JOINT", "expected 'ROOT'")):
        with pytest.raises(BVHError, match=what):
            parse_bvh(small.replace(old, new, 1))
    rows = small.split("Frame Time: 0.0333333\n")
    with pytest.raises(BVHError, match="non-finite"):
        parse_bvh(rows[0] + "Frame Time: 0.0333333\n" + "nan " + rows[1].split(" ", 1)[1])
    with pytest.raises(BVHError, match="OFFSET of joint 'mixamorig:Hips' holds a non-finite"):
        parse_bvh(re.sub(r"OFFSET \S+", "OFFSET nan", small, count=1))
