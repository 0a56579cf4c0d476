"""Speed of ``smplik scene animate`` on real estimator files, export included (issue 44).

Reads every estimator file under a folder (the first argument, else ``$SMPLIK_REAL_ESTIMATORS``, else
``<cache>/real/estimators``; the files stay outside the repository: see ``docs/animation.md``, "Speed on real
files", for where to get them) and, per file, in this process (the model loaded once, one warm-up run first):

* ``pipeline``: :func:`workflows.animation.run.animate_file` without export (read, retarget, clean, keyframes,
  effector recovery on keyframes);
* ``export``: the BVH and GLB of every track (:func:`workflows.animation.run.export_animation`);
* ``preview``: the GIF preview (:func:`workflows.animation.preview.write_preview`, every 2nd frame of a 30
  frames/s clip), when a GL backend is there;

each as frames per CPU second of this process (``time.process_time``; the machine is shared, so wall-clock rates
are printed too but not judged). And once per file, the whole command in a fresh process (``python -m smplik.cli
scene animate FILE --export bvh,glb``, startup, imports and model load included: CPU time of the child), with the
optional ``[fast]`` extra's backends as installed and with them hidden (``numba`` and ``onnxruntime`` made
unimportable by a ``sitecustomize`` on the child's ``PYTHONPATH``), to say whether ``[fast]`` speeds the command up.

Target: at least 60 frames per CPU second for the pipeline plus export on every file. Writes
``benchmarks/results/animation_speed.json``; without files it says so and exits 0.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _child import child_cpu, child_env  # noqa: E402
from _common import save  # noqa: E402

from smplik.paths import real_estimators_dir  # noqa: E402

SUFFIXES = (".pt", ".pkl", ".pk", ".npz")
TARGET_FRAMES_PER_CPU_S = 60.0
ASSUMED_FPS = 30.0
"""Frame rate given to formats that store none (WHAM, PHALP: their demos' video rate)."""
"""A ``sitecustomize`` that makes the ``[fast]`` extra's packages unimportable (the command without ``[fast]``)."""


def _cpu(fn):
    start, wall = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - start, time.perf_counter() - wall


def fresh_process(path: Path, frames: int, hide_fast: bool, tmp: Path, fps: float | None) -> dict:
    """The whole command in a new process (startup included), with or without the ``[fast]`` backends."""
    env = child_env(tmp, hide_fast)
    out = tmp / ("fresh_nofast" if hide_fast else "fresh")
    rc, cpu, wall, _ = child_cpu([sys.executable, "-m", "smplik.cli", "scene", "animate", str(path), "--out", str(out),
                                "--export", "bvh,glb", *(["--fps", str(fps)] if fps else [])], env)
    return {"fast_backends": not hide_fast, "exit": rc, "cpu_s": round(cpu, 2), "wall_s": round(wall, 2),
            "frames_per_cpu_s": round(frames / cpu, 1) if rc == 0 else None}


def source_fps(path: Path) -> float | None:
    """None where the file stores its frame rate (or GVHMR's 30 is assumed), else :data:`ASSUMED_FPS`."""
    from workflows.animation.clips import ASSUMED_FPS as KNOWN_DEFAULTS
    from workflows.animation.clips import read_clip

    clip = read_clip(path, frames=(0, 3))
    return None if clip.fps is not None or clip.format in KNOWN_DEFAULTS else ASSUMED_FPS


def bench_file(path: Path, solver, tmp: Path, preview: bool, fps: float | None) -> dict:
    from workflows.animation.run import animate_file, export_animation

    animate_file(path, tmp / "warm", solver, formats=(), fps=fps)  # first-call caches are not the speed
    out, cpu, wall = _cpu(lambda: animate_file(path, tmp / "run", solver, formats=(), fps=fps))
    frames = sum(t.num_frames for t in out.animation.tracks)
    row = {"file": str(path), "tracks": len(out.animation.tracks), "frames": frames,
           "keyframes": sum(len(t.keyframes) for t in out.animation.tracks),
           "pipeline": {"cpu_s": round(cpu, 3), "wall_s": round(wall, 3), "frames_per_cpu_s": round(frames / cpu, 1)}}
    _, cpu_x, wall_x = _cpu(lambda: export_animation(out.animation, tmp / "run", ("bvh", "glb")))
    row["export"] = {"cpu_s": round(cpu_x, 3), "wall_s": round(wall_x, 3),
                     "frames_per_cpu_s": round(frames / cpu_x, 1)}
    row["pipeline_and_export_frames_per_cpu_s"] = round(frames / (cpu + cpu_x), 1)
    if preview:
        from workflows.animation.preview import write_preview

        try:
            shown, cpu_p, wall_p = _cpu(lambda: write_preview(out.animation, tmp / "run" / "preview.gif"))
            row["preview_gif"] = {"shown_frames": len(shown.frames), "cpu_s": round(cpu_p, 3),
                                  "wall_s": round(wall_p, 3), "frames_per_cpu_s": round(frames / cpu_p, 1)}
        except Exception as exc:  # no GL backend on this machine: said, not fatal
            row["preview_gif"] = {"error": f"{type(exc).__name__}: {exc}"[:200]}
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder", type=Path, nargs="?", default=real_estimators_dir())
    parser.add_argument("--only", default="", help="Only files whose path contains this.")
    parser.add_argument("--no-preview", action="store_true")
    parser.add_argument("--no-fresh", action="store_true", help="Skip the fresh-process runs.")
    parser.add_argument("--no-save", action="store_true")
    args = parser.parse_args()
    files = sorted(p for p in args.folder.rglob("*") if p.is_file() and p.suffix in SUFFIXES
                   and args.only in str(p)) if args.folder.is_dir() else []
    if not files:
        print(f"no estimator files under {args.folder} (pass a folder or set SMPLIK_REAL_ESTIMATORS); nothing to do")
        return
    import torch

    from smplik.solver import IKSolver

    torch.set_num_threads(1)
    solver = IKSolver.load(None)
    rows = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        for k, path in enumerate(files):
            tmp = Path(tmp_dir) / str(k)
            tmp.mkdir()
            try:
                fps = source_fps(path)
                row = bench_file(path, solver, tmp, not args.no_preview, fps)
            except Exception as exc:  # a file scene animate refuses: listed, not fatal
                print(f"{path}: refused ({type(exc).__name__}: {str(exc)[:120]})")
                continue
            if not args.no_fresh:
                row["fresh_process"] = [fresh_process(path, row["frames"], hide, tmp, fps) for hide in (False, True)]
            rows.append(row)
            p, x = row["pipeline"], row["export"]
            print(f"{path.name} ({path.parent.name}): {row['frames']} frames, {row['keyframes']} keyframes; "
                  f"pipeline {p['frames_per_cpu_s']} frames/CPU s, export {x['frames_per_cpu_s']}, together "
                  f"{row['pipeline_and_export_frames_per_cpu_s']} (wall {p['wall_s'] + x['wall_s']:.1f} s)")
            if "preview_gif" in row:
                print(f"  preview GIF: {row['preview_gif']}")
            for f in row.get("fresh_process", []):
                print(f"  fresh process, {'with' if f['fast_backends'] else 'without'} [fast]: {f['cpu_s']} CPU s "
                      f"({f['frames_per_cpu_s']} frames/CPU s, exit {f['exit']}, wall {f['wall_s']} s)")
    checks = {"pipeline_and_export_at_least_60_frames_per_cpu_s":
              all(r["pipeline_and_export_frames_per_cpu_s"] >= TARGET_FRAMES_PER_CPU_S for r in rows)}
    print(checks)
    if not args.no_save and rows:
        print(f"wrote {save('animation_speed', {'folder': str(args.folder), 'rows': rows, 'checks': checks})}")


if __name__ == "__main__":
    main()
