"""Bad input (issue 11): physical ranges, robust refinement, strict readers, the restricted unpickler,
bounded npz reading, stale temp files, one-line CLI errors, residual reports and renders."""

from __future__ import annotations

import io
import json
import os
import pickle
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import needs_gl
from typer.testing import CliRunner

from smplik.atomic import remove_stale_temp_files, write_json_atomic, write_npz_deterministic
from smplik.body_model import ModelFileError, read_model_arrays
from smplik.effector_schema import parse_effector_document
from smplik.effectors import Effector, EffectorError, pack_effectors
from smplik.refine import RefineConfig, refine_output
from smplik.safe_pickle import UnsafePickleError, load_pickle, loads_restricted, read_npz
from smplik.solver import packaged_model_path

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl")}


@pytest.fixture(scope="module")
def solver(shipped_solver):
    if not packaged_model_path().is_file():
        pytest.skip("no packaged model in this checkout")
    return shipped_solver


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "smplik.cli", *args], capture_output=True, text=True, env=ENV,
                          cwd=cwd, timeout=300)


def one_error_line(res: subprocess.CompletedProcess) -> str:
    """The contract for a user's mistake: exit 1 and exactly one stderr line starting 'error:'."""
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    return lines[0]


# ----------------------------------------------------------------------------- 11.2 ranges and refinement


@pytest.mark.parametrize("doc", [
    [{"joint": "head", "type": "position", "value": [0.0, 1e308, 0.0]}],
    [{"joint": "head", "type": "position", "value": [1000.5, 0.0, 0.0]}],
    [{"joint": "head", "type": "look_at", "target": [0.0, 0.0, -1e200]}],
])
def test_values_outside_the_physical_range_are_refused_by_name(doc):
    with pytest.raises(EffectorError, match=r"f.json: effectors\[0\]\.(value|target): .* outside the accepted range"):
        parse_effector_document(doc, "f.json")
    with pytest.raises(EffectorError, match="outside the accepted range"):
        Effector.from_dict(doc[0])


def test_extreme_but_valid_effectors_solve_to_finite_poses(solver):
    near_identity = np.eye(3) + 4e-4 * np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]])  # just within 1e-3
    effectors = [Effector.position("left_wrist", [999.0, -999.0, 999.0]),
                 Effector.look_at("head", [-999.0, 999.0, -999.0]),
                 Effector.rotation("pelvis", near_identity),
                 Effector.rotation("left_elbow", [[1, 0, 0], [0, -1, 1e-9], [0, -1e-9, -1]])]
    pose = solver.solve(effectors)
    for key in ("global_orient", "body_pose", "transl", "joints"):
        assert np.isfinite(getattr(pose, key)).all(), key


def test_failed_factorisation_keeps_that_poses_iterate(bodies):
    """A pose whose normal equations overflow (fast path, no validation) keeps the network's pose, while the
    other pose of the batch is refined; nothing raises."""
    from smplik.kinematics import forward_kinematics
    from smplik.network import IKOutput

    betas, gender = torch.zeros(2, 10), torch.tensor([0, 0])
    J_rest = bodies.rest_joints(betas, gender)
    R = torch.eye(3).expand(2, 24, 3, 3).clone()
    R_world, p_world = forward_kinematics(R, J_rest, torch.zeros(2, 3))
    out = IKOutput(R, R_world, p_world, p_world, torch.zeros(2, 3))
    good = Effector.position("left_wrist", p_world[0, 20].numpy() + [0.05, 0.0, 0.0])
    eff = pack_effectors([[good], [good]])
    eff.data[1, 0, :3] = torch.tensor([1e300, 1e300, 1e300])  # float32 inf: beyond any range
    refined = refine_output(out, J_rest, eff, RefineConfig(iterations=3))
    assert torch.equal(refined.R_local[1], out.R_local[1]) and torch.equal(refined.transl[1], out.transl[1])
    moved = (refined.p_world[0, 20] - p_world[0, 20]).norm()
    assert moved > 0.02 and torch.isfinite(refined.p_world[0]).all()


# ----------------------------------------------------------------------------- 11.7 strict effector files


@pytest.mark.parametrize(("item", "message"), [
    ({"joint": "head", "type": "position", "value": [0, 1, 0], "tolerence": 0.1}, r"unknown key\(s\) \['tolerence'\]"),
    ({"joint": "head", "type": "position", "value": [0, 1, 0], "tolerance": "0.5"}, r"tolerance: must be a number"),
    ({"joint": "head", "type": "position", "value": [0, 1, 0], "tolerance": True}, r"tolerance: must be a number"),
    ({"joint": "head", "type": "position", "value": [0, True, 0]}, r"value: must be numbers"),
    ({"joint": "head", "type": "look_at", "target": [0, 1, 1], "direction": [False, 0, 1]}, "direction: must be"),
    ({"joint": 15, "type": "position", "value": [0, 1, 0]}, r"joint: unknown joint 15"),
    ({"joint": "head", "type": ["position"], "value": [0, 1, 0]}, r"type: must be one of"),
])
def test_effector_items_are_parsed_strictly(item, message):
    with pytest.raises(EffectorError, match=message):
        parse_effector_document([item], "f.json")


def test_deeply_nested_effector_json_is_one_named_error(tmp_path):
    from smplik.effector_schema import load_effector_file

    path = tmp_path / "deep.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(EffectorError, match=f"{path}: JSON nested too deeply"):
        load_effector_file(path)


# ----------------------------------------------------------------------------- 11.7 strict scenes


@pytest.fixture(scope="module")
def scene_dict(solver):
    from smplik.conventions import Gender
    from workflows.estimators.base import CameraInfo
    from workflows.scene import Scene, SceneCharacter

    eff = (Effector.position("left_wrist", [0.4, 1.1, 0.2]), Effector.position("pelvis", [0.0, 0.9, 0.0]))
    betas = np.linspace(-1, 1, 10)
    pose = solver.solve(list(eff), betas=betas, gender="female")
    scene = Scene((SceneCharacter("a", Gender.FEMALE, betas, 1.0, None, eff, pose),),
                  camera=CameraInfo(500.0, (640, 480)))
    return scene.to_dict()


def test_scene_keys_are_the_dataclass_fields(scene_dict):
    import dataclasses

    from workflows.estimators.base import CameraInfo
    from workflows.scene import Scene, SceneCharacter, SceneError, scene_from_dict

    assert set(scene_dict) == {"format", "version"} | {f.name for f in dataclasses.fields(Scene)}
    assert set(scene_dict["characters"][0]) == {f.name for f in dataclasses.fields(SceneCharacter)}
    assert set(scene_dict["camera"]) == {f.name for f in dataclasses.fields(CameraInfo)}
    for where in ("root", "character", "camera"):
        data = json.loads(json.dumps(scene_dict))
        target = {"root": data, "character": data["characters"][0], "camera": data["camera"]}[where]
        target["colour"] = "red"
        with pytest.raises(SceneError, match=r"s.json: .*unknown key\(s\) \['colour'\]"):
            scene_from_dict(data, "s.json")


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["characters"][0].update(betas=[0.5] * 10), r"characters\[0\]\.pose\.betas: .* do not match"),
    (lambda d: d["characters"][0].update(gender="male"), r"characters\[0\]\.pose\.gender"),
    (lambda d: d["camera"].update(focal_px=float("nan")), r"camera\.focal_px: contains NaN"),
    (lambda d: d["camera"].update(focal_px=-3.0), r"camera\.focal_px: must be a positive"),
    (lambda d: d["camera"].update(image_size=[0, 0]), r"camera\.image_size"),
    (lambda d: d["characters"][0].update(scale=1e-9), r"characters\[0\]\.scale: must be in"),
    (lambda d: d["characters"][0].update(betas=[1e6] * 10), r"characters\[0\]\.betas: .*outside"),
    (lambda d: d.update(characters=d["characters"] * 2), r"the name 'a' is used twice"),
])
def test_inconsistent_scenes_are_refused_by_json_path(scene_dict, edit, message):
    from workflows.scene import SceneError, scene_from_dict

    data = json.loads(json.dumps(scene_dict))
    edit(data)
    with pytest.raises(SceneError, match=message):
        scene_from_dict(data, "s.json")


def test_character_count_is_capped_and_the_cap_can_be_raised(scene_dict):
    from workflows.scene import MAX_CHARACTERS, SceneError, scene_from_dict

    data = json.loads(json.dumps(scene_dict))
    one = data["characters"][0]
    data["characters"] = [{**one, "name": f"p{i}"} for i in range(1000)]
    with pytest.raises(SceneError, match=f"1000 characters; at most {MAX_CHARACTERS}"):
        scene_from_dict(data, "s.json")
    data["characters"] = data["characters"][:150]
    assert len(scene_from_dict(data, "s.json", max_characters=200).characters) == 150


def test_save_scene_refuses_a_nan_focal_length_and_writes_nothing(scene_dict, tmp_path):
    import dataclasses

    from workflows.scene import SceneError, save_scene, scene_from_dict

    scene = scene_from_dict(scene_dict)
    # The camera record refuses a NaN focal length itself; a scene can never carry one to the writer.
    with pytest.raises(ValueError, match="focal"):
        bad = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, focal_px=float("nan")))
        save_scene(bad, tmp_path / "scene.json")
    assert list(tmp_path.iterdir()) == []
    data = scene.to_dict()
    data["camera"]["focal_px"] = float("nan")
    with pytest.raises(SceneError, match="focal"):
        scene_from_dict(data)


# ----------------------------------------------------------------------------- 11.7 SMPL model arrays


def builtin_arrays() -> dict[str, np.ndarray]:
    from smplik.body_model import load_body_model

    return {k: np.array(v) for k, v in load_body_model("neutral").export_arrays().items()}


@pytest.mark.parametrize(("edit", "message"), [
    (lambda a: a.update(v_template=a["v_template"][:, :2]), r"'v_template' has shape .*expected \(V, 3\)"),
    (lambda a: a["v_template"].__setitem__((5, 1), np.nan), "'v_template' contains NaN"),
    (lambda a: a.update(J_regressor=np.zeros_like(a["J_regressor"])), "'J_regressor' has all-zero"),
    (lambda a: a.update(f=a["f"] + 10**6), "'f' indexes vertices outside"),
    (lambda a: a.update(weights=a["weights"][:-1]), "'weights' has shape"),
    (lambda a: a.pop("shapedirs"), "missing key 'shapedirs'"),
])
def test_malformed_smpl_arrays_are_refused_by_key(tmp_path, edit, message):
    arrays = builtin_arrays()
    edit(arrays)
    path = write_npz_deterministic(tmp_path / "SMPL_NEUTRAL.npz", arrays)
    with pytest.raises(ModelFileError, match=message):
        read_model_arrays(path)


def test_corrupt_npz_and_declared_sizes_are_checked_before_reading(tmp_path, monkeypatch):
    path = tmp_path / "SMPL_NEUTRAL.npz"
    path.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ModelFileError, match="cannot read SMPL model: not a readable .npz"):
        read_model_arrays(path)
    # a member whose header declares 8 GB but holds a few bytes (a lying header) is refused unread
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (10**9,)})
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("v_template.npy", buf.getvalue() + b"\0" * 64)
    with pytest.raises(ValueError, match=r"shape \(1000000000,\)\): 1000000000 elements .* SMPLIK_MAX_ARRAY_ELEMENTS"):
        read_npz(path)
    monkeypatch.setenv("SMPLIK_MAX_ARRAY_ELEMENTS", "2000000000")
    monkeypatch.setenv("SMPLIK_MAX_ARRAY_BYTES", "16G")
    with pytest.raises(ValueError, match=r"declares shape \(1000000000,\)"):  # within the limits: still a liar
        read_npz(path)
    # a zip bomb: small on disk, large uncompressed (the zip directory says so)
    write_npz_deterministic(path, {"big": np.zeros(4_000_000)})
    assert path.stat().st_size < 200_000
    monkeypatch.setenv("SMPLIK_MAX_INPUT_BYTES", "1000000")
    with pytest.raises(ValueError, match=r"32000128 bytes \(all arrays of the input\) is over the limit of 1000000 .*"
                                         "SMPLIK_MAX_INPUT_BYTES"):
        read_npz(path)


# ----------------------------------------------------------------------------- 11.5 restricted unpickler


def _pickle_of_call(module: str, name: str, args: bytes) -> bytes:
    """Protocol-0 pickle calling ``module.name(*args)`` (``args`` is the pickled argument tuple body)."""
    return f"c{module}\n{name}\n(".encode() + args + b"tR."


@pytest.mark.parametrize(("payload", "message"), [
    (_pickle_of_call("builtins", "bytearray", b"F2000000000.0\n"), "never a size"),
    (_pickle_of_call("builtins", "bytearray", b"I2000000000\n"), "never a size"),
    (_pickle_of_call("builtins", "bytes", b"I2000000000\n"), "never a size"),
    (_pickle_of_call("numpy", "ndarray", b"(I1000000000\ntp0\n"), "Refusing to call numpy.ndarray"),
    (_pickle_of_call("builtins", "range", b"I1000000000\n"), "Refusing to load global 'builtins.range'"),
    (_pickle_of_call("os", "system", b"Vecho pwned\n"), "Refusing to load global 'os.system'"),
    (_pickle_of_call("copyreg", "_reconstructor", b"cnumpy\nndarray\ncnumpy\nndarray\n(I1000000000\nt"),
     "base other than object"),
])
def test_no_allowed_global_allocates_from_a_number(payload, message):
    with pytest.raises(UnsafePickleError, match=message):
        loads_restricted(payload)


class _LyingArray:
    """Pickles as numpy does (``_reconstruct`` + ``BUILD``), with a declared shape its data does not fill."""

    def __init__(self, shape: tuple[int, ...], dtype: str, data: object) -> None:
        self.state = (1, shape, np.dtype(dtype), False, data)

    def __reduce__(self):
        from numpy._core.multiarray import _reconstruct

        return _reconstruct, (np.ndarray, (0,), b"b"), self.state


def test_array_states_and_newobj_are_checked_before_allocating():
    for lying in (_LyingArray((10**9,), "O", [1]), _LyingArray((10**5, 10**5), "f8", b"\0" * 8)):
        with pytest.raises(UnsafePickleError, match="Refusing an array"):
            loads_restricted(pickle.dumps(lying, protocol=2))
    honest = loads_restricted(pickle.dumps(_LyingArray((2,), "O", [1, "x"]), protocol=2))
    assert honest.tolist() == [1, "x"]
    # NEWOBJ (cls.__new__(cls, *args)) with arguments is refused
    newobj = b"\x80\x02cnumpy\nndarray\nJ\x00\xca\x9a;\x85\x81."
    with pytest.raises(UnsafePickleError, match="__new__ with arguments"):
        loads_restricted(newobj)
    # plain arrays, dicts and protocol-2 bytes still load
    value = {"a": np.arange(6.0).reshape(2, 3), "b": [1, 2.5, "x"], "c": b"\x00\xff"}
    for protocol in (0, 2, 4, 5):
        back = loads_restricted(pickle.dumps(value, protocol=protocol), encoding="latin1")
        np.testing.assert_array_equal(back["a"], value["a"])
        assert back["b"] == value["b"] and back["c"] == value["c"]


def test_smpl_pkl_and_estimator_pickles_share_the_unpickler(tmp_path):
    import workflows.estimators.phalp as reader

    # One restricted unpickler: smplik.safe_pickle; the estimator readers load with it (no copy in workflows).
    assert reader.load_pickle is load_pickle
    assert not any(Path(reader.__file__).parents[1].rglob("safe_pickle.py"))
    marker = tmp_path / "ran"
    payload = tmp_path / "SMPL_NEUTRAL.pkl"
    payload.write_bytes(_pickle_of_call("os", "system", f"V touch {marker}\n".encode()))
    with pytest.raises(ModelFileError, match=f"{payload}: Refusing to load global 'os.system'"):
        read_model_arrays(payload)
    with pytest.raises(UnsafePickleError, match="os.system"):
        load_pickle(payload)
    assert not marker.exists()


# ----------------------------------------------------------------------------- 11.6 temp files, npz writer


def test_stale_temp_files_of_dead_writers_are_removed_on_the_next_write(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)
    target = tmp_path / "pose.json"
    stale = tmp_path / f".pose.json.{dead_pid}-abcd1234.tmp.json"
    old_style = tmp_path / ".pose.json.zz9_xy12.tmp.json"
    live = tmp_path / f".pose.json.{os.getpid()}-live0000.tmp.json"
    other = tmp_path / f".other.json.{dead_pid}-abcd1234.tmp.json"
    for p in (stale, old_style, live, other):
        p.write_text("partial")
    os.utime(old_style, (time.time() - 7200, time.time() - 7200))
    write_json_atomic(target, {"ok": 1})
    assert json.loads(target.read_text()) == {"ok": 1}
    assert not stale.exists() and not old_style.exists()
    assert live.exists() and other.exists()  # a live writer's file, another target's file
    assert remove_stale_temp_files(tmp_path / "other.json") == [other]


def test_deterministic_npz_bytes_depend_only_on_the_arrays(tmp_path):
    arrays = {"b": np.arange(5.0), "a": np.array("neutral"), "c": np.eye(3, dtype=np.float32)[::2]}
    one = write_npz_deterministic(tmp_path / "one.npz", arrays).read_bytes()
    time.sleep(1.1)  # not a timing assumption: a later clock must not change the bytes (zip entry times)
    two = write_npz_deterministic(tmp_path / "two.npz", dict(reversed(arrays.items()))).read_bytes()
    assert one == two
    with np.load(tmp_path / "one.npz") as data:
        assert data["a"].shape == () and str(data["a"]) == "neutral"
        np.testing.assert_array_equal(data["c"], arrays["c"])


# ----------------------------------------------------------------------------- 11.3 one-line CLI errors


@pytest.mark.slow
def test_user_mistakes_are_one_stderr_line(tmp_path):
    (tmp_path / "a[").mkdir()
    eff = tmp_path / "a[" / "red].json"  # its path holds '[/red]', rich markup if printed unescaped
    eff.write_text(json.dumps([{"joint": "head", "type": "position", "value": [0, 1.6, 0]}]))
    empty = tmp_path / "empty_models"
    empty.mkdir()
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    cases = [
        (["body", "info", "--model-dir", str(empty)], "No SMPL neutral model in"),
        (["solve", str(tmp_path / "a[" / "red].deep.json"), "--out", str(tmp_path / "o.json")], "a[/red].deep.json"),
        (["solve", str(tmp_path / "a[" / "red].missing.json"), "--out", str(tmp_path / "o.json")], "not found"),
        (["solve", str(eff), "--out", str(a_file / "pose.json"), "--refine-steps", "0"], "not a folder"),
        (["solve", str(eff), "--out", str(tmp_path), "--refine-steps", "0"], "is a folder"),
    ]
    (tmp_path / "a[" / "red].deep.json").write_text("[" * 50_000)
    for args, expected in cases:
        line = one_error_line(run_cli(*args))
        assert expected in line, line


def test_a_bug_keeps_its_traceback():
    import typer

    from smplik.cli.errors import is_user_error, run_guarded

    app = typer.Typer()

    @app.command()
    def boom() -> None:
        raise KeyError("a bug")

    with pytest.raises(KeyError):
        run_guarded(app, [])
    assert not is_user_error(KeyError("x")) and not is_user_error(TypeError("x"))
    assert is_user_error(ModelFileError("x")) and is_user_error(IsADirectoryError(21, "x", "f"))


def test_bad_image_for_scene_render_is_one_line(scene_dict, tmp_path):
    from smplik.cli.main import app

    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(scene_dict))
    image = tmp_path / "photo.png"
    image.write_bytes(b"not a png")
    res = CliRunner().invoke(app, ["scene", "render", str(scene), "--out", str(tmp_path / "o.png"),
                                   "--image", str(image)])
    assert res.exit_code == 1 and isinstance(res.exception, SystemExit), res.output
    assert f"{image}: not a readable image" in " ".join(res.output.split())


# ----------------------------------------------------------------------------- 16.6 / 16.7 reports and renders


def test_solve_prints_each_effectors_residual(tmp_path, solver):
    from smplik.cli.main import app

    eff = tmp_path / "eff.json"
    eff.write_text(json.dumps([{"joint": "left_wrist", "type": "position", "value": [0.45, 1.1, 0.2]},
                               {"joint": "pelvis", "type": "rotation", "value": np.eye(3).tolist()},
                               {"joint": "head", "type": "look_at", "target": [0.0, 1.6, 2.0]}]))
    res = CliRunner().invoke(app, ["solve", str(eff), "--out", str(tmp_path / "pose.json")])
    assert res.exit_code == 0, res.output
    text = res.output
    assert "after the network and 3 refinement steps" in text
    for joint, unit in (("left_wrist position", "mm"), ("pelvis rotation", "deg"), ("head look_at", "deg")):
        line = next(line for line in text.splitlines() if joint in line)
        assert unit in line and "network" in line
    # the refinement's printed result is the pose's own residual
    from smplik.pose import Pose
    from smplik.solver import effector_residuals

    pose = Pose.load(tmp_path / "pose.json")
    wrist = effector_residuals(pose, [Effector.position("left_wrist", [0.45, 1.1, 0.2])], solver.bodies)[0]
    line = next(line for line in text.splitlines() if "left_wrist position" in line)
    assert f"{wrist.value:.1f} mm" in line




@needs_gl
def test_body_render_uses_the_pose_gender_and_one_scale(tmp_path):
    import matplotlib.image

    from smplik.cli.main import app
    from smplik.pose import Pose

    pose = Pose(np.zeros(3), np.zeros((23, 3)), np.zeros(3), np.zeros(10), gender=__import__(
        "smplik.conventions", fromlist=["Gender"]).Gender.FEMALE)
    pose.save(tmp_path / "pose.json")
    res = CliRunner().invoke(app, ["body", "render", "--pose", str(tmp_path / "pose.json"), "--out",
                                   str(tmp_path / "b.png"), "--width", "400", "--height", "400"])
    assert res.exit_code == 0, res.output
    assert "female body" in res.output
    img = matplotlib.image.imread(tmp_path / "b.png")[..., :3]
    heights = []
    for panel in (img[:, :200], img[:, 200:]):
        rows = np.flatnonzero((panel < 0.95).any(axis=(1, 2)))
        heights.append(rows.max() - rows.min())
    assert abs(heights[0] - heights[1]) <= 2, heights  # front and side at one scale: same stature in pixels


@needs_gl
def test_markers_stay_visible_inside_a_mesh():
    import trimesh

    from smplik.render import MeshItem, Sphere, View, render

    box = trimesh.creation.box(extents=(0.4, 0.4, 0.4))
    mesh = MeshItem(box.vertices, box.faces, color=(0.2, 0.2, 0.2, 1.0))
    marker = Sphere((0.0, 0.0, 0.0), radius=0.1, color=(1.0, 0.0, 0.0, 1.0))
    on_top = render([mesh], [marker], size=(64, 64), view=View())
    hidden = render([mesh], [marker], size=(64, 64), view=View(), markers_on_top=False)
    r_on, r_hidden = on_top[32, 32].astype(int), hidden[32, 32].astype(int)
    assert r_on[0] - r_on[1] > 100  # red shows through the box
    assert abs(r_hidden[0] - r_hidden[1]) < 20  # without it, the grey box hides the marker
