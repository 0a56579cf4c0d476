"""Bounded fuzzing of the readers through the CLI, in-process (hypothesis and seeded mutations, ~20 s).

The contract (issue 11): exit 0 on input the reader accepts, or a non-zero exit with exactly one
``error:`` line naming the problem; never a traceback (an unexpected exception), a hang or a payload run.
``benchmarks/fuzz_campaign.py`` runs the same contract over the real CLI in subprocesses for every reader.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from smplik.cli.errors import is_user_error
from smplik.cli.main import app
from smplik.solver import IKSolver, packaged_model_path

FUZZ = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

VALID_EFFECTORS = {
    "format": "smplik-effectors", "version": 1, "betas": [0.3] + [0.0] * 9, "gender": "male",
    "effectors": [{"joint": "left_wrist", "type": "position", "value": [0.4, 1.1, 0.2], "tolerance": 0.0},
                  {"joint": "pelvis", "type": "rotation", "value": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
                  {"joint": "head", "type": "look_at", "target": [0.0, 1.6, 2.0], "direction": [0, 0, 1]}],
}

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(alphabet="ab[]/red,.0123456789", max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.sampled_from(["joint", "type", "value", "x"]),
                                                                 inner, max_size=3),
    max_leaves=12)


def json_paths(doc, prefix=()):  # noqa: ANN001, ANN201 - a JSON document
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from json_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from json_paths(v, (*prefix, i))


@st.composite
def mutated(draw, valid):  # noqa: ANN001, ANN201 - a hypothesis strategy of mutated JSON documents
    doc = json.loads(json.dumps(valid))
    for _ in range(draw(st.integers(1, 3))):
        paths = list(json_paths(doc))
        path = draw(st.sampled_from(paths[1:]))
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        action = draw(st.sampled_from(["replace", "replace", "delete", "unknown_key", "repeat"]))
        if action == "replace":
            parent[path[-1]] = draw(json_values)
        elif action == "delete":
            del parent[path[-1]]
        elif action == "unknown_key" and isinstance(parent, dict):
            parent["colour"] = draw(json_values)
        elif isinstance(parent, list):
            parent.extend([parent[path[-1]]] * draw(st.integers(1, 3)))
    return doc


def assert_contract(result) -> None:  # noqa: ANN001 - click.testing.Result
    """Exit 0, or exit 1 with one ``error:`` line; an escaping exception only if it is a user error
    (the top level turns it into that line)."""
    exc = result.exception
    if exc is not None and not isinstance(exc, SystemExit):
        assert is_user_error(exc), f"unexpected {type(exc).__name__}: {exc}"
        return
    if result.exit_code == 0:
        return
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.stderr


@pytest.fixture(scope="module")
def solver(shipped_solver):
    if not packaged_model_path().is_file():
        pytest.skip("no packaged model in this checkout")
    return shipped_solver


@pytest.fixture
def cached_solver(monkeypatch, solver):

    monkeypatch.setattr(IKSolver, "load", classmethod(lambda cls, *a, **k: solver))
    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: solver)
    return solver


@FUZZ
@given(doc=mutated(VALID_EFFECTORS))
def test_fuzz_effector_files(tmp_path_factory, cached_solver, doc):
    d = tmp_path_factory.mktemp("eff")
    (d / "eff.json").write_text(json.dumps(doc))
    result = CliRunner().invoke(app, ["solve", str(d / "eff.json"), "--out", str(d / "pose.json")])
    assert_contract(result)
    if result.exit_code == 0:
        pose = json.loads((d / "pose.json").read_text())
        assert np.isfinite(np.asarray(pose["body_pose"], float)).all()


@pytest.fixture(scope="module")
def valid_scene(solver, tmp_path_factory):
    from smplik.conventions import Gender
    from smplik.effectors import Effector
    from workflows.scene import Scene, SceneCharacter

    eff = (Effector.position("left_wrist", [0.4, 1.1, 0.2]), Effector.position("pelvis", [0.0, 0.9, 0.1]))
    pose = solver.solve(list(eff), gender="female")
    scene = Scene((SceneCharacter("a", Gender.FEMALE, np.zeros(10), 1.2, None, eff, pose),))
    return json.loads(json.dumps(scene.to_dict()))


@FUZZ
@given(data=st.data())
def test_fuzz_scene_files(tmp_path_factory, cached_solver, valid_scene, data):
    doc = data.draw(mutated(valid_scene))
    d = tmp_path_factory.mktemp("scene")
    (d / "scene.json").write_text(json.dumps(doc))
    assert_contract(CliRunner().invoke(app, ["scene", "solve", str(d / "scene.json"), "--out", str(d / "o.json")]))


def _smpl_arrays() -> dict[str, np.ndarray]:
    from smplik.body_model import load_body_model

    return {k: np.asarray(v) for k, v in load_body_model("neutral").export_arrays().items()}


def test_fuzz_smpl_model_folders(tmp_path, monkeypatch):
    """Seeded array-level and byte-level mutations of an SMPL npz, pkl variants and a payload pickle."""
    import smplik.body_model as bm
    from smplik.atomic import write_npz_deterministic

    valid = _smpl_arrays()
    rng = np.random.default_rng(0)
    marker = tmp_path / "PAYLOAD_RAN"

    class Payload:
        def __reduce__(self):
            import os

            return os.system, (f"touch {marker}",)

    valid_bytes = write_npz_deterministic(tmp_path / "valid.npz", valid).read_bytes()
    for n in range(8):
        d = tmp_path / f"m{n}"
        d.mkdir()
        arrays = {k: v.copy() for k, v in valid.items()}
        key = sorted(arrays)[rng.integers(len(arrays))]
        kind = n
        if kind == 0:
            arrays[key] = arrays[key][: max(0, len(arrays[key]) - 2)]
        elif kind == 1 and arrays[key].dtype.kind == "f":
            arrays[key].flat[rng.integers(arrays[key].size)] = np.nan
        elif kind == 2:
            arrays[key] = np.zeros_like(arrays[key])
        elif kind == 3:
            arrays[key] = arrays[key].astype("<U2")
        elif kind == 4:
            data = bytearray(valid_bytes)
            for i in rng.integers(0, len(data), 20):
                data[i] = rng.integers(256)
            (d / "SMPL_NEUTRAL.npz").write_bytes(bytes(data))
        elif kind == 5:
            (d / "SMPL_NEUTRAL.npz").write_bytes(valid_bytes[: rng.integers(len(valid_bytes))])
        elif kind == 6:
            (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps({**arrays, "f": Payload()}, protocol=2))
        else:
            arrays.pop(key)
            (d / "SMPL_NEUTRAL.pkl").write_bytes(pickle.dumps(arrays, protocol=0))
        if not any(d.iterdir()):
            write_npz_deterministic(d / "SMPL_NEUTRAL.npz", arrays)
        result = CliRunner().invoke(app, ["body", "info", "--model-dir", str(d)])
        assert_contract(result)
        assert not marker.exists()
        bm._CACHE.pop(("neutral", str(d)), None)  # keep memory flat


def test_fuzz_npz_zip_directory(tmp_path):
    """Zip members whose directory sizes or npy headers lie are refused before they are inflated."""
    from smplik.safe_pickle import read_npz

    rng = np.random.default_rng(1)
    for n in range(12):
        buf = io.BytesIO()
        shape = tuple(int(x) for x in rng.integers(0, 10**rng.integers(1, 10), size=rng.integers(0, 4)))
        np.lib.format.write_array_header_1_0(buf, {"descr": rng.choice(["<f8", "|u1", "<i4", "|O"]),
                                                   "fortran_order": False, "shape": shape})
        path = tmp_path / f"z{n}.npz"
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("a.npy", buf.getvalue() + bytes(int(rng.integers(0, 256))))
        try:
            read_npz(path, allow_objects=bool(n % 2))
        except ValueError as exc:
            assert str(path) in str(exc)


@pytest.mark.parametrize("name", ["folder", "under_a_file", "markup", "long_name", "empty_suffix", "fifo"])
def test_fuzz_output_paths(tmp_path, name):
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_folder.npz").mkdir()
    out = {"folder": tmp_path / "a_folder.npz", "under_a_file": tmp_path / "a_file" / "x.npz",
           "markup": tmp_path / "[red]x[/red].npz", "long_name": tmp_path / ("x" * 300 + ".npz"),
           "empty_suffix": tmp_path / "x.", "fifo": tmp_path / "fifo.npz"}[name]
    os.mkfifo(tmp_path / "fifo.npz")
    result = CliRunner().invoke(app, ["body", "export", "--out", str(out)])
    if name == "markup":
        assert result.exit_code == 0 and out.is_file() and "[red]x[/red].npz" in result.stderr
    elif result.exception is not None and not isinstance(result.exception, SystemExit):
        assert is_user_error(result.exception), repr(result.exception)
    else:
        assert_contract(result)
        assert result.exit_code != 0
