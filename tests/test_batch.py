"""``smplik batch``: one job over a folder of good and broken estimator files, on the local process pool and on
Ray; the report, the exit status, resume, ``--force``, atomic output folders; manifests and option errors.

The batch runs go through ``python -m smplik.cli`` (separate processes, as a user runs them): the local engine
starts its own worker processes, the Ray engine a local Ray with 2 CPUs (``ray.init(num_cpus=2)``).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from estimator_fixtures import people, write_romp

REPO = Path(__file__).resolve().parents[1]
GOOD = ("clip_0", "clip_1", "clip_2")


def smplik(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "PYOPENGL_PLATFORM": "egl"}
    return subprocess.run([sys.executable, "-m", "smplik.cli", *args], capture_output=True, text=True, env=env,
                          cwd=REPO, timeout=timeout)


def write_clip(path: Path, seed: int) -> Path:
    """One person of ROMP (simple_romp ``save_results``, tests/estimator_fixtures.write_romp) at ``path``."""
    tmp = path.parent / f".fixture_{seed}"
    tmp.mkdir()
    written = write_romp(tmp, *people(seed=seed, n=1))
    shutil.move(written.path, path)
    tmp.rmdir()
    return path


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def report(out: Path) -> dict:
    return json.loads((out / "batch_report.json").read_text())


def rows(out: Path) -> dict[str, dict]:
    return {row["name"]: row for row in report(out)["inputs"]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A mixed folder (3 good ROMP files, a truncated .npz, a JSON of no estimator) run once on the local engine
    (2 workers) and, when Ray is installed, once on Ray; the outputs are snapshot right after each run."""
    root = tmp_path_factory.mktemp("batch")
    mix = root / "mix"
    mix.mkdir()
    for i, name in enumerate(GOOD):
        write_clip(mix / f"{name}.npz", seed=i)
    (mix / "broken.npz").write_bytes((mix / "clip_0.npz").read_bytes()[:300])
    (mix / "notes.json").write_text('{"hello": 1}')
    (mix / "readme.txt").write_text("not an input: the folder gives only estimator files")
    local = smplik("batch", "from-estimate", str(mix), "--out", str(root / "local"), "--workers", "2",
                   "--", "--no-previews", "--max-effectors", "4")
    result = {"root": root, "mix": mix, "local": local, "local_files": snapshot(root / "local")}
    try:
        import ray  # noqa: F401
    except ImportError:
        result["ray"] = None
    else:
        result["ray"] = smplik("batch", "from-estimate", str(mix), "--out", str(root / "ray"), "--engine", "ray",
                               "--workers", "2", "--", "--no-previews", "--max-effectors", "4")
        result["ray_files"] = snapshot(root / "ray")
    return result


@pytest.mark.slow
def test_mixed_folder_report_and_exit_status(runs, shipped_solver, tmp_path):
    res, out = runs["local"], runs["root"] / "local"
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("error: 2 of 5 inputs failed"), res.stderr
    assert "Traceback" not in res.stderr
    data = report(out)
    assert data["format"] == "smplik-batch-report" and data["finished"] and data["job"] == "from-estimate"
    assert data["counts"] == {"done": 3, "skipped": 0, "failed": 2, "pending": 0}
    assert data["options"] == ["--no-previews", "--max-effectors", "4"] and data["workers"] == 2
    table = rows(out)
    assert set(table) == {*GOOD, "broken", "notes"}  # readme.txt is no from-estimate input
    for name in GOOD:
        row = table[name]
        assert row["status"] == "done" and row["error"] is None and row["seconds"] > 0
        assert row["outputs"] == ["scene.json", "batch_done.json"]
        assert row["input"] == str(runs["mix"] / f"{name}.npz")
        assert sorted(p.name for p in (out / name).iterdir()) == ["batch_done.json", "scene.json"]
        done = json.loads((out / name / "batch_done.json").read_text())
        assert done["job"] == "from-estimate" and done["outputs"] == ["scene.json"]
        assert done["options"]["max_effectors"] == 4 and done["options"]["no_previews"] is True
    assert table["broken"]["status"] == "failed" and "not a readable zip" in table["broken"]["error"]
    assert table["notes"]["status"] == "failed" and "Cannot detect the estimator format" in table["notes"]["error"]
    for name in ("broken", "notes"):  # a one-line error, no traceback (user errors), no output folder
        assert "\n" not in table[name]["error"] and "traceback" not in table[name]
        assert table[name]["outputs"] == [] and not (out / name).exists()
        assert f"failed: {name} (" in res.stderr
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []  # no temporary folder left

    # each output is the job's own output: the scene `smplik scene from-estimate` writes for that file
    from workflows.scene.pipeline import from_estimate
    from workflows.scene.recovery import RecoveryConfig

    from_estimate(runs["mix"] / "clip_1.npz", tmp_path, shipped_solver, previews=False,
                  config=RecoveryConfig(max_effectors=4))
    assert_json_close(json.loads((out / "clip_1" / "scene.json").read_text()),
                      json.loads((tmp_path / "scene.json").read_text()))


def assert_json_close(a, b, path: str = "$") -> None:
    """Equal JSON documents, numbers within 1e-5 (this process's torch threads may differ from a worker's)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and sorted(a) == sorted(b), path
        for k in a:
            assert_json_close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_json_close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        np.testing.assert_allclose(a, b, atol=1e-5, err_msg=path)
    else:
        assert a == b, path


@pytest.mark.slow
def test_ray_engine_gives_the_same_outputs(runs):
    if runs["ray"] is None:
        pytest.skip("ray is not installed (pip install -e '.[ray]')")
    res = runs["ray"]
    assert res.returncode == 1, res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("error: 2 of 5 inputs failed"), res.stderr
    data = report(runs["root"] / "ray")
    assert data["engine"] == "ray" and data["counts"] == {"done": 3, "skipped": 0, "failed": 2, "pending": 0}
    local, ray = runs["local_files"], runs["ray_files"]
    outputs = {k for k in local if k != "batch_report.json"}
    assert outputs == {f"{n}/{f}" for n in GOOD for f in ("scene.json", "batch_done.json")}
    assert outputs == {k for k in ray if k != "batch_report.json"}
    for key in sorted(outputs):  # byte for byte: the same worker code, one thread, the same model
        assert ray[key] == local[key], key
    assert {r["name"]: r["error"] for r in data["inputs"]} == {r["name"]: r["error"]
                                                                 for r in report(runs["root"] / "local")["inputs"]}


@pytest.mark.slow
def test_rerun_skips_complete_outputs_retries_failures_and_force_redoes(runs):
    mix, out = runs["mix"], runs["root"] / "local"
    stamps = {n: (out / n / "scene.json").stat().st_mtime_ns for n in GOOD}
    write_clip(mix / "broken.npz.tmp", seed=7)  # the broken file repaired
    os.replace(mix / "broken.npz.tmp", mix / "broken.npz")
    res = smplik("batch", "from-estimate", str(mix), "--out", str(out), "--workers", "1",
                 "--", "--no-previews", "--max-effectors", "4")
    assert res.returncode == 1 and "error: 1 of 5 inputs failed" in res.stderr, res.stderr
    table = rows(out)
    assert {n: table[n]["status"] for n in table} == {**dict.fromkeys(GOOD, "skipped"), "broken": "done",
                                                      "notes": "failed"}
    assert {n: (out / n / "scene.json").stat().st_mtime_ns for n in GOOD} == stamps  # not rewritten
    assert (out / "broken" / "scene.json").is_file()

    # --force redoes every input; one that now fails keeps its earlier complete folder untouched
    before = snapshot(out / "clip_2")
    (mix / "clip_2.npz").write_bytes(b"PK\x03\x04 not a zip any more")
    res = smplik("batch", "from-estimate", str(mix / "clip_*.npz"), str(mix / "broken.npz"), "--out", str(out),
                 "--workers", "1", "--force", "--", "--no-previews", "--max-effectors", "4")
    assert res.returncode == 1 and "error: 1 of 4 inputs failed" in res.stderr, res.stderr
    table = rows(out)
    assert {n: table[n]["status"] for n in table} == {"clip_0": "done", "clip_1": "done", "clip_2": "failed",
                                                      "broken": "done"}
    assert snapshot(out / "clip_2") == before
    for n in ("clip_0", "clip_1"):  # redone: new files, the same bytes (deterministic)
        assert (out / n / "scene.json").stat().st_mtime_ns != stamps[n]
        assert (out / n / "scene.json").read_bytes() == runs["local_files"][f"{n}/scene.json"]
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []

    # other options make the outputs incomplete for this run: redone without --force
    res = smplik("batch", "from-estimate", str(mix / "clip_0.npz"), "--out", str(out), "--workers", "1",
                 "--", "--no-previews", "--max-effectors", "3")
    assert res.returncode == 0, res.stderr
    assert rows(out)["clip_0"]["status"] == "done"
    assert json.loads((out / "clip_0" / "batch_done.json").read_text())["options"]["max_effectors"] == 3


# ----------------------------------------------------------------------------- light: no worker starts


def bad_invocations(tmp: Path) -> dict[str, list[str]]:
    (tmp / "empty").mkdir()
    good = write_clip(tmp / "a.npz", seed=0)
    (tmp / "list.txt").write_text(f"{good}\n# a comment\n\nmissing.npz\n")
    (tmp / "list.json").write_text(json.dumps({"inputs": [{"path": "a.npz", "args": ["--frame", "x"]}]}))
    (tmp / "keys.json").write_text(json.dumps({"inputs": [{"path": "a.npz", "opts": []}]}))
    out = str(tmp / "out")
    return {
        "unknown job": ["batch", "retarget", str(good), "--out", out],
        "empty folder": ["batch", "animate", str(tmp / "empty"), "--out", out],
        "manifest line": ["batch", "animate", "--manifest", str(tmp / "list.txt"), "--out", out],
        "manifest args": ["batch", "from-estimate", "--manifest", str(tmp / "list.json"), "--out", out],
        "manifest keys": ["batch", "from-estimate", "--manifest", str(tmp / "keys.json"), "--out", out],
        "engine": ["batch", "animate", str(good), "--out", out, "--engine", "spark"],
        "job option": ["batch", "animate", str(good), "--out", out, "--", "--smoothness", "lots"],
        "job --out": ["batch", "animate", str(good), "--out", out, "--", "--out", "x"],
        "preview path": ["batch", "animate", str(good), "--out", out, "--", "--preview", "sub/p.gif"],
        "address": ["batch", "animate", str(good), "--out", out, "--address", "auto"],
        "no inputs": ["batch", "animate", "--out", out],
        "glob": ["batch", "animate", str(tmp / "nothing" / "*.npz"), "--out", out],
    }


EXPECTED = {
    "unknown job": "unknown job 'retarget'; choose one of: animate, from-estimate, track, invert-shape, export",
    "empty folder": "holds no animate input",
    "manifest line": "list.txt line 4: missing.npz: no such file",
    "manifest args": "inputs[0]: from-estimate options: Invalid value for '--frame'",
    "manifest keys": "inputs[0]: unknown key(s) ['opts']",
    "engine": "--engine must be one of local, ray, got 'spark'",
    "job option": "animate options: Invalid value for '--smoothness'",
    "job --out": "--out is the batch's own option",
    "preview path": "--preview sub/p.gif: give a file name",
    "address": "--address is for --engine ray",
    "no inputs": "no inputs",
    "glob": "the pattern matches no file",
}


def test_bad_invocations_are_one_line_before_anything_heavy_loads(tmp_path):
    cases = bad_invocations(tmp_path)
    script = ("import json, sys\nfrom typer.testing import CliRunner\nfrom smplik.cli.main import app\n"
              "cases = json.loads(sys.argv[1])\nout = {}\n"
              "for name, args in cases.items():\n"
              "    r = CliRunner().invoke(app, args)\n"
              "    out[name] = [r.exit_code, r.output]\n"
              "out['heavy'] = sorted(m for m in ('torch', 'numpy', 'ray') if m in sys.modules)\n"
              "print(json.dumps(out))\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    res = subprocess.run([sys.executable, "-c", script, json.dumps(cases)], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=300)
    assert res.returncode == 0, res.stderr
    results = json.loads(res.stdout.strip().splitlines()[-1])
    assert results.pop("heavy") == [], "a bad invocation loaded torch, numpy or ray"
    for name, (code, output) in results.items():
        lines = output.strip().splitlines()
        assert code == 1 and len(lines) == 1 and lines[0].startswith("error: "), (name, output)
        assert EXPECTED[name] in lines[0], (name, lines[0])
    assert not (tmp_path / "out").exists()


def test_output_names_are_unique_and_readable(tmp_path):
    from workflows.batch.plan import output_names

    p = Path("/data")
    assert output_names([p / "a.npz", p / "b.npz"]) == ["a", "b"]
    assert output_names([p / "clip_a/results.pkl", p / "clip_b/results.pkl"]) == ["clip_a", "clip_b"]
    assert output_names([p / "x/a.npz", p / "y/a.pkl", p / "y/b.npz"]) == ["x__a", "y__a", "b"]
    assert output_names([p / "a.npz", p / "a.pkl"]) == ["a_npz", "a_pkl"]
    assert output_names([p / "my clip [1].npz"]) == ["my_clip__1_"]
    assert output_names([p / ".hidden.npz"]) == ["hidden"]


def test_manifests_text_and_json(tmp_path):
    from workflows.batch.jobs import JOBS
    from workflows.batch.plan import collect_inputs, plan_tasks

    (tmp_path / "data").mkdir()
    a, b = write_clip(tmp_path / "data" / "a.npz", 0), write_clip(tmp_path / "data" / "b.npz", 1)
    (tmp_path / "img.png").write_bytes(b"\x89PNG not really")
    (tmp_path / "list.txt").write_text("# clips\ndata/a.npz\n\n  data/b.npz  \n")
    items = collect_inputs(JOBS["from-estimate"], [], tmp_path / "list.txt")
    assert [i.source for i in items] == [a, b]
    (tmp_path / "list.json").write_text(json.dumps({"inputs": [
        "data/a.npz", {"path": "data/b.npz", "name": "take_2", "args": ["--image", "img.png", "--frame", "0"]}]}))
    items = collect_inputs(JOBS["from-estimate"], [str(a)], tmp_path / "list.json")  # a named twice: once
    tasks = plan_tasks(JOBS["from-estimate"], items, tmp_path / "out", ["--max-effectors", "5"])
    assert [(t.name, Path(t.source)) for t in tasks] == [("a", a), ("take_2", b)]
    assert tasks[0].params["image"] is None and tasks[0].params["max_effectors"] == 5
    assert tasks[1].params["image"] == tmp_path / "img.png"  # relative to the manifest's folder
    assert tasks[1].params["max_effectors"] == 5 and tasks[1].out_dir == str(tmp_path / "out" / "take_2")
    assert tasks[0].identity["options_sha256"] != tasks[1].identity["options_sha256"]


def test_leftovers_of_a_killed_batch_are_tidied(tmp_path):
    from workflows.batch.engines import replace_folder
    from workflows.batch.plan import tidy_leftovers

    (tmp_path / ".a.partial-123-0123abcd").mkdir()  # a half-written output: removed
    old = tmp_path / ".b.old-123-0123abcd"  # a complete output moved aside, its replacement never renamed in
    old.mkdir()
    (old / "scene.json").write_text("{}")
    (tmp_path / ".c.partial-123-0123abcd").mkdir()  # not an input of this batch: kept
    tidy_leftovers(tmp_path, ["a", "b"])
    assert sorted(p.name for p in tmp_path.iterdir()) == [".c.partial-123-0123abcd", "b"]
    assert (tmp_path / "b" / "scene.json").read_text() == "{}"
    new = tmp_path / ".b.partial-1-00000000"
    new.mkdir()
    (new / "scene.json").write_text('{"new": 1}')
    replace_folder(new, tmp_path / "b")
    assert (tmp_path / "b" / "scene.json").read_text() == '{"new": 1}'
    assert sorted(p.name for p in tmp_path.iterdir()) == [".c.partial-123-0123abcd", "b"]


# ----------------------------------------------------------------------------- every job, in this process


@pytest.mark.slow
def test_every_job_runs_through_its_entry_point(tmp_path, shipped_solver):
    """Each job's options reach its command's entry point: one input each, run as a worker runs it
    (:func:`workflows.batch.engines.run_task`), the files the command writes in the input's folder."""
    import torch
    from animation_fixtures import video_motion, write_gvhmr_video

    from smplik.body_model import BodyModelSet
    from smplik.tracking.config import TRACKER_SETS
    from smplik.tracking.io import signals_from_motion
    from workflows.batch.engines import _STATE, run_task
    from workflows.batch.jobs import JOBS
    from workflows.batch.plan import BatchInput, plan_tasks
    from workflows.examples_gen import write_mixamo_character

    _STATE["models"][("solver", None)] = shipped_solver  # as a worker holds it
    (tmp_path / "video").mkdir()
    video = write_gvhmr_video(tmp_path / "video", *video_motion(12))
    J = BodyModelSet.load().rest_joints(torch.zeros(10), torch.tensor(0)).double().numpy()
    signals = signals_from_motion(np.tile(np.eye(3), (20, 24, 1, 1)), np.zeros((20, 3)), J, TRACKER_SETS["4"], 60.0)
    trackers = tmp_path / "session.json"
    trackers.write_text(json.dumps(signals.to_dict()))
    character = write_mixamo_character(tmp_path / "hero.bvh")
    scene = write_clip(tmp_path / "romp.npz", seed=3)
    runs = [("animate", video, ["--export", "bvh", "--smoothing", "none", "--frames", "0:10"],
             {"animation.json", "person_0.bvh"}),
            ("from-estimate", scene, ["--no-previews", "--max-effectors", "3"], {"scene.json"}),
            ("track", trackers, ["--export", "bvh", "--betas", ",".join(["0"] * 10)],
             {"animation.json", "person_0.bvh"}),
            ("invert-shape", character, ["--bank-samples", "400", "--gender", "female"], {"shape.json"})]
    out = tmp_path / "out"
    out.mkdir()
    for job, source, args, files in runs:
        (task,) = plan_tasks(JOBS[job], [BatchInput(source.resolve())], out / job, args)
        result = run_task(task)
        assert result.status == "done", (job, result.error, result.traceback)
        assert set(result.outputs) == files | {"batch_done.json"}, job
        assert {p.name for p in Path(task.out_dir).iterdir()} == files | {"batch_done.json"}
    anim = json.loads((out / "animate" / "hmr4d_results" / "animation.json").read_text())
    assert anim["format"] == "smplik-animation"
    shape = json.loads((out / "invert-shape" / "hero" / "shape.json").read_text())
    assert shape["gender"] == "female" and shape["character"]["rig"]
    # export: the scene written above -> per character a BVH and a GLB
    (task,) = plan_tasks(JOBS["export"], [BatchInput(out / "from-estimate" / "romp" / "scene.json")], out / "export",
                         ["--format", "bvh"])
    result = run_task(task)
    assert result.status == "done" and set(result.outputs) == {"person_0.bvh", "batch_done.json"}, result


def test_ray_engine_without_ray_names_the_extra(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from smplik.cli.main import app
    from workflows.batch import engines

    monkeypatch.setattr(engines, "ray_available", lambda: False)  # as in an install without the [ray] extra
    good = write_clip(tmp_path / "a.npz", seed=0)
    res = CliRunner().invoke(app, ["batch", "from-estimate", str(good), "--out", str(tmp_path / "out"),
                                   "--engine", "ray"])
    assert res.exit_code == 1
    assert res.output.strip() == "error: --engine ray needs Ray: pip install 'smplik[ray]'."
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_model_that_cannot_load_stops_the_batch_with_one_line(tmp_path):
    good = write_clip(tmp_path / "a.npz", seed=0)
    bad_model = tmp_path / "model.pt"
    bad_model.write_text("not a model")
    res = smplik("batch", "from-estimate", str(good), "--out", str(tmp_path / "out"), "--workers", "1",
                 "--", "--checkpoint", str(bad_model))
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bad_model}: "), res.stderr
    assert "batch stopped" in lines[0] and "Traceback" not in res.stderr
    assert report(tmp_path / "out")["counts"] == {"done": 0, "skipped": 0, "failed": 0, "pending": 1}
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["batch_report.json"]
