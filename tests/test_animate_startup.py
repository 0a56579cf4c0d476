"""``smplik scene animate`` refuses a bad option before anything heavy loads (issue 44, item 4): the refusal is one
``error:`` line with exit status 1, and the process never imported numpy or torch (nor read the file or loaded the
model). The option lists of :mod:`workflows.animation.options` equal those of the modules they stand for."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

RUNNER = ("import sys\nfrom smplik.cli.main import app\n"
          "try:\n    app(args=sys.argv[1:], prog_name='smplik')\nexcept SystemExit as exc:\n"
          "    print('exit', exc.code, file=sys.stderr)\n"
          "print('heavy', sorted(m for m in ('torch', 'numpy', 'scipy', 'sklearn') if m in sys.modules), "
          "file=sys.stderr)\n")

BAD = {
    "frames": (["--frames", "abc"], "--frames must be 'all' or 'A:B'"),
    "frames order": (["--frames", "9:3"], "need 0 <= A < B"),
    "fps": (["--fps", "0"], "--fps"),
    "export": (["--export", "bvh,fbx"], "unknown export format(s) ['fbx']"),
    "format": (["--format", "xyz"], "--format must be one of auto"),
    "space": (["--space", "up"], "--space must be 'camera' or 'world'"),
    "smoothing": (["--smoothing", "bogus"], "--smoothing must be one of"),
    "preview": (["--preview", "p.png"], "a preview is a .gif or .mp4 file"),
    "smoothness": (["--smoothness", "-1"], "--smoothness must be a positive number, got -1."),
    "pose budget": (["--pose-budget", "nan"], "--pose-budget must be a number of mm >= 0"),
    "keyframe threshold": (["--keyframe-threshold", "0"], "the keyframe threshold must be a positive number"),
    "character": (["--character", "missing.bvh"], "--character missing.bvh: no such file."),
    "units": (["--units", "furlong"], "Unknown units 'furlong'"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_a_bad_option_is_refused_before_numpy_or_torch_import(case, tmp_path):
    extra, message = BAD[case]
    results = tmp_path / "hmr4d_results.pt"  # never read: the options are refused first
    results.write_bytes(b"not a torch file")
    args = ["scene", "animate", str(results), "--out", str(tmp_path / "out"), *extra]
    res = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert lines[-1] == "heavy []", res.stderr[-2000:]
    assert lines[-2] == "exit 1", res.stderr[-2000:]
    errors = [line for line in lines if line.startswith("error:")]
    assert len(errors) == 1 and message in errors[0], res.stderr[-2000:]
    assert "Traceback" not in res.stderr and not (tmp_path / "out").exists()


def test_a_good_option_set_goes_on_to_read_the_file(tmp_path):
    """The same runner with valid options gets past the checks: the unreadable file is what it refuses."""
    results = tmp_path / "hmr4d_results.pt"
    results.write_bytes(b"not a torch file")
    args = ["scene", "animate", str(results), "--out", str(tmp_path / "out"), "--frames", "0:5", "--fps", "30"]
    res = subprocess.run([sys.executable, "-c", RUNNER, *args], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert lines[-2] == "exit 1" and "torch" in lines[-1], res.stderr[-2000:]
    assert any(line.startswith("error:") and "hmr4d_results.pt" in line for line in lines), res.stderr[-2000:]


def test_option_lists_match_the_modules_that_use_them():
    from workflows.animation import options
    from workflows.animation.clean import CleanConfig, CleanError
    from workflows.estimators import FORMATS as READERS
    from workflows.scene.export import FORMATS as EXPORTS

    assert options.EXPORT_FORMATS == tuple(EXPORTS)
    assert options.ESTIMATOR_FORMATS == tuple(READERS)
    for method in options.SMOOTHING_METHODS:
        if method != "auto":
            CleanConfig(smoothing=method)  # every listed method is one the cleaning takes
    with pytest.raises(CleanError):
        CleanConfig(smoothing="bogus")


def test_parse_frames_and_the_error_class_are_the_ones_the_pipeline_uses():
    from workflows.animation import clips, options, preview, run

    assert clips.AnimationError is options.AnimationError and clips.parse_frames is options.parse_frames
    assert run.check_animate_options is options.check_animate_options
    assert preview.check_preview_path is options.check_preview_path
    assert options.parse_frames("all") is None and options.parse_frames(" 3:7 ") == (3, 7)
    with pytest.raises(options.AnimationError, match="got '3'"):
        options.parse_frames("3")


def _smplik(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "smplik.cli", *args], capture_output=True, text=True, timeout=600,
                          cwd=cwd)


@pytest.mark.slow
def test_the_command_leaves_with_its_status_output_and_files_after_torch_loaded(tmp_path):
    """The end of a command that imported torch skips the interpreter's teardown (:func:`smplik.cli.leave`): its
    files, its printed lines, atexit functions and the exit status are all still there."""
    from animation_fixtures import video_motion, write_gvhmr_video

    src = write_gvhmr_video(tmp_path, *video_motion(12))
    res = _smplik("scene", "animate", str(src), "--out", str(tmp_path / "out"), "--export", "bvh", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    said = res.stdout + res.stderr  # the command's lines go to stderr
    assert f"wrote {tmp_path / 'out' / 'person_0.bvh'}" in said and said.endswith("\n")
    assert (tmp_path / "out" / "animation.json").stat().st_size > 0
    res = _smplik("scene", "animate", str(src), "--out", str(tmp_path / "o2"), "--track", "7", cwd=tmp_path)
    assert res.returncode == 1 and "no track '7'" in res.stdout + res.stderr  # refused after torch loaded
    code = ("import atexit, sys, threading, time, torch\nfrom concurrent.futures import ThreadPoolExecutor\n"
            "from smplik.cli import leave\n"
            "atexit.register(lambda: print('atexit ran', flush=True))\nprint('before', end='')\n"
            "pool = ThreadPoolExecutor(1)\npool.submit(time.sleep, 0.2)\n"  # a pool's idle worker must not hang it
            "threading.Thread(target=lambda: (time.sleep(0.3), print(' thread', flush=True))).start()\n"
            "leave(sys.argv[1:] and int(sys.argv[1]))\n")
    for status in (0, 3):
        res = subprocess.run([sys.executable, "-c", code, str(status)], capture_output=True, text=True, timeout=300)
        assert res.returncode == status and res.stdout == "before thread\natexit ran\n", res
    res = subprocess.run([sys.executable, "-c", code.replace("int(sys.argv[1])", "'a message'"), "x"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 1 and res.stderr.strip() == "a message"


def test_the_speed_benchmark_splits_a_run_into_its_stages(tmp_path):
    """``benchmarks/animation_real_speed.py``: the stages of one run on a GVHMR file (the files written, every
    stage timed once, the wrapped functions put back), and an empty folder said and left with status 0."""
    import importlib.util

    from animation_fixtures import video_motion, write_gvhmr_video

    root = Path(__file__).resolve().parents[1]
    script = root / "benchmarks" / "animation_real_speed.py"
    spec = importlib.util.spec_from_file_location("animation_real_speed", script)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    from workflows.animation import clips
    from workflows.scene import recovery

    before = (clips.clean_track, clips.select_keyframes, recovery.recover_many)
    src = write_gvhmr_video(tmp_path, *video_motion(12))
    row = bench.animate_stages(src, tmp_path / "out", None)
    assert row["frames"] == 12 and row["tracks"] == 1 and row["keyframes"] >= 2
    assert set(row["cpu_s"]) == set(bench.STAGES) - {"start"}
    assert all(v >= 0 for v in row["cpu_s"].values()) and row["cpu_s"]["effectors"] > 0
    assert {p.name for p in (tmp_path / "out").iterdir()} == {"animation.json", "person_0.bvh", "person_0.glb"}
    assert (clips.clean_track, clips.select_keyframes, recovery.recover_many) == before
    empty = tmp_path / "empty"
    empty.mkdir()
    res = subprocess.run([sys.executable, str(script), str(empty)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and "no estimator files under" in res.stdout
