"""meshopt-compressed glTF (``EXT_meshopt_compression`` / ``KHR_meshopt_compression``) read with no options.

The fixtures are real gltfpack 1.3 and glTF-Transform 4.5.1 outputs of the Khronos RiggedFigure, and the expected
decoded bytes come from meshoptimizer's own decoder (``tests/data/meshopt/README.md``).
"""

from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

DATA = Path(__file__).resolve().parent / "data"
MESHOPT = DATA / "meshopt"
ORIGINAL = DATA / "rigs" / "RiggedFigure.glb"
FIXTURES = sorted(f for f in MESHOPT.glob("RiggedFigure_*.glb") if "draco" not in f.name)  # the meshopt ones


def _glb_json_and_bin(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + n])
    m = struct.unpack_from("<I", data, 20 + n)[0]
    return doc, data[28 + n:28 + n + m]


def test_the_fixtures_are_compressed_files_that_require_the_extension():
    assert len(FIXTURES) == 3
    for f in FIXTURES:
        doc, _ = _glb_json_and_bin(f)
        (ext,) = [e for e in doc["extensionsRequired"] if "meshopt" in e]
        assert any("uri" not in b and b.get("extensions", {}).get(ext, {}).get("fallback") for b in doc["buffers"])
        assert sum(ext in (v.get("extensions") or {}) for v in doc["bufferViews"]) >= 5


def test_every_codec_vector_decodes_to_meshoptimizers_own_output():
    from shape_inversion.meshopt_codec import decode_gltf_buffer

    vectors = json.loads((MESHOPT / "codec_vectors.json").read_text())["vectors"]
    seen = set()
    for v in vectors:
        out = decode_gltf_buffer(bytes.fromhex(v["compressed"]), v["count"], v["byteStride"], v["mode"], v["filter"])
        assert len(out) == v["count"] * v["byteStride"]
        assert hashlib.sha256(out).hexdigest() == v["decoded_sha256"], v["name"]
        seen.add((v["mode"], v["filter"], v["compressed"][:2]))
    assert {m for m, _, _ in seen} == {"ATTRIBUTES", "TRIANGLES", "INDICES"}
    assert {f for _, f, _ in seen} == {"NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL", "COLOR"}
    assert {"a0", "a1"} <= {h for _, _, h in seen}  # both attribute codec versions


def test_every_compressed_view_of_the_real_files_decodes_to_meshoptimizers_own_output():
    from shape_inversion.meshopt_codec import decode_gltf_buffer

    reference = json.loads((MESHOPT / "reference_views.json").read_text())
    for f in FIXTURES:
        doc, blob = _glb_json_and_bin(f)
        done = 0
        for i, view in enumerate(doc["bufferViews"]):
            ext = (view.get("extensions") or {})
            spec = ext.get("EXT_meshopt_compression") or ext.get("KHR_meshopt_compression")
            if spec is None:
                continue
            start = spec.get("byteOffset", 0)
            out = decode_gltf_buffer(blob[start:start + spec["byteLength"]], spec["count"], spec["byteStride"],
                                     spec["mode"], spec.get("filter", "NONE"))
            assert hashlib.sha256(out).hexdigest() == reference[f.name][str(i)], (f.name, i)
            done += 1
        assert done == len(reference[f.name])


def _mesh(path: Path):
    from shape_inversion.gltf_io import load_gltf, read_rig
    from workflows.character_mesh import skinned_mesh

    rig = read_rig(load_gltf(path))
    return rig, skinned_mesh(rig)


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.stem)
def test_decoded_mesh_and_skin_equal_the_uncompressed_originals(path):
    """Vertices (world, after the quantization the tools add), triangles and skin weights of the compressed file
    equal the original's within the tools' quantization (positions 14-16 bits of a 1.45 m figure, weights 8 bits);
    the tools reorder and weld vertices, so vertices are matched by position."""
    rig0, mesh0 = _mesh(ORIGINAL)
    rig, mesh = _mesh(path)
    assert rig.joint_nodes and len(rig.joint_nodes) == len(rig0.joint_nodes)
    names0 = [rig0.doc.gltf.nodes[n].name for n in rig0.joint_nodes]
    names = [rig.doc.gltf.nodes[n].name for n in rig.joint_nodes]
    assert names == names0
    np.testing.assert_allclose(rig.T_world_joint_bind[:, :3, 3], rig0.T_world_joint_bind[:, :3, 3], atol=1e-5)
    height = np.ptp(mesh0.vertices_world[:, 1])
    assert 1.0 < height < 2.0
    tol = 2e-4 * height
    dist, near = cKDTree(mesh0.vertices_world).query(mesh.vertices_world)
    assert dist.max() < tol  # every decoded vertex is an original vertex
    assert cKDTree(mesh.vertices_world).query(mesh0.vertices_world)[0].max() < tol  # and none is lost
    assert len(mesh.faces) == len(mesh0.faces)
    c0 = np.sort(mesh0.vertices_world[mesh0.faces].mean(1), axis=0)
    centroids = mesh.vertices_world[mesh.faces].mean(1)
    assert cKDTree(centroids).query(mesh0.vertices_world[mesh0.faces].mean(1))[0].max() < tol
    assert c0.shape == centroids.shape

    def dense(m, k):
        w = np.zeros((len(m.joints), len(rig0.joint_nodes)))
        np.add.at(w, (np.arange(len(m.joints))[:, None], m.joints), m.weights)
        return w[k] if k is not None else w

    np.testing.assert_allclose(dense(mesh, None), dense(mesh0, near), atol=0.01)


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.stem)
def test_a_compressed_character_reads_as_its_original(path):
    from shape_inversion.skeleton_io import read_character

    plain, packed = read_character(ORIGINAL), read_character(path)
    assert packed.joint_map == plain.joint_map
    np.testing.assert_allclose(packed.positions, plain.positions, atol=1e-5)


def test_invert_shape_reads_a_gltf_transform_file_with_no_options(tmp_path):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    runner = CliRunner()
    out = {}
    for name, f in (("plain", ORIGINAL), ("packed", MESHOPT / "RiggedFigure_gltf_transform.glb")):
        res = runner.invoke(app, ["invert-shape", str(f), "--out", str(tmp_path / f"{name}.json")])
        assert res.exit_code == 0, res.output
        assert "Traceback" not in res.output
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    assert out["packed"]["scale"] == pytest.approx(out["plain"]["scale"], rel=1e-4)
    np.testing.assert_allclose(out["packed"]["betas"], out["plain"]["betas"], atol=1e-3)


def _corrupt(src: Path, dst: Path, how: str) -> Path:
    """``src`` with its first compressed view's stream damaged: its header byte, or its length cut short."""
    data = bytearray(src.read_bytes())
    doc, _ = _glb_json_and_bin(src)
    n = struct.unpack_from("<I", data, 12)[0]
    view = next(v for v in doc["bufferViews"] if "EXT_meshopt_compression" in (v.get("extensions") or {}))
    spec = view["extensions"]["EXT_meshopt_compression"]
    if how == "header":
        data[28 + n + spec.get("byteOffset", 0)] = 0x55
    else:
        spec["byteLength"] //= 2
        text = json.dumps(doc).encode()
        text += b" " * (-len(text) % 4)
        data = bytearray(data[:12]) + struct.pack("<I", len(text)) + b"JSON" + text + data[20 + n:]
        struct.pack_into("<I", data, 8, len(data))
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("how", ["header", "short"])
def test_a_damaged_stream_is_refused_in_one_line_naming_the_view(tmp_path, how):
    from typer.testing import CliRunner

    from smplik.cli.main import app

    f = _corrupt(MESHOPT / "RiggedFigure_gltfpack_cc.glb", tmp_path / "bad.glb", how)
    res = CliRunner().invoke(app, ["invert-shape", str(f), "--out", str(tmp_path / "s.json")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    line = res.output.strip().splitlines()[-1]
    assert line.startswith("error:") and "bufferViews[" in line and "EXT_meshopt_compression" in line


def test_the_decoder_refuses_bad_arguments_and_streams_without_reading_past_them():
    from shape_inversion.meshopt_codec import MeshoptError, decode_gltf_buffer

    vectors = {v["name"]: v for v in json.loads((MESHOPT / "codec_vectors.json").read_text())["vectors"]}
    good = vectors["attributes_v1_stride12"]
    data = bytes.fromhex(good["compressed"])
    cases = [((data, 260, 12, "ATTRIBUTES", "BLUR"), "filter"), ((data, 260, 12, "POINTS"), "mode"),
             ((data, 260, 10, "ATTRIBUTES"), "byteStride"), ((data[:40], 260, 12, "ATTRIBUTES"), "stream"),
             ((data, 261, 12, "ATTRIBUTES"), "stream"), ((b"\xa2" + data[1:], 260, 12, "ATTRIBUTES"), "version"),
             ((data, 259, 12, "TRIANGLES"), "TRIANGLES"), ((data, 260, 12, "ATTRIBUTES", "QUATERNION"), "byteStride")]
    for args, word in cases:
        with pytest.raises(MeshoptError, match=word):
            decode_gltf_buffer(*args)
    tri = vectors["triangles16_v1"]
    for cut in (1, 10, len(tri["compressed"]) // 4):
        with pytest.raises(MeshoptError):
            decode_gltf_buffer(bytes.fromhex(tri["compressed"])[:-cut], tri["count"], 2, "TRIANGLES")


def test_a_draco_compressed_character_reads_its_mesh_with_dracopy():
    """glTF-Transform's ``draco`` output: the skeleton reads as the original's; with DracoPy (the ``[draco]``
    extra) the mesh decodes to the original's vertices (Draco's 11-14 bit quantization)."""
    from shape_inversion.skeleton_io import read_character

    f = MESHOPT / "RiggedFigure_draco.glb"
    assert "KHR_draco_mesh_compression" in _glb_json_and_bin(f)[0]["extensionsRequired"]
    plain, packed = read_character(ORIGINAL), read_character(f)
    assert packed.joint_map == plain.joint_map
    np.testing.assert_allclose(packed.positions, plain.positions, atol=1e-9)
    pytest.importorskip("DracoPy", reason="decoding the Draco mesh needs DracoPy (pip install -e '.[draco]')")
    _, mesh0 = _mesh(ORIGINAL)
    _, mesh = _mesh(f)
    assert len(mesh.faces) == len(mesh0.faces)
    tol = 2e-4 * np.ptp(mesh0.vertices_world[:, 1])
    assert cKDTree(mesh0.vertices_world).query(mesh.vertices_world)[0].max() < tol
    assert cKDTree(mesh.vertices_world).query(mesh0.vertices_world)[0].max() < tol


def test_scene_export_of_a_compressed_character_writes_a_plain_glb_of_its_own_mesh(tmp_path):
    """The exported GLB holds the decoded views (no meshopt extension left pointing at moved bytes) and re-reads
    as the same character: its mesh equal to the original's at the bind pose."""
    import sys

    from typer.testing import CliRunner

    sys.path.insert(0, str(Path(__file__).parent))
    from estimator_fixtures import framing, people, write_romp

    from smplik.cli.main import app

    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    w = write_romp(tmp_path, aa, transl, betas)
    runner = CliRunner()
    packed = MESHOPT / "RiggedFigure_gltf_transform.glb"
    res = runner.invoke(app, ["scene", "from-estimate", str(w.path), "--out", str(tmp_path / "scene"), "--character",
                              str(packed), "--no-previews", "--max-effectors", "2"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["scene", "export", str(tmp_path / "scene" / "scene.json"), "--out", str(tmp_path / "x"),
                              "--format", "glb"])
    assert res.exit_code == 0, res.output
    out = tmp_path / "x" / "person_0.glb"
    doc, _ = _glb_json_and_bin(out)
    assert not any("meshopt" in e for e in doc.get("extensionsUsed", []) + doc.get("extensionsRequired", []))
    assert not any("meshopt" in str(v.get("extensions")) for v in doc["bufferViews"])
    _, mesh0 = _mesh(ORIGINAL)
    _, mesh = _mesh(out)  # the exported file's bind pose, in its own (the file's) frame
    assert len(mesh.faces) == len(mesh0.faces)
    d0 = np.ptp(mesh0.vertices_world, axis=0)
    np.testing.assert_allclose(np.sort(np.ptp(mesh.vertices_world, axis=0)), np.sort(d0), rtol=2e-3)


def test_a_gltf_with_an_external_compressed_buffer_and_a_fallback_buffer_reads_as_its_original():
    """gltfpack ``-cf``: a ``.gltf`` with two external buffers (compressed data; an uncompressed fallback with a uri,
    the extension only used): the decoded views agree with the fallback's bytes."""
    from shape_inversion.gltf_io import _buffer_bytes, load_gltf
    from shape_inversion.skeleton_io import read_character

    f = MESHOPT / "gltfpack_cf" / "RiggedFigure.gltf"
    doc = json.loads(f.read_text())
    assert len(doc["buffers"]) == 2 and all("uri" in b for b in doc["buffers"])
    assert "EXT_meshopt_compression" in doc["extensionsUsed"]
    assert "EXT_meshopt_compression" not in doc.get("extensionsRequired", [])
    loaded = load_gltf(f)
    fallback = _buffer_bytes(f, loaded.gltf, 1)  # the file's own uncompressed bytes
    for view in doc["bufferViews"]:
        if view["buffer"] == 1:
            a, n = view.get("byteOffset", 0), view["byteLength"]
            mine, theirs = loaded.buffers[1][a:a + n], fallback[a:a + n]
            if view["extensions"]["EXT_meshopt_compression"]["mode"] == "TRIANGLES":
                # the index codec may start a triangle at another corner (same winding): compare rotations
                t1, t2 = (np.frombuffer(b, np.uint16).reshape(-1, 3) for b in (mine, theirs))
                canon = lambda t: np.stack([np.roll(t, -k, axis=1) for k in range(3)])[  # noqa: E731
                    np.argmin(t, axis=1), np.arange(len(t))]
                np.testing.assert_array_equal(canon(t1), canon(t2))
            else:
                assert mine == theirs
    plain, packed = read_character(ORIGINAL), read_character(f)
    assert packed.joint_map == plain.joint_map
    np.testing.assert_allclose(packed.positions, plain.positions, atol=1e-5)


def test_a_gltfpack_skin_without_a_mesh_reads_from_its_nodes_with_one_warning():
    """gltfpack quantizes a meshless skin's inverse bind matrices to zeros: the joints' default pose (here the
    bind pose) is used, said in one warning, instead of refusing the file."""
    from shape_inversion.skeleton_io import read_character

    f = MESHOPT / "sketchfab_anime_boy_skeleton_gltfpack.glb"
    plain = read_character(DATA / "rigs" / "sketchfab_anime_boy_skeleton.glb")
    with pytest.warns(UserWarning, match="singular inverse bind matrix") as caught:
        packed = read_character(f)
    assert sum("singular inverse bind" in str(w.message) for w in caught) == 1
    assert packed.joint_map == plain.joint_map
    np.testing.assert_allclose(packed.positions, plain.positions, atol=1e-5)
