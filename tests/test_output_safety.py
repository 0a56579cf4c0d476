"""Security round 4 (issue #45), outputs and readers: outputs never touch inputs, a failed or killed run leaves
all-old or all-new files and no empty folder, glTF/VRM/Draco limits before the work, Ctrl-C and malformed HTTP.

Each recipe of the issue runs the real CLI in a subprocess on small generated files and checks the one ``error:``
line, the exit status, that every input is byte-identical afterwards and that no temporary or empty folder is
left. Kill and Ctrl-C checks signal the child at a point it is known to have reached (a file it creates, a
library it mapped), found by polling, never after a fixed sleep.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
POLL_LIMIT_S = 600.0
"""How long a poll waits for a condition before the test fails (a hung child), never a timing assertion."""


def run_cli(*args: str, env: dict[str, str] | None = None, cwd: Path | None = None) -> tuple[int, list[str]]:
    """``python -m smplik.cli ARGS``: (exit status, non-empty stderr lines)."""
    proc = subprocess.run([sys.executable, "-m", "smplik.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or ROOT, env={**os.environ, "PYTHONPATH": str(ROOT), **(env or {})},
                          timeout=900)
    return proc.returncode, [ln for ln in proc.stderr.splitlines() if ln.strip()]


def assert_refused(args: list, *needles: str) -> str:
    rc, lines = run_cli(*args)
    assert rc == 1, lines
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def digest(folder: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file under ``folder`` (hidden ones included)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(parent: Path) -> list[str]:
    """Temporary folders and files of ours under ``parent``."""
    return [str(p) for p in parent.rglob("*") if ".smplik-" in p.name or ".tmp" in p.name]


def trackers_doc(frames: int = 20) -> dict:
    """A ``smplik-trackers`` recording of a person standing still (head, wrists, pelvis; metres, y-up)."""
    still = {"head": [0.0, 1.6, 0.0], "left_wrist": [0.25, 0.85, 0.05], "right_wrist": [-0.25, 0.85, 0.05],
             "pelvis": [0.0, 0.95, 0.0]}
    trackers = {name: {"position": [list(p)] * frames, "rotation": [[1.0, 0.0, 0.0, 0.0]] * frames}
                for name, p in still.items()}
    return {"format": "smplik-trackers", "version": 1, "fps": 60, "trackers": trackers}


@pytest.fixture(scope="module")
def material(shipped_solver, tmp_path_factory) -> dict[str, Path]:
    """A trackers file, a Mixamo BVH character and a scene with effectors (files only; nothing solved)."""
    from helpers import demo_scene

    from workflows.layout_examples import smpl_rest, write_mixamo_bvh
    from workflows.scene.document import save_scene

    folder = tmp_path_factory.mktemp("material")
    trackers = folder / "trackers.json"
    trackers.write_text(json.dumps(trackers_doc()))
    bvh = write_mixamo_bvh(folder / "hero.bvh", smpl_rest()[0])
    scene = save_scene(demo_scene(shipped_solver), folder / "scene.json")
    return {"trackers": trackers, "bvh": bvh, "scene": scene}


# ----------------------------------------------------------------------------- O1-O4: outputs never touch inputs


def test_O1_track_refuses_to_write_its_recording(material, tmp_path):
    out = tmp_path / "OUT"
    out.mkdir()
    src = out / "animation.json"  # the recording sits where the command writes animation.json
    src.write_bytes(material["trackers"].read_bytes())
    before = digest(out)
    assert_refused(["track", src, "--out", out], "animation.json", "would overwrite the input")
    assert digest(out) == before and not leftovers(tmp_path)
    # the same through a symlinked output folder
    (tmp_path / "link").symlink_to(out, target_is_directory=True)
    assert_refused(["track", src, "--out", tmp_path / "link"], "would overwrite the input")
    assert digest(out) == before and not leftovers(tmp_path)


def test_O2_track_refuses_to_export_over_its_character(material, tmp_path):
    out = tmp_path / "OUT"
    out.mkdir()
    character = out / "person_0.bvh"
    character.write_bytes(material["bvh"].read_bytes())
    before = digest(out)
    assert_refused(["track", material["trackers"], "--character", character, "--out", out, "--export", "bvh"],
                   "person_0.bvh", "would overwrite the input")
    assert digest(out) == before and not leftovers(tmp_path)


def test_O3_variants_refuse_to_overwrite_their_scene(material, tmp_path):
    out = tmp_path / "OUT"
    out.mkdir()
    scene = out / "variant_0.json"
    scene.write_bytes(material["scene"].read_bytes())
    before = digest(out)
    assert_refused(["scene", "variants", scene, "--out", out, "--k", "2"], "variant_0.json",
                   "would overwrite the input")
    assert digest(out) == before and not leftovers(tmp_path)


def test_O4_export_refuses_to_overwrite_the_scenes_skeleton(material, tmp_path):
    import dataclasses

    from workflows.scene.characters import SkeletonSource
    from workflows.scene.document import load_scene, save_scene

    out = tmp_path / "OUT"
    out.mkdir()
    (out / "person_0.bvh").write_bytes(material["bvh"].read_bytes())
    scene = load_scene(material["scene"])
    chars = list(scene.characters)
    chars[0] = dataclasses.replace(chars[0], skeleton=SkeletonSource("person_0.bvh"))
    save_scene(dataclasses.replace(scene, characters=tuple(chars)), out / "scene.json")
    before = digest(out)
    line = assert_refused(["scene", "export", out / "scene.json", "--out", out], "person_0.bvh",
                          "would overwrite the input")
    assert str(out / "person_0.bvh") in line
    assert digest(out) == before and not leftovers(tmp_path)


def test_edit_keyframe_refuses_to_export_over_the_tracks_skeleton(material, tmp_path):
    out, first = tmp_path / "OUT", tmp_path / "first"
    out.mkdir()
    character = out / "person_0.bvh"
    character.write_bytes(material["bvh"].read_bytes())
    rc, lines = run_cli("track", material["trackers"], "--character", character, "--out", first, "--export", "")
    assert rc == 0, lines
    effectors = tmp_path / "e.json"
    effectors.write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [
        {"joint": "left_wrist", "type": "position", "value": [0.3, 1.2, 0.2]}]}))
    before, anim = digest(out), (first / "animation.json").read_bytes()
    assert_refused(["scene", "edit-keyframe", first / "animation.json", "--frame", "0", "--effectors", effectors,
                    "--out", out / "edited.json", "--export", "bvh"], "person_0.bvh", "would overwrite the input")
    assert digest(out) == before and (first / "animation.json").read_bytes() == anim and not leftovers(tmp_path)


def test_render_refuses_a_scene_image_that_is_a_device_and_its_own_image_as_output(material, tmp_path):
    import dataclasses

    from workflows.estimators.base import CameraInfo
    from workflows.scene.document import load_scene, save_scene

    scene = dataclasses.replace(load_scene(material["scene"]), camera=CameraInfo(image_size=(64, 48)))
    bad = save_scene(dataclasses.replace(scene, image="/dev/zero"), tmp_path / "s.json")
    assert_refused(["scene", "render", bad, "--out", tmp_path / "r.png"], "/dev/zero", "not a regular file")
    assert not (tmp_path / "r.png").exists()
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"\x89PNG not really")
    own = save_scene(dataclasses.replace(scene, image=str(photo)), tmp_path / "own.json")
    assert_refused(["scene", "render", own, "--out", photo], "photo.png", "would overwrite the input")
    assert photo.read_bytes() == b"\x89PNG not really"


def test_a_refused_estimate_leaves_no_output_folder(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not a zip")
    out = tmp_path / "new" / "deeper" / "OUT"
    rc, lines = run_cli("scene", "from-estimate", bad, "--out", out, "--no-previews")
    assert rc == 1 and len(lines) == 1 and lines[0].startswith("error: ") and "bad.npz" in lines[0], lines
    assert not (tmp_path / "new").exists() and not leftovers(tmp_path)


def test_data_build_refuses_to_write_over_a_clip_it_reads(tmp_path):
    src = tmp_path / "amass"
    src.mkdir()
    frames = 20
    poses = np.zeros((frames, 72))
    poses[:, 0] = np.pi / 2
    for name in ("clip0", "clip1"):  # AMASS's layout (poses, trans, betas, gender, mocap_framerate)
        np.savez(src / f"{name}_poses.npz", poses=poses, trans=np.zeros((frames, 3)), betas=np.zeros(10),
                 gender="neutral", mocap_framerate=30.0)
    before = digest(src)
    assert_refused(["data", "build", "--amass", src, "--out", src / "clip1_poses.npz"], "clip1_poses.npz",
                   "would overwrite the input")
    assert digest(src) == before


def test_a_preview_naming_a_folder_is_refused_before_the_work(tmp_path):
    folder = tmp_path / "p.gif"
    folder.mkdir()
    src = tmp_path / "missing_results.npz"  # never read: the preview path is refused first
    assert_refused(["scene", "animate", src, "--out", tmp_path / "OUT", "--preview", folder], "p.gif", "folder")
    assert not (tmp_path / "OUT").exists()


# ----------------------------------------------------------------------------- all-or-nothing (library)


def test_staged_folder_writes_everything_or_nothing(tmp_path):
    from smplik.output_files import OutputPathError, staged_folder

    out = tmp_path / "a" / "b" / "OUT"
    with pytest.raises(RuntimeError), staged_folder(out) as stage:
        (stage.dir / "variant_0.json").write_text("{}")
        raise RuntimeError("the second variant fails")
    assert not (tmp_path / "a").exists() and not leftovers(tmp_path)  # no file, no empty folder
    with staged_folder(out) as stage:
        (stage.dir / "x.json").write_text("1")
        (stage.dir / "y.json").write_text("1")
    assert digest(out) == digest(out) and sorted(os.listdir(out)) == ["x.json", "y.json"]
    (out / "mine.txt").write_text("a user's file")
    inode = (out / "mine.txt").stat().st_ino
    with staged_folder(out, reads=[out / "mine.txt"]) as stage:
        (stage.dir / "x.json").write_text("2")
    assert (out / "x.json").read_text() == "2" and (out / "y.json").read_text() == "1"
    assert (out / "mine.txt").stat().st_ino == inode and not leftovers(tmp_path)
    with pytest.raises(OutputPathError, match="mine.txt"), staged_folder(out, reads=[out / "mine.txt"]) as stage:
        (stage.dir / "mine.txt").write_text("overwritten")
    assert (out / "mine.txt").read_text() == "a user's file" and not leftovers(tmp_path)
    with staged_folder(tmp_path / "empty") as stage:
        pass  # nothing written: no folder either
    assert not (tmp_path / "empty").exists()


_KILLED_WRITER = """
import sys
from pathlib import Path
import smplik.output_files as of
if sys.argv[2] == "journal":
    of._exchange = lambda a, b: False  # another file system: the journaled commit
with of.staged_folder(Path(sys.argv[1])) as stage:
    for name in ("a.bvh", "b.bvh", "c.glb"):
        (stage.dir / name).write_text("new " + name)
"""


def _wait_for(condition, what: str, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + POLL_LIMIT_S
    while not condition():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the child ended ({proc.returncode}) before {what}: {proc.stderr.read()}")
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        time.sleep(0.01)


@pytest.mark.parametrize("point,mode,expect", [("swap", "swap", "old"), ("swapped", "swap", "new"),
                                               ("moved", "journal", "new")])
def test_a_writer_killed_mid_commit_leaves_all_old_or_all_new(tmp_path, point, mode, expect):
    out = tmp_path / "OUT"
    out.mkdir()
    for name in ("a.bvh", "b.bvh", "c.glb"):
        (out / name).write_text("old " + name)
    (out / "notes.txt").write_text("the user's")
    flag = tmp_path / "flag"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(out), mode], stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT), "_SMPLIK_TEST_COMMIT_HOOK": f"{point}:{flag}"})
    _wait_for(flag.exists, f"the commit point {point}", proc)
    proc.kill()
    proc.wait()
    from smplik.output_files import recover_stale_stages

    if mode == "journal":  # the fallback: mixed until the next write to OUT finishes the journaled move
        recover_stale_stages(out)
    else:  # the folder swap: all-old or all-new the moment the writer dies
        assert {(out / n).read_text().split()[0] for n in ("a.bvh", "b.bvh", "c.glb")} == {expect}
        recover_stale_stages(out)  # what the next write does first: drop the dead writer's folder
    assert {(out / n).read_text() for n in ("a.bvh", "b.bvh", "c.glb")} == {f"{expect} {n}" for n in
                                                                              ("a.bvh", "b.bvh", "c.glb")}
    assert (out / "notes.txt").read_text() == "the user's" and not leftovers(tmp_path)


@pytest.fixture(scope="module")
def gvhmr_file(tmp_path_factory) -> Path:
    torch = pytest.importorskip("torch")
    folder = tmp_path_factory.mktemp("video")
    L = 24
    rng = np.random.default_rng(0)
    aa = np.zeros((L, 24, 3))
    aa[:, 0] = [np.pi, 0.0, 0.0]
    aa[:, 1:] = rng.normal(0, 0.05, (L, 23, 3))
    transl = np.tile([0.0, 0.3, 4.0], (L, 1))

    def params(a: np.ndarray, t: np.ndarray) -> dict:
        return {"body_pose": torch.tensor(a[:, 1:22].reshape(L, 63), dtype=torch.float32),
                "global_orient": torch.tensor(a[:, 0], dtype=torch.float32),
                "transl": torch.tensor(t, dtype=torch.float32), "betas": torch.zeros(L, 10)}

    # GVHMR's hmr4d_results.pt layout (zju3dv/GVHMR demo.py: smpl_params_global/incam, K_fullimg)
    pred = {"smpl_params_global": params(aa, transl), "smpl_params_incam": params(aa, transl),
            "K_fullimg": torch.tensor([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1.0]]).expand(L, 3, 3).clone(),
            "net_outputs": {"pred_cam": torch.zeros(L, 3)}}
    path = folder / "hmr4d_results.pt"
    torch.save(pred, path)
    return path


@pytest.mark.slow
def test_scene_animate_export_killed_while_committing_is_all_old_then_all_new(gvhmr_file, tmp_path):
    args = ["scene", "animate", gvhmr_file, "--fps", "30", "--max-effectors", "2", "--export", "bvh,glb",
            "--smoothing", "none"]
    out, ref = tmp_path / "OUT", tmp_path / "REF"
    rc, lines = run_cli(*args, "--out", out, "--keyframe-threshold", "0.5")  # the old files
    assert rc == 0, lines
    old = digest(out)
    rc, lines = run_cli(*args, "--out", ref)  # what the new run writes (the same command, another folder)
    assert rc == 0, lines
    new = digest(ref)
    assert old.keys() == new.keys() and old != new
    for point, expect in (("swap", old), ("swapped", new)):
        flag = tmp_path / f"flag_{point}"
        proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", *map(str, args), "--out", str(out)],
                                stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONPATH": str(ROOT),
                                     "_SMPLIK_TEST_COMMIT_HOOK": f"{point}:{flag}"})
        _wait_for(flag.exists, f"scene animate's commit point {point}", proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert digest(out) == expect, point  # every file of one run, never a mix
    rc, lines = run_cli(*args, "--out", out)  # the next run removes what the killed one left
    assert rc == 0 and digest(out) == new and not leftovers(tmp_path)


# ----------------------------------------------------------------------------- Ctrl-C


def _sigint_when(args: list, condition) -> tuple[int, list[str]]:
    proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", *map(str, args)], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _wait_for(lambda: condition(proc.pid), "the point to interrupt", proc)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=POLL_LIMIT_S)
    return proc.returncode, [ln for ln in err.splitlines() if ln.strip()]


def _mapped(pid: int, library: str) -> bool:
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see what the child has loaded")
def test_ctrl_c_during_imports_and_mid_run_gives_one_line_and_130(material, tmp_path):
    out = tmp_path / "OUT"
    args = ["track", material["trackers"], "--out", out]
    for condition in (lambda pid: _mapped(pid, "libtorch"),  # while (or right after) torch is imported
                      lambda pid: any(tmp_path.glob(".OUT.smplik-*.tmp"))):  # mid-run: its files being made
        rc, lines = _sigint_when(args, condition)
        assert rc == 130, lines
        assert lines == ["error: interrupted (Ctrl-C): stopped; no file was left half-written."], lines
        assert not out.exists() and not leftovers(tmp_path)


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see what the child has loaded")
@pytest.mark.parametrize("library", ["_multiarray_umath", "libtorch", "scipy"])
def test_ctrl_c_during_scene_animates_imports_gives_one_line_and_130(gvhmr_file, tmp_path, library):
    """``scene animate`` imports numpy, scipy and torch inside the command (``--help`` imports none): a SIGINT
    once the child has mapped numpy's core (the first heavy import), torch or scipy (found by polling
    /proc/PID/maps) is one line and exit 130, with no output folder left."""
    out = tmp_path / "OUT"
    rc, lines = _sigint_when(["scene", "animate", gvhmr_file, "--out", out], lambda pid: _mapped(pid, library))
    assert rc == 130, lines
    assert lines == ["error: interrupted (Ctrl-C): stopped; no file was left half-written."], lines
    assert not out.exists() and not leftovers(tmp_path)


def test_a_ctrl_c_swallowed_by_a_finalizer_stops_the_run(monkeypatch, capsys):
    """Python reports a KeyboardInterrupt raised in ``__del__`` as "Exception ignored in ..." (4 lines) and carries
    on; smplik's hook raises it again in the main thread instead, silently."""
    from smplik.cli.interrupt import unraisable_hook

    class Finalizer:
        def __del__(self) -> None:
            raise KeyboardInterrupt

    monkeypatch.setattr(sys, "unraisablehook", unraisable_hook)
    steps = [0]
    with pytest.raises(KeyboardInterrupt):
        Finalizer()  # collected at once: its __del__'s Ctrl-C is "unraisable"
        while steps[0] < 10**9:  # the run would go on (minutes); the re-raised interrupt stops it here
            steps[0] += 1
    assert steps[0] < 10**9
    assert "Exception ignored" not in capsys.readouterr().err


# ----------------------------------------------------------------------------- glTF / VRM / Draco


def _gltf(path: Path, nodes: list, skins: list | None = None, extensions: dict | None = None) -> Path:
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes}
    if skins is not None:
        doc["skins"] = skins
    if extensions:
        doc["extensions"] = extensions
    path.write_text(json.dumps(doc))
    return path


def test_GW_composed_world_matrices_are_checked(tmp_path):
    nodes = [{"name": "root", "matrix": [1e150, 0, 0, 0, 0, 1e150, 0, 0, 0, 0, 1e150, 0, 0, 0, 0, 1], "children": [1]},
             {"name": "hips", "scale": [1e200, 1e200, 1e200], "children": [2]},
             {"name": "spine", "translation": [0, 1, 0]}]
    src = _gltf(tmp_path / "gw.gltf", nodes, [{"joints": [1, 2]}])
    before = src.read_bytes()
    assert_refused(["invert-shape", src, "--out", tmp_path / "s.json", "--bind", "nodes"], "gw.gltf",
                   "world transform")
    src2 = _gltf(tmp_path / "gw2.gltf", [{**nodes[0], "matrix": [1e6, 0, 0, 0, 0, 1e6, 0, 0, 0, 0, 1e6, 0, 0, 0, 0, 1]},
                                         {**nodes[1], "scale": [1e7, 1e7, 1e7]}, nodes[2]], [{"joints": [1, 2]}])
    assert_refused(["invert-shape", src2, "--out", tmp_path / "s.json"], "gw2.gltf", "node 1")  # 1e13: each finite
    assert src.read_bytes() == before and not (tmp_path / "s.json").exists()


def test_GJ_joint_and_node_limits_apply_before_parsing(tmp_path, monkeypatch):
    n = 100_000
    chain = [{"name": f"j{i}", "translation": [0, 0.01, 0], **({"children": [i + 1]} if i < n - 1 else {})}
             for i in range(n)]
    deep = _gltf(tmp_path / "chain.gltf", chain, [{"joints": list(range(n))}])
    assert_refused(["invert-shape", deep, "--out", tmp_path / "s.json"], "chain.gltf", "100000 joints", "10000")
    small = _gltf(tmp_path / "small.gltf", chain[:30] + [{"name": "j30"}], [{"joints": list(range(31))}])
    assert_refused(["invert-shape", small, "--out", tmp_path / "s.json", "--max-joints", "10"], "small.gltf",
                   "31 joints", "limit 10")
    extra = [{"name": "a", "children": [1]}, {"name": "b", "translation": [0, 1, 0], "children": [2]},
             {"name": "c", "translation": [0, 1, 0]}] + [{"name": f"x{i}"} for i in range(200_000)]
    wide = _gltf(tmp_path / "wide.gltf", extra, [{"joints": [0, 1, 2]}])
    assert_refused(["invert-shape", wide, "--out", tmp_path / "s.json"], "wide.gltf", "SMPLIK_MAX_GLTF_NODES")
    # in process: refused from the JSON counts, before pygltflib parses anything
    import pygltflib

    from shape_inversion.skeleton_io import SkeletonError, read_skeleton

    def never(*args, **kwargs):
        raise AssertionError("pygltflib parsed a file the limits refuse")

    monkeypatch.setattr(pygltflib.GLTF2, "load_json", staticmethod(never))
    for path, kwargs in ((deep, {}), (wide, {}), (small, {"max_joints": 10})):
        with pytest.raises(SkeletonError):
            read_skeleton(path, **kwargs)


def test_node_hierarchy_depths_are_linear_and_equal_the_naive_count():
    from shape_inversion.gltf_io import _depths

    rng = np.random.default_rng(3)
    n = 300
    parent = tuple([-1] + [int(rng.integers(0, i)) for i in range(1, n)])
    members = [int(m) for m in rng.choice(n, 120, replace=False)]
    index = {m: k for k, m in enumerate(members)}

    def naive(m: int) -> int:
        d, p = 0, parent[m]
        while p >= 0:
            d, p = d + (p in index), parent[p]
        return d

    assert _depths(parent, members, index) == [naive(m) for m in members]


@pytest.mark.parametrize("extensions,needle", [({"VRMC_vrm": {"humanoid": ["x"]}}, "VRMC_vrm.humanoid"),
                                               ({"VRM": {"humanoid": "abc"}}, "VRM.humanoid"),
                                               ({"VRM": [1]}, "extensions.VRM")])
def test_VR_vrm_tables_of_the_wrong_type(tmp_path, extensions, needle):
    src = _gltf(tmp_path / "v.vrm.gltf", [{"name": "a", "children": [1]}, {"name": "b", "translation": [0, 1, 0]}],
                None, extensions)
    assert_refused(["invert-shape", src, "--out", tmp_path / "s.json"], "v.vrm.gltf", needle, "must be an object")


def test_DB_a_draco_buffer_declaring_3e8_points_is_refused_before_decoding(tmp_path):
    pytest.importorskip("DracoPy", reason="pip install 'smplik[draco]' for Draco-compressed glTF meshes")
    import DracoPy
    import pygltflib

    from shape_inversion.gltf_io import GltfError, draco_declared_counts
    from shape_inversion.skeleton_io import read_skeleton
    from workflows.character_mesh import skinned_mesh
    from workflows.layout_examples import smpl_rest, write_mixamo_gltf

    # the header reader agrees with DracoPy's encoder (google/draco's bitstream 2.2 / point cloud 2.3)
    pts = np.random.default_rng(0).random((10, 3)).astype(np.float32)
    tri = np.array([[0, 1, 2], [2, 3, 4]])
    assert draco_declared_counts(DracoPy.encode(pts), "x") == (10, 0)
    assert draco_declared_counts(DracoPy.encode(pts, faces=tri, preserve_order=True), "x") == (10, 2)
    assert draco_declared_counts(DracoPy.encode(pts, faces=tri), "x")[1] == 2
    # 64 bytes: a point cloud that declares 3e8 points, on a skinned mesh's primitive
    bomb = bytearray(DracoPy.encode(pts))
    bomb[11:15] = (300_000_000).to_bytes(4, "little")
    bomb = bytes(bomb[:64].ljust(64, b"\0"))
    assert draco_declared_counts(bomb, "x") == (300_000_000, 0)
    J, V, F, W = smpl_rest()
    src = write_mixamo_gltf(tmp_path / "c.glb", J, (V, F, W))
    g = pygltflib.GLTF2().load(str(src))
    blob = bytearray(g.binary_blob())
    while len(blob) % 4:
        blob.append(0)
    g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(bomb)))
    blob.extend(bomb)
    prim = g.meshes[0].primitives[0]
    prim.extensions = {"KHR_draco_mesh_compression": {"bufferView": len(g.bufferViews) - 1,
                                                      "attributes": {"POSITION": 0, "JOINTS_0": 1, "WEIGHTS_0": 2}}}
    g.buffers[0].byteLength = len(blob)
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(tmp_path / "bomb.glb"))
    with pytest.raises(GltfError, match=r"bomb.glb.*declares 300000000 vertices"):
        skinned_mesh(read_skeleton(tmp_path / "bomb.glb").gltf)
    # through the real command: a scene whose character is bomb.glb (a path relative to the scene's folder, the
    # command run from another folder: the own mesh was silently skipped there before), under a 3 GiB cap
    from workflows.character import CharacterOptions
    from workflows.examples_gen import example_poses
    from workflows.scene import Scene, SceneCharacter, SkeletonSource
    from workflows.scene.document import save_scene

    pose = example_poses()[0].pose
    save_scene(Scene((SceneCharacter("hero", pose.gender, pose.betas, 1.0,
                                     SkeletonSource.from_options("bomb.glb", CharacterOptions()), (), pose),)),
               tmp_path / "scene.json")
    assert json.loads((tmp_path / "scene.json").read_text())["characters"][0]["skeleton"]["path"] == "bomb.glb"
    proc = subprocess.run(["bash", "-c", 'ulimit -v 3145728 && exec "$@"', "-", sys.executable, "-m", "smplik.cli",
                           "scene", "render", str(tmp_path / "scene.json"), "--out", str(tmp_path / "r.png")],
                          capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                          timeout=900)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), lines
    assert "bomb.glb" in lines[0] and "declares 300000000 vertices" in lines[0] and "2000000" in lines[0], lines
    assert not (tmp_path / "r.png").exists()


# ----------------------------------------------------------------------------- errors name the file


def test_a_4300_digit_number_names_the_file(tmp_path):
    src = tmp_path / "effectors.json"
    src.write_text('{"format": "smplik-effectors", "effectors": [{"joint": ' + "9" * 5000 + "}]}")
    line = assert_refused(["solve", src, "--out", tmp_path / "o.json"], "effectors.json")
    assert "9999999999" not in line


def test_a_gltf_zero_quaternion_names_the_file_and_node(tmp_path):
    """A node ``rotation`` [0, 0, 0, 0] (scipy's "Found zero norm quaternions" if it reached Rotation.from_quat)."""
    src = _gltf(tmp_path / "q0.gltf", [{"name": "Hips", "rotation": [0, 0, 0, 0], "children": [1]},
                                       {"name": "Spine", "translation": [0, 1, 0]}], [{"joints": [0, 1]}])
    for bind in ("inverse_bind", "nodes"):
        line = assert_refused(["invert-shape", src, "--out", tmp_path / "s.json", "--bind", bind], "q0.gltf",
                              "nodes[0]", "rotation", "zero quaternion")
        assert "Found zero norm" not in line


@pytest.mark.parametrize("key", ["skeleton.path", "skeleton.map", "image", "source"])
def test_a_nul_character_in_a_scene_path_names_the_file_and_key(material, tmp_path, key):
    """"a\u0000b.glb" as a scene's skeleton, rig map, image or source: the OS would say "embedded null byte"
    (or, for ``scene render``, the file was silently skipped)."""
    data = json.loads(material["scene"].read_text())
    if key.startswith("skeleton"):
        data["characters"][0]["skeleton"] = {"path": "hero.bvh", key.split(".")[1]: "a\u0000b.glb"}
    else:
        data[key] = "a\u0000b.png"
    src = tmp_path / "scene.json"
    src.write_text(json.dumps(data))
    where = f"characters[0].{key}" if key.startswith("skeleton") else key
    for command in ("render", "export"):
        out = tmp_path / ("r.png" if command == "render" else "OUT")
        line = assert_refused(["scene", command, src, "--out", out], "scene.json", where, "NUL character")
        assert "embedded null byte" not in line and not out.exists()


@pytest.mark.parametrize("camera,body,needle", [(0.0, None, "singular values"), (1e200, None, "an entry of 1e+200"),
                                                 (None, 0.0, "singular values")])
def test_degenerate_estimator_rotation_matrices_name_the_file_and_key(tmp_path, camera, body, needle):
    """TRAM's SLAM camera rotations (``camera.npy`` ``pred_cam_R``) or body rotations (``pred_rotmat``) that are
    zero or huge: projected by an SVD (numpy's "SVD did not converge" on huge entries) into an invented pose before;
    now one line naming the file and key. The fixture writes TRAM's own layout (tests/estimator_fixtures.py)."""
    from estimator_fixtures import people, write_tram

    aa, transl, betas = people()[:3]
    _, paths = write_tram(tmp_path, aa, transl, betas, cam_R=None if camera is None else np.full((4, 3, 3), camera))
    key = "pred_cam_R[0]" if camera is not None else "pred_rotmat"
    if body is not None:
        import torch

        data = np.load(paths[0], allow_pickle=True).item()
        data["pred_rotmat"] = torch.full_like(data["pred_rotmat"], body)
        np.save(paths[0], data)
    where = "camera.npy" if camera is not None else "hps_track_0.npy"
    out = tmp_path / "OUT"
    assert_refused(["scene", "animate", paths[0], "--fps", "30", "--space", "world", "--out", out], where,
                   f"'{key}'", "not a rotation", needle)
    assert not out.exists()


def test_a_library_error_without_a_file_gets_the_commands_inputs(capsys, tmp_path):
    """numpy's "SVD did not converge" (a LinAlgError) from deep inside a command: the line names its input."""
    import typer

    from smplik.cli.errors import user_errors
    from smplik.cli.outputs import _PARAMS

    src = tmp_path / "scene.json"
    src.write_text("{}")
    token = _PARAMS.set({"scene": src, "out": tmp_path / "never.png"})
    try:
        with pytest.raises(typer.Exit), user_errors():
            raise np.linalg.LinAlgError("SVD did not converge")
    finally:
        _PARAMS.reset(token)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert lines == [f"error: {src}: SVD did not converge"], lines


# ----------------------------------------------------------------------------- variants: bounded, all-or-nothing


def test_variant_distances_equal_the_full_matrix_rows():
    from smplik.variants import MIN_DISTANCE_M, farthest_points

    joints = np.random.default_rng(1).normal(size=(40, 24, 3)) * 0.1
    full = np.linalg.norm(joints[:, None] - joints[None], axis=-1).mean(-1)
    rows = farthest_points(lambda i: np.linalg.norm(joints[i][None] - joints, axis=-1).mean(-1), 12,
                           MIN_DISTANCE_M)
    assert rows == farthest_points(full, 12, MIN_DISTANCE_M)


# ----------------------------------------------------------------------------- the editor: malformed HTTP is 4xx


def _raw_status(port: int, request: bytes) -> int:
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(request)
        head = s.recv(4096).decode("latin-1")
    return int(head.split()[1]) if head else 0  # 0: closed without an answer


@pytest.fixture(scope="module")
def running_editor(shipped_solver, tmp_path_factory):
    """One editor on a fresh scene for the HTTP tests: ``(port, token, "127.0.0.1:PORT")``."""
    pytest.importorskip("viser")
    import torch

    from workflows.editor.app import EditorApp
    from workflows.editor.state import EditorState, fresh_scene

    torch.set_num_threads(1)
    path = tmp_path_factory.mktemp("editor") / "scene.json"
    editor = EditorApp(EditorState(fresh_scene(), shipped_solver, path=path), host="127.0.0.1", port=0)
    try:
        yield editor.port, editor.access.token, f"127.0.0.1:{editor.port}"
    finally:
        editor.stop()


def test_editor_answers_repeated_host_and_origin_headers_with_400(running_editor):
    port, token, own = running_editor
    base = f"GET /?token={token} HTTP/1.1\r\n"
    assert _raw_status(port, f"{base}Host: {own}\r\n\r\n".encode()) == 200
    for extra in (f"Host: {own}\r\nHost: {own}\r\n", f"Host: {own}\r\nHost: evil.example.com:{port}\r\n",
                  f"Host: {own}\r\nOrigin: http://{own}\r\nOrigin: http://{own}\r\n"):
        assert _raw_status(port, f"{base}{extra}\r\n".encode()) == 400, extra


def test_editor_answers_malformed_http_with_4xx_and_stays_up(running_editor):
    """Requests websockets' HTTP parser refuses (it closed them without an answer) get 400; bad Host, token,
    path or WebSocket handshakes get 4xx; never a 5xx, and the editor still serves its page afterwards."""
    port, token, own = running_editor
    q = f"/?token={token}"
    base = f"GET {q} HTTP/1.1\r\n"
    ws = f"Origin: http://{own}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    cases = {  # request -> expected status
        f"FOO {q} HTTP/1.1\r\nHost: {own}\r\n\r\n": 400,  # a bad method
        f"POST {q} HTTP/1.1\r\nHost: {own}\r\nContent-Length: 3\r\n\r\nabc": 400,
        "GARBAGE\r\n\r\n": 400,
        f"GET {q} HTTP/1.0\r\nHost: {own}\r\n\r\n": 400,
        f"{base}Host: {own}\r\nX-A: {'a' * 20000}\r\n\r\n": 400,  # an over-long header
        f"{base}Host: {own}\r\n" + "".join(f"X-{i}: a\r\n" for i in range(300)) + "\r\n": 400,
        f"{base}Host: {own}\r\nNoColon\r\n\r\n": 400,
        f"{base}Host: {own}\r\nX-A: a\x00b\r\n\r\n": 400,
        f"GET /{'a' * 20000}{q} HTTP/1.1\r\nHost: {own}\r\n\r\n": 400,
        f"{base}\r\n": 403,  # no Host
        f"{base}Host: 127.0.0.1\xe9:{port}\r\n\r\n": 403,  # a non-ASCII Host
        f"{base}Host: [::1:{port}\r\n\r\n": 403,  # an unbalanced IPv6 literal
        f"GET /?token=\xe9\xff HTTP/1.1\r\nHost: {own}\r\n\r\n": 400,
        f"GET /%00{q} HTTP/1.1\r\nHost: {own}\r\n\r\n": 404,
        f"GET /assets/%00.js{q} HTTP/1.1\r\nHost: {own}\r\n\r\n": 404,
        f"{base}Host: {own}\r\n{ws}Sec-WebSocket-Key: x\r\nSec-WebSocket-Version: 13\r\n\r\n": 400,
        f"{base}Host: {own}\r\n{ws}Sec-WebSocket-Version: 13\r\n\r\n": 400,  # no key
        f"{base}Host: {own}\r\n{ws}Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
        "Sec-WebSocket-Version: 99\r\n\r\n": 400,
    }
    for request, status in cases.items():
        assert _raw_status(port, request.encode("latin-1")) == status, request[:120]
    assert _raw_status(port, f"{base}Host: {own}\r\n\r\n".encode()) == 200
