"""Body model files and model-file configs: sparse ``J_regressor`` layouts fuzzed (a clean error, never a
signal), every number of a config bounded, and the resource limits of :mod:`smplik.limits`."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
from helpers import tiny_smpl_arrays

from smplik.body_model import ModelFileError, read_model_arrays

ROOT = Path(__file__).resolve().parents[1]


def sparse_mutations() -> list[tuple[str, str, dict]]:
    """(layout, name, attribute overrides) of malformed sparse matrices, as a pickle sets them."""
    out = []
    for layout in ("csr", "csc"):
        out += [(layout, "index 1e9", {"indices": ("set", 3, 10**9)}),
                (layout, "index -5", {"indices": ("set", 3, -5)}),
                (layout, "index = V", {"indices": ("set", 0, "minor")}),
                (layout, "indptr past nnz", {"indptr": ("set", -1, 10**6)}),
                (layout, "indptr decreasing", {"indptr": ("set", 5, 0)}), (layout, "indptr short", {"indptr": "short"}),
                (layout, "indptr negative start", {"indptr": ("set", 0, -3)}),
                (layout, "indices float", {"indices": "float"}), (layout, "data NaN", {"data": ("set", 0, np.nan)}),
                (layout, "shape huge", {"_shape": (10**9, 10**9)}), (layout, "shape negative", {"_shape": (-24, 30)}),
                (layout, "data missing", {"data": None})]
    out += [("coo", "row 1e9", {"row": ("set", 0, 10**9)}), ("coo", "col -1", {"col": ("set", 0, -1)}),
            ("coo", "row short", {"row": "short"}), ("coo", "shape huge", {"_shape": (2**40, 2**40)}),
            ("coo", "col object", {"col": "object"})]
    return out


def _mutated(layout: str, overrides: dict, V: int):
    """A sparse J_regressor (24, V) of ``layout`` with ``overrides`` applied to its pickled attributes."""
    dense = tiny_smpl_arrays(V)["J_regressor"]
    m = {"csr": scipy.sparse.csr_matrix, "csc": scipy.sparse.csc_matrix, "coo": scipy.sparse.coo_matrix}[layout](dense)
    state = dict(vars(m))
    if layout == "coo":
        state.pop("coords", None)
        state["row"], state["col"] = m.row.copy(), m.col.copy()
    for key, change in overrides.items():
        if change is None:
            state.pop(key)
        elif isinstance(change, tuple) and change and change[0] == "set":
            arr = state[key].astype(np.float64 if key == "data" else np.int64)
            arr[change[1]] = V if change[2] == "minor" else change[2]
            state[key] = arr
        elif change == "short":
            state[key] = state[key][:-2]
        elif change == "float":
            state[key] = state[key].astype(np.float64)
        elif change == "object":
            state[key] = state[key].astype(object)
        else:
            state[key] = change
    obj = object.__new__(type(m))
    obj.__dict__.update(state)
    return obj


FUZZ_SCRIPT = """
import json, sys
from smplik.body_model import read_model_arrays
for path in sys.argv[1:]:
    try:
        read_model_arrays(path)
        print(json.dumps({"path": path, "result": "loaded"}), flush=True)
    except ValueError as exc:
        print(json.dumps({"path": path, "result": type(exc).__name__, "message": str(exc)}), flush=True)
"""


def test_sparse_j_regressor_fuzz_gives_a_clean_error_never_a_signal(tmp_path):
    V = 30
    files = []
    for i, (layout, name, overrides) in enumerate(sparse_mutations()):
        arrays = tiny_smpl_arrays(V)
        arrays["J_regressor"] = _mutated(layout, overrides, V)
        path = tmp_path / f"{i:02d}_{layout}.pkl"
        path.write_bytes(pickle.dumps(arrays, protocol=2))
        files.append((path, f"{layout}: {name}"))
    # one subprocess reads them all: a signal (the SIGSEGV of an out-of-range index) kills it, rc < 0
    proc = subprocess.run([sys.executable, "-c", FUZZ_SCRIPT, *[str(p) for p, _ in files]], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, f"rc {proc.returncode}: {proc.stderr[-2000:]}"
    results = [json.loads(line) for line in proc.stdout.splitlines()]
    assert len(results) == len(files)
    for (path, what), res in zip(files, results, strict=True):
        assert res["result"] == "ModelFileError", (what, res)
        assert "\n" not in res["message"] and str(path) in res["message"] and "J_regressor" in res["message"], what


@pytest.mark.parametrize("layout", ["csr", "csc", "coo"])
def test_valid_sparse_layouts_load_as_the_dense_matrix(tmp_path, layout):
    arrays = tiny_smpl_arrays(30)
    dense = arrays["J_regressor"]
    arrays["J_regressor"] = _mutated(layout, {}, 30)
    (tmp_path / "m.pkl").write_bytes(pickle.dumps(arrays, protocol=2))
    assert np.allclose(read_model_arrays(tmp_path / "m.pkl")["J_regressor"], dense)


def test_the_cli_names_an_out_of_range_sparse_index(tmp_path):
    arrays = tiny_smpl_arrays(30)
    arrays["J_regressor"] = _mutated("csr", {"indices": ("set", 3, 10**9)}, 30)
    (tmp_path / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps(arrays, protocol=2))
    proc = subprocess.run([sys.executable, "-m", "smplik.cli", "body", "info", "--model-dir", str(tmp_path)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "sparse 'indices' outside [0, 29]" in lines[0]


@pytest.mark.parametrize("key,value,message", [
    ("f", np.full((40, 3), np.nan), "'f' contains NaN"),
    ("shapedirs", np.full((30, 3, 10), 1e6), "'shapedirs' has values up to"),
    ("kintree_table", np.stack([np.array([2**32 - 1] + list(range(23))), np.arange(24)[::-1]]), "row 1"),
])
def test_model_arrays_are_checked_before_use(tmp_path, key, value, message):
    arrays = tiny_smpl_arrays(30)
    arrays[key] = value
    np.savez(tmp_path / "m.npz", **arrays)
    with pytest.raises(ModelFileError, match=message):
        read_model_arrays(tmp_path / "m.npz")


def test_config_numbers_from_a_model_file_are_bounded(tmp_path):
    from smplik.model_io import CheckpointError, read_model_file, write_model_file
    from smplik.network import NetworkConfig
    from smplik.refine import MAX_REFINE_ITERATIONS, RefineConfig
    from smplik.solver import IKSolver, packaged_model_path

    for bad in (dict(iterations=10**9), dict(iterations=1e9), dict(iterations=True), dict(damping=float("inf")),
                dict(sigma_pos=float("nan")), dict(sigma_rot=0.0), dict(tolerance_eta=1e300),
                dict(joint_prior=[1.0] * 5000)):
        with pytest.raises(ValueError, match="RefineConfig"):
            RefineConfig(**bad)
    assert RefineConfig(iterations=MAX_REFINE_ITERATIONS).iterations == MAX_REFINE_ITERATIONS
    for bad in (dict(width=10**9), dict(encoder_blocks=0), dict(embedding_dim=2.5), dict(dropout=1.0),
                dict(layers_per_block=True)):
        with pytest.raises(ValueError, match="NetworkConfig"):
            NetworkConfig(**bad)
    state = read_model_file(packaged_model_path())
    state = {**state, "refine": {**(state.get("refine") or RefineConfig().to_dict()), "iterations": 10**9}}
    write_model_file(tmp_path / "m.pt", state)
    with pytest.raises(ValueError, match=r"m\.pt: key 'refine': RefineConfig.iterations must be an integer in"):
        IKSolver.load(tmp_path / "m.pt")
    state["network"] = {**state["network"], "width": 10**9}
    write_model_file(tmp_path / "w.pt", state)
    with pytest.raises(CheckpointError, match=r"w\.pt: key 'network'.*width must be an integer"):
        IKSolver.load(tmp_path / "w.pt")


def test_train_config_numbers_are_bounded(tmp_path):
    from smplik.train import TrainConfig

    for bad in (dict(steps=10**18), dict(batch_size=0), dict(lr=float("nan")), dict(val_every=0), dict(steps=True)):
        with pytest.raises(ValueError, match="TrainConfig"):
            TrainConfig(data="", out="", **bad)
    (tmp_path / "cfg.json").write_text(json.dumps({"steps": 10**18}))
    with pytest.raises(ValueError, match=r"cfg\.json: TrainConfig\.steps must be a number in \[0, 1e\+09\]"):
        TrainConfig.from_file(tmp_path / "cfg.json", data="", out="")
    (tmp_path / "cfg.json").write_text(json.dumps({"network": {"width": 10**9}}))
    with pytest.raises(ValueError, match=r"cfg\.json: NetworkConfig\.width"):
        TrainConfig.from_file(tmp_path / "cfg.json", data="", out="")
