"""Resource limits (:mod:`smplik.limits`): every allocation sized by a number in a file is checked first.

Each bomb is small on disk and is refused with one error naming the limit's environment variable;
raising that variable lets the same input through (so the check is the limit, not a side effect).
"""

from __future__ import annotations

import io
import os
import pickle
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from smplik.limits import INPUT_BYTES, PICKLE_OBJECTS, LimitError, check_array, check_npz, check_tensors

ROOT = Path(__file__).resolve().parents[1]


def npz_with_header(path: Path, name: str, shape: tuple, data: bytes = b"", compress: bool = False) -> Path:
    """An ``.npz`` whose member ``name`` has an ``.npy`` header declaring ``shape`` (float64) over ``data``."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as zf:
        zf.writestr(f"{name}.npy", buf.getvalue() + data)
    return path


def test_limits_read_their_environment_variable(monkeypatch):
    assert INPUT_BYTES.value == 2 << 30
    monkeypatch.setenv("SMPLIK_MAX_INPUT_BYTES", "3G")
    assert INPUT_BYTES.value == 3 << 30
    with pytest.raises(LimitError, match="SMPLIK_MAX_INPUT_BYTES to raise it"):
        INPUT_BYTES.check(4 << 30, "x.npz")
    monkeypatch.setenv("SMPLIK_MAX_INPUT_BYTES", "lots")
    with pytest.raises(LimitError, match="SMPLIK_MAX_INPUT_BYTES='lots' is not a number"):
        INPUT_BYTES.check(1, "x.npz")
    with pytest.raises(LimitError, match=r"shape \(-1, 3\)"):
        check_array((-1, 3), 8, "a")
    assert check_array((10, 3), 4, "a") == 120


def test_npz_bombs_are_refused_from_the_headers(tmp_path, monkeypatch):
    # a compressed member that inflates to 115 MB from 100 KB: over an input budget of 100 MiB (2 GiB by default)
    monkeypatch.setenv("SMPLIK_MAX_INPUT_BYTES", "100M")
    bomb = npz_with_header(tmp_path / "bomb.npz", "poses", (200_000, 72), bytes(200_000 * 72 * 8), compress=True)
    assert bomb.stat().st_size < 200_000
    with pytest.raises(LimitError, match="SMPLIK_MAX_INPUT_BYTES"):
        check_npz(bomb)
    monkeypatch.delenv("SMPLIK_MAX_INPUT_BYTES")
    # a header declaring 10**9 x 3 over 64 bytes: refused before reading
    liar = npz_with_header(tmp_path / "liar.npz", "poses", (10**9, 3), bytes(64))
    with pytest.raises(LimitError, match="SMPLIK_MAX_ARRAY_ELEMENTS"):
        check_npz(liar)
    small_liar = npz_with_header(tmp_path / "small.npz", "poses", (1000, 3), bytes(64))
    with pytest.raises(ValueError, match=r"declares shape \(1000, 3\) \(24000 bytes\) but its member holds 64"):
        check_npz(small_liar)


def test_amass_reader_checks_the_npz_before_loading(tmp_path):
    from smplik.data.amass import read_amass

    liar = npz_with_header(tmp_path / "clip_poses.npz", "poses", (10**9, 156), bytes(64))
    with pytest.raises(LimitError, match="SMPLIK_MAX_ARRAY_ELEMENTS"):
        read_amass(liar)


def test_stride_zero_tensors_count_their_full_shape(tmp_path, monkeypatch):
    import torch

    view = torch.zeros(1).expand(10**9, 8)  # 4 bytes stored, 32 GB once made contiguous
    assert view.untyped_storage().nbytes() == 4
    with pytest.raises(LimitError, match=r"tensor pred\.0: .*SMPLIK_MAX_ARRAY_ELEMENTS|tensor pred\[0\]"):
        check_tensors({"pred": [view]}, "x.pt")
    torch.save({"smpl_params_global": {"body_pose": view}}, tmp_path / "hmr4d_results.pt")
    from workflows.estimators import read_estimate

    with pytest.raises(ValueError, match=r"hmr4d_results\.pt: tensor smpl_params_global\.body_pose.*ELEMENTS"):
        read_estimate(tmp_path / "hmr4d_results.pt")
    check_tensors({"a": torch.zeros(10, 3)}, "ok.pt")
    monkeypatch.setenv("SMPLIK_MAX_INPUT_BYTES", "100")
    with pytest.raises(LimitError, match=r"ok\.pt \(all tensors\)"):
        check_tensors({"a": torch.zeros(10, 3), "b": torch.zeros(10, 3)}, "ok.pt")


def test_model_file_with_a_stride_zero_tensor_is_refused(tmp_path):
    import torch

    from smplik.model_io import read_model_file
    from smplik.solver import packaged_model_path

    state = read_model_file(packaged_model_path())
    state["metrics_tensor"] = torch.zeros(1).expand(10**9, 8)
    torch.save(state, tmp_path / "m.pt")
    with pytest.raises(LimitError, match=r"m\.pt: tensor metrics_tensor"):
        read_model_file(tmp_path / "m.pt")


def test_a_pickle_dag_counts_as_the_tree_it_expands_to():
    from smplik.safe_pickle import UnsafePickleError, check_object_graph, loads_restricted

    node: list = []
    for _ in range(28):  # 2**28 leaves once expanded, 28 lists in memory
        node = [node, node]
    data = pickle.dumps({"pred": node})
    assert len(data) < 1000
    with pytest.raises(UnsafePickleError, match="expand to more than .*SMPLIK_MAX_PICKLE_OBJECTS"):
        loads_restricted(data)
    shallow: list = []
    for _ in range(10):  # 2**11 objects: fine
        shallow = [shallow, shallow]
    assert loads_restricted(pickle.dumps(shallow)) == shallow
    cycle: list = []
    cycle.append(cycle)
    with pytest.raises(UnsafePickleError, match="cycle"):
        loads_restricted(pickle.dumps(cycle))
    deep: list = []
    for _ in range(500):
        deep = [deep]
    with pytest.raises(UnsafePickleError, match="nested deeper"):
        check_object_graph(deep)
    assert PICKLE_OBJECTS.value == 10_000_000


def test_a_pickle_dag_estimator_file_is_one_clean_error(tmp_path):
    node: list = []
    for _ in range(28):
        node = [node, node]
    path = tmp_path / "results.pkl"
    path.write_bytes(pickle.dumps({"pred_thetas": node}))
    proc = subprocess.run([sys.executable, "-m", "smplik.cli", "scene", "from-estimate", str(path), "--out",
                           str(tmp_path / "out"), "--no-previews"], capture_output=True, text=True, cwd=ROOT,
                          timeout=300)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and "SMPLIK_MAX_PICKLE_OBJECTS" in lines[0], proc.stderr


def test_bvh_frame_counts_are_bounded_before_parsing(tmp_path, monkeypatch):
    from smplik.data.bvh import parse_bvh

    head = "HIERARCHY\nROOT hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n}\nMOTION\n"
    with pytest.raises(LimitError, match=r"'Frames: 10000000'.*SMPLIK_MAX_BVH_FRAMES"):
        parse_bvh(head + "Frames: 10000000\nFrame Time: 0.01\n0 0 0\n", "x.bvh")
    monkeypatch.setenv("SMPLIK_MAX_BVH_FRAMES", "1000")
    with pytest.raises(LimitError, match=r"'Frames: 2000'.*SMPLIK_MAX_BVH_FRAMES"):
        parse_bvh(head + "Frames: 2000\nFrame Time: 0.01\n" + "0 0 0\n" * 2000, "x.bvh")
    # a small declared count over a flood of lines: refused before the text is split (the hierarchy's allowance
    # is 8 lines per joint of max_joints)
    flood = head + "Frames: 5\nFrame Time: 0.01\n" + "0 0 0\n" * 3000
    with pytest.raises(LimitError, match=r"lines of the MOTION section.*SMPLIK_MAX_BVH_FRAMES"):
        parse_bvh(flood, "x.bvh", max_joints=100)
    monkeypatch.setenv("SMPLIK_MAX_BVH_FRAMES", "5000")
    assert parse_bvh(head + "Frames: 2000\nFrame Time: 0.01\n" + "0 0 0\n" * 2000, "x.bvh").num_frames == 2000
    with pytest.raises(ValueError, match=r"line 11: frame 1: 'x' is not a number"):
        parse_bvh(head + "Frames: 2\nFrame Time: 0.01\n0 0 0\n0 x 0\n", "x.bvh")


def test_image_pixels_are_checked_from_the_header(tmp_path, monkeypatch):
    from PIL import Image

    from workflows.scene.previews import load_image

    Image.new("RGB", (400, 300)).save(tmp_path / "a.png")
    assert load_image(tmp_path / "a.png").shape == (300, 400, 3)
    monkeypatch.setenv("SMPLIK_MAX_IMAGE_PIXELS", "100000")
    with pytest.raises(LimitError, match=r"a\.png \(400 x 300 image\): 120000 pixels .*SMPLIK_MAX_IMAGE_PIXELS"):
        load_image(tmp_path / "a.png")


@pytest.mark.parametrize("args", [["solve", "/dev/zero", "--out", "{tmp}/o.json"],
                                  ["scene", "solve", "/dev/zero", "--out", "{tmp}/o.json"]])
def test_json_readers_refuse_devices_and_read_a_bounded_amount(tmp_path, args):
    proc = subprocess.run([sys.executable, "-m", "smplik.cli", *[a.format(tmp=tmp_path) for a in args]],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and "/dev/zero: input file is a character device" in lines[0], \
        proc.stderr
    from smplik.limits import JSON_BYTES, read_bounded

    big = tmp_path / "big.json"
    big.write_bytes(b" " * 2000)
    os.environ["SMPLIK_MAX_JSON_BYTES"] = "1000"
    try:
        with pytest.raises(LimitError, match="SMPLIK_MAX_JSON_BYTES"):
            read_bounded(big, JSON_BYTES)
    finally:
        del os.environ["SMPLIK_MAX_JSON_BYTES"]
