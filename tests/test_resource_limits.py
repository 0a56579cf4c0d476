"""Security round 3 (issue #36): every input that declares or implies more work than the limits allow is refused
*before* the work, in one ``error:`` line naming the limit's environment variable, exit 1.

Each case is built from a recipe that stays small on disk (pickle DAGs, stride-0 tensors, declared frame counts,
sparse files, a symlink to ``/dev/zero``, a named pipe) and runs the real CLI in a subprocess under a 3 GiB
address-space cap (``RLIMIT_AS``), so a regression fails with a ``MemoryError`` instead of eating the machine;
the child's peak RSS is read back and must stay under 2 GiB.
"""

from __future__ import annotations

import gzip
import io
import json
import os
import pickle
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from limit_recipes import bvh_text, gltf_rig, run_capped, str_of_list_dag

from smplik.limits import (
    ALL_LIMITS,
    MEMORY_BYTES,
    CappedReader,
    LimitError,
    check_input_file,
    check_render_size,
    check_tensors,
)
from smplik.safe_pickle import UnsafePickleError, loads_restricted

ROOT = Path(__file__).resolve().parents[1]
def assert_refused(args: list[str], *needles: str, env: dict[str, str] | None = None) -> str:
    """The command fails with exactly one ``error:`` line holding every needle, exit 1, under 2 GiB."""
    rc, lines, peak = run_capped(*args, env=env)
    assert rc == 1 and len(lines) == 1 and lines[0].startswith("error: "), lines
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert peak < 2 << 30, f"peak RSS {peak / 2**30:.2f} GiB"
    return lines[0]


# ----------------------------------------------------------------------------- pickles


def test_str_of_an_object_is_refused_before_the_call():
    data = str_of_list_dag()
    assert len(data) < 400
    with pytest.raises(UnsafePickleError, match=r"builtins\.str\(list\)"):
        loads_restricted(data)
    # numbers and text still convert (Python 2 pickles and numpy use them)
    assert loads_restricted(b"cbuiltins\nstr\n(C\x03abcVlatin1\ntR.") == "abc"
    assert loads_restricted(b"cbuiltins\nint\n(V12\ntR.") == 12


def test_a_tuple_dag_as_a_dict_key_or_set_member_is_refused_before_hashing():
    node: tuple = ()
    for _ in range(40):  # hashing it would walk 2**40 tuples: never hashed here, the pickles are spelled out
        node = (node, node)
    key = pickle.dumps(node, protocol=4)[2:-1]  # its opcodes, without PROTO and STOP
    for ops in (b"}" + key + b"K\x01s",  # SETITEM
                b"}(" + key + b"K\x01u",  # SETITEMS
                b"(" + key + b"K\x01d",  # DICT
                b"\x8f(" + key + b"\x90",  # EMPTY_SET, ADDITEMS
                b"(" + key + b"\x91"):  # FROZENSET
        with pytest.raises(UnsafePickleError, match="dict key or set member"):
            loads_restricted(b"\x80\x04" + ops + b".")
    small: tuple = ()
    for _ in range(5):
        small = (small, small)
    assert loads_restricted(pickle.dumps({small: 1}, protocol=2)) == {small: 1}


def test_copies_made_by_calls_count_against_the_budget(monkeypatch):
    # list(x) called 50 times on one memoised 1000-item list: 50,000 items copied from a file of a few KB
    items = pickle.dumps(list(range(1000)), protocol=2)[2:-1]  # the list's opcodes (without PROTO and STOP)
    body = b"\x80\x02" + items + b"q\x00" + b"(" + b"cbuiltins\nlist\nh\x00\x85R" * 50 + b"l."
    assert len(loads_restricted(body)) == 50
    monkeypatch.setenv("SMPLIK_MAX_PICKLE_OBJECTS", "20000")
    with pytest.raises(UnsafePickleError, match="SMPLIK_MAX_PICKLE_OBJECTS"):
        loads_restricted(body)


def test_the_str_dag_estimate_is_one_line_through_the_cli(tmp_path):
    path = tmp_path / "results.pkl"
    path.write_bytes(str_of_list_dag())
    assert_refused(["scene", "from-estimate", str(path), "--out", str(tmp_path / "out"), "--no-previews"],
                   "builtins.str(list)")


def test_the_str_dag_smpl_model_file_is_one_line(tmp_path):
    from smplik.body_model import ModelFileError, read_model_arrays

    path = tmp_path / "SMPL_NEUTRAL.pkl"
    path.write_bytes(str_of_list_dag())
    with pytest.raises(ModelFileError, match=r"builtins\.str\(list\)"):
        read_model_arrays(path)


@pytest.mark.slow
def test_compressed_pickles_are_inflated_with_a_running_cap(tmp_path, monkeypatch):
    from smplik.safe_pickle import load_pickle

    # a BINBYTES8 declaring 4 GiB: the one read that would allocate it is refused first
    head = b"\x80\x04\x8e" + (4 << 30).to_bytes(8, "little")
    bomb = tmp_path / "bomb.pkl"
    bomb.write_bytes(gzip.compress(head + bytes(4 << 20), compresslevel=1))
    assert bomb.stat().st_size < 100_000
    with pytest.raises(LimitError, match=r"bomb\.pkl \(decompressed\): more than .*SMPLIK_MAX_PICKLE_BYTES"):
        load_pickle(bomb)
    # many small opcodes (a list of 3 M ints, 9 MB once inflated): stopped once the cap is passed
    stream = pickle.dumps(list(range(3_000_000)), protocol=4)
    flood = tmp_path / "flood.pkl"
    import joblib

    joblib.dump(list(range(3_000_000)), flood, compress=("zlib", 3))
    assert load_pickle(flood) == list(range(3_000_000))
    monkeypatch.setenv("SMPLIK_MAX_PICKLE_BYTES", str(len(stream) // 2))
    with pytest.raises(LimitError, match="SMPLIK_MAX_PICKLE_BYTES"):
        load_pickle(flood)


def test_the_gzip_bomb_estimate_is_one_line_through_the_cli(tmp_path):
    head = b"\x80\x04\x8e" + (4 << 30).to_bytes(8, "little")
    path = tmp_path / "results.pkl"
    path.write_bytes(gzip.compress(head + bytes(4 << 20), compresslevel=1))
    assert_refused(["scene", "from-estimate", str(path), "--out", str(tmp_path / "out"), "--no-previews"],
                   "SMPLIK_MAX_PICKLE_BYTES")


def test_npz_object_members_are_refused_from_their_declared_size(tmp_path, monkeypatch):
    from smplik.safe_pickle import read_npz

    path = tmp_path / "romp.npz"
    np.savez(path, results=np.array({"smpl_thetas": np.zeros((1000, 72))}, dtype=object))
    assert read_npz(path)["results"]["smpl_thetas"].shape == (1000, 72)
    monkeypatch.setenv("SMPLIK_MAX_PICKLE_BYTES", "100000")  # the member holds 576 KB of pickle
    with pytest.raises(LimitError, match=r"object array 'results' \(a pickle\).*SMPLIK_MAX_PICKLE_BYTES"):
        read_npz(path)


# ----------------------------------------------------------------------------- tensors


def test_dtype_conversions_are_counted_across_the_file(tmp_path):
    import torch

    a = torch.zeros(1).expand(199_000_000)  # 4 bytes stored; 796 MB as float32, 1.6 GB as float64
    b = torch.zeros(1).expand(199_000_000)
    check_tensors({"a": a, "b": b}, "x.pt")  # each inside the array limits, both inside the input budget
    with pytest.raises(LimitError, match=r"x\.pt \(all tensors as 64-bit floats\).*SMPLIK_MAX_MEMORY_BYTES"):
        check_tensors({"a": a, "b": b}, "x.pt", as_itemsize=8)
    path = tmp_path / "hmr4d_results.pt"
    torch.save({"smpl_params_global": {"body_pose": a, "betas": b}}, path)
    assert path.stat().st_size < 10_000
    assert_refused(["scene", "from-estimate", str(path), "--out", str(tmp_path / "out"), "--no-previews"],
                   "64-bit floats", "SMPLIK_MAX_MEMORY_BYTES")


def test_a_compressed_torch_storage_is_refused_from_the_zip_directory(tmp_path):
    import torch

    plain = tmp_path / "plain.pt"
    torch.save({"x": torch.zeros(4)}, plain)
    bomb = tmp_path / "hmr4d_results.pt"
    with zipfile.ZipFile(plain) as src, zipfile.ZipFile(bomb, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if "/data/" in info.filename:  # one storage member inflating to 80 MB
                dst.writestr(info.filename, bytes(80 << 20), compress_type=zipfile.ZIP_DEFLATED, compresslevel=1)
            else:
                dst.writestr(info, data)
    assert bomb.stat().st_size < 1 << 20
    assert_refused(["scene", "from-estimate", str(bomb), "--out", str(tmp_path / "out"), "--no-previews"],
                   "is compressed and inflates to 83886080 bytes")


# ----------------------------------------------------------------------------- model sizes


def test_network_memory_estimate_counts_the_real_weights():
    import torch

    from smplik.configs import NetworkConfig, check_network_memory, network_parameter_count
    from smplik.network import ProtoResIK

    for cfg in (NetworkConfig(), NetworkConfig(width=48, encoder_blocks=2, layers_per_block=3, effector_slots=True)):
        model = ProtoResIK(cfg, torch.zeros(3, 24, 3), torch.zeros(3, 24, 3, 10))
        assert network_parameter_count(cfg) == sum(p.numel() for p in model.parameters())
    check_network_memory(NetworkConfig.paper(), "paper")  # the paper's model loads for inference
    for cfg in (NetworkConfig(width=8192), NetworkConfig(width=1024, encoder_blocks=32, decoder_blocks=32,
                                                         layers_per_block=16)):
        with pytest.raises(LimitError, match="SMPLIK_MAX_MEMORY_BYTES"):
            check_network_memory(cfg, "m.pt")
    with pytest.raises(LimitError, match="training at batch 512 x 16 effectors.*SMPLIK_MAX_MEMORY_BYTES"):
        check_network_memory(NetworkConfig(encoder_blocks=32, decoder_blocks=32, layers_per_block=16), "cfg",
                             batch=512, tokens=16, training=True)


def test_a_checkpoint_whose_sizes_imply_too_much_memory_is_refused_before_building(tmp_path):
    import torch

    from smplik.model_io import read_model_file
    from smplik.solver import packaged_model_path

    state = read_model_file(packaged_model_path())
    state["network"] = {**state["network"], "width": 8192}
    path = tmp_path / "wide.pt"
    torch.save(state, path)
    effectors = tmp_path / "e.json"
    effectors.write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [
        {"joint": "pelvis", "type": "position", "value": [0.0, 0.9, 0.0]}]}))
    assert_refused(["solve", str(effectors), "--checkpoint", str(path), "--out", str(tmp_path / "p.json")],
                   "wide.pt: key 'network': a network of width 8192", "SMPLIK_MAX_MEMORY_BYTES")


def test_train_config_sizes_are_checked_before_anything_is_written(tmp_path):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"network": {"encoder_blocks": 32, "decoder_blocks": 32, "layers_per_block": 16}}))
    assert_refused(["train", "--config", str(config), "--data", str(tmp_path / "cache.npz"), "--out",
                    str(tmp_path / "run")], "training config", "SMPLIK_MAX_MEMORY_BYTES")
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------- images and renders


def test_render_sizes_are_bounded_by_memory(tmp_path, monkeypatch):
    check_render_size(1920, 1080)
    with pytest.raises(LimitError, match=r"6000 x 6000 image at 64 bytes a pixel.*SMPLIK_MAX_MEMORY_BYTES"):
        check_render_size(6000, 6000)  # inside the pixel limit, not the memory one
    assert_refused(["body", "render", "--out", str(tmp_path / "b.png"), "--width", "8192", "--height", "8192"],
                   "SMPLIK_MAX_MEMORY_BYTES")
    assert not (tmp_path / "b.png").exists()


def test_images_decode_to_uint8_and_their_render_is_bounded(tmp_path, monkeypatch):
    from PIL import Image

    from workflows.scene.previews import load_image

    small = tmp_path / "a.png"
    Image.fromarray(np.arange(24, dtype=np.uint8).reshape(2, 4, 3)).save(small)
    img = load_image(small)
    assert img.dtype == np.uint8 and img.tolist() == np.arange(24).reshape(2, 4, 3).tolist()  # exact, not float
    monkeypatch.setenv("SMPLIK_MAX_MEMORY_BYTES", "32")
    with pytest.raises(LimitError, match=r"a\.png \(4 x 2 image decoded at 8 bytes a pixel\).*MEMORY_BYTES"):
        load_image(small)


def test_an_8000_pixel_photo_under_scene_render_is_one_line(shipped_solver, tmp_path):
    from PIL import Image

    from smplik.conventions import Gender
    from smplik.effectors import Effector
    from workflows.estimators.base import CameraInfo
    from workflows.scene import Scene, SceneCharacter, save_scene

    eff = (Effector.position("pelvis", [0.0, 0.9, -3.0]),)
    pose = shipped_solver.solve(list(eff), betas=np.zeros(10), gender="neutral")
    photo = tmp_path / "photo.png"
    Image.new("RGB", (8000, 8000)).save(photo)
    assert photo.stat().st_size < 1 << 20
    scene = save_scene(Scene((SceneCharacter("a", Gender.NEUTRAL, np.zeros(10), 1.0, None, eff, pose),),
                             camera=CameraInfo(8000.0, (8000, 8000)), image=str(photo)), tmp_path / "scene.json")
    assert_refused(["scene", "render", str(scene), "--out", str(tmp_path / "o.png"), "--image", str(photo)],
                   "8000 x 8000", "SMPLIK_MAX_MEMORY_BYTES")
    assert not (tmp_path / "o.png").exists()


# ----------------------------------------------------------------------------- files that are not files


def test_devices_pipes_and_links_to_them_are_refused_up_front(tmp_path):
    regular = tmp_path / "a.bin"
    regular.write_bytes(b"abc")
    assert check_input_file(regular) == 3
    link = tmp_path / "z.glb"
    link.symlink_to("/dev/zero")
    with pytest.raises(LimitError, match=r"z\.glb: input file is a character device \(through a link to /dev/zero\)"):
        check_input_file(link)
    fifo = tmp_path / "pipe.bin"
    os.mkfifo(fifo)
    with pytest.raises(LimitError, match="a named pipe"):
        check_input_file(fifo)
    with pytest.raises(LimitError, match="a folder"):
        check_input_file(tmp_path)
    assert_refused(["invert-shape", str(link), "--out", str(tmp_path / "s.json")], "z.glb", "character device")


def test_a_gltf_buffer_on_a_named_pipe_is_refused_not_waited_for(tmp_path):
    os.mkfifo(tmp_path / "pipe.bin")  # nobody writes to it: opening it would block for ever
    path = gltf_rig(tmp_path, [{"uri": "pipe.bin", "byteLength": 128}],
                 [{"bufferView": 0, "componentType": 5126, "count": 2, "type": "MAT4"}])
    assert_refused(["invert-shape", str(path), "--out", str(tmp_path / "s.json")], "pipe.bin", "named pipe (FIFO)")


def test_a_skin_accessor_claiming_5e7_matrices_is_refused_before_allocating(tmp_path):
    path = gltf_rig(tmp_path, [], [{"componentType": 5126, "count": 50_000_000, "type": "MAT4"}])
    assert_refused(["invert-shape", str(path), "--out", str(tmp_path / "s.json")], "accessors[0] (MAT4 x 50000000)",
                   "SMPLIK_MAX_ARRAY_ELEMENTS")


def test_an_estimator_json_is_read_under_the_json_limit(tmp_path):
    path = tmp_path / "plain.json"
    with open(path, "wb") as fh:  # 300 MB, sparse on disk: under --max-bytes (1 GiB), over the JSON limit
        fh.truncate(300 << 20)
    assert_refused(["scene", "from-estimate", str(path), "--out", str(tmp_path / "out"), "--no-previews"],
                   "SMPLIK_MAX_JSON_BYTES")


# ----------------------------------------------------------------------------- work sized by a number


def test_a_bvh_whose_parse_would_pass_the_memory_budget_is_refused_first(tmp_path, monkeypatch):
    from smplik.data.bvh import parse_bvh

    assert parse_bvh(bvh_text(31, 20, 20)).num_frames == 20
    monkeypatch.setenv("SMPLIK_MAX_MEMORY_BYTES", "100K")
    with pytest.raises(LimitError, match=r"20 frames of 31 joints, parsed at 848 bytes.*SMPLIK_MAX_MEMORY_BYTES"):
        parse_bvh(bvh_text(31, 20, 20))
    monkeypatch.delenv("SMPLIK_MAX_MEMORY_BYTES")
    path = tmp_path / "long.bvh"  # 900,000 frames of 31 joints (23 GB parsed) inside the 10**6-frame limit
    path.write_text(bvh_text(31, 900_000, 2))
    assert_refused(["data", "preview", str(path), "--out", str(tmp_path / "p.png")], "900000 frames of 31 joints",
                   "SMPLIK_MAX_MEMORY_BYTES")


def test_benchmark_sample_counts_are_bounded_by_memory(tmp_path):
    assert_refused(["benchmark", "make", "--data", str(tmp_path / "cache.npz"), "--out", str(tmp_path / "b"),
                    "--samples-per-count", "1000000000"], "--samples-per-count 1000000000", "SMPLIK_MAX_MEMORY_BYTES")
    assert not (tmp_path / "b").exists()


def test_capped_reader_refuses_a_read_past_its_cap_before_reading(monkeypatch):
    monkeypatch.setenv("SMPLIK_MAX_PICKLE_BYTES", "10")
    reader = CappedReader(io.BytesIO(b"0123456789abcdef"), "s")
    with pytest.raises(LimitError, match="s: more than 10 bytes"):
        reader.read(11)
    assert reader.count == 0  # refused before anything was read
    reader.read(10)
    with pytest.raises(LimitError):
        reader.read(1)


def test_every_limit_is_listed_on_the_security_page():
    page = (ROOT / "docs" / "security.md").read_text()
    for limit in ALL_LIMITS:
        assert f"`{limit.env}`" in page, limit.env
    assert MEMORY_BYTES.env == "SMPLIK_MAX_MEMORY_BYTES"


# ----------------------------------------------------------------------------- long runs


def test_a_long_animation_shows_progress_and_stops_on_ctrl_c(tmp_path):
    """A 100,000-frame AIST++ clip (the frame limit) takes minutes: progress lines appear on a non-terminal
    stderr, and a real SIGINT (sent once the first progress line is out, long before the run could end) stops it
    with one line, exit 130, and no output folder."""
    n = 100_000
    clip = tmp_path / "aist.pkl"
    with open(clip, "wb") as fh:
        pickle.dump({"smpl_poses": np.zeros((n, 72), np.float32), "smpl_trans": np.zeros((n, 3), np.float32),
                     "smpl_scaling": np.ones(1, np.float32)}, fh)
    proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", "scene", "animate", str(clip), "--out",
                             str(tmp_path / "anim")], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        first = proc.stderr.readline()  # blocks until the first progress line (or the end of stderr)
        assert first.startswith("reading frames: 0/100000"), first
        proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    lines = [ln for ln in rest.splitlines() if ln.strip() and not ln.startswith("reading frames")]
    assert proc.returncode == 130 and lines == ["error: interrupted (Ctrl-C): stopped; no file was left "
                                                "half-written."], rest
    assert not (tmp_path / "anim").exists()
