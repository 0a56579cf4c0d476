"""Where ``smplik scene animate``'s time goes on real estimator files, stage by stage, end to end (issue 44, item 4).

Reads every estimator file under a folder (the first argument, else ``$SMPLIK_REAL_ESTIMATORS``, else
``<cache>/real/estimators``; the files stay outside the repository; ``docs/animation.md``, "Speed on real files",
says where each one is published: GVHMR's tennis demo, WHAM's demo, an AIST++ motion, 4D-Humans ``track.py`` runs).
Per file, three measurements, all CPU time (``time.process_time`` / ``getrusage``; the machine is shared, so wall
times are printed but not judged):

* **stages**, in a fresh process (``python benchmarks/animation_real_speed.py --child FILE``) that runs what the
  command runs, one stage after the other: ``start`` (the interpreter and the command's imports: numpy, torch,
  scipy), ``model`` (:func:`workflows.cli_shared._solver`: the shipped model, its ONNX/numba backends),
  ``read`` (:func:`workflows.animation.clips.read_clip`), then inside
  :func:`~workflows.animation.clips.animation_from_clip`: ``clean`` (:func:`~workflows.animation.clips.clean_track`),
  ``keyframes`` (:func:`~workflows.animation.clips.select_keyframes`), ``effectors`` (the keyframes' effector
  recovery, :func:`workflows.scene.recovery.recover_many`) and ``other`` (retargeting, rest joints, records),
  ``export`` (``animation.json`` + BVH + GLB of every track), and ``preview`` (the GIF, every 2nd frame of a 30
  frames/s clip; ``--no-preview`` skips it; not part of the end-to-end figure, as ``--preview`` is optional);
* **command**: ``smplik scene animate FILE --export bvh,glb`` in a fresh process, its whole CPU time (children
  included), with the optional ``[fast]`` extra's backends as installed and, with ``--fast-off``, hidden
  (``numba`` and ``onnxruntime`` unimportable through a ``sitecustomize``);
* **warm**: in this process, the model loaded once and the file animated once before (a server or a batch of
  files: ``smplik batch``), read to export.

Frames per CPU second = the file's frames / CPU seconds. Target (issue 44): at least 60 end to end, export
included. Prints a table and writes ``benchmarks/results/animation_real_speed.json``; without files it says so and
exits 0.
"""

from __future__ import annotations

import time

_T0 = time.process_time()  # the interpreter's start, before any import of this script

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from _child import child_cpu, child_env  # noqa: E402

SUFFIXES = (".pt", ".pkl", ".pk", ".npz")
TARGET = 60.0
ASSUMED_FPS = 30.0
"""Frame rate given to formats that store none (WHAM, PHALP: their demos' video rate; GVHMR's 30 is the reader's)."""
STAGES = ("start", "model", "read", "clean", "keyframes", "effectors", "other", "export")


def source_fps(path: Path) -> float | None:
    """None where the file stores its frame rate or the reader assumes one, else :data:`ASSUMED_FPS`."""
    from workflows.animation.clips import ASSUMED_FPS as KNOWN_DEFAULTS
    from workflows.animation.clips import KNOWN_FPS, read_clip

    clip = read_clip(path, frames=(0, 3))
    known = clip.fps is not None or clip.format in KNOWN_DEFAULTS or clip.format in KNOWN_FPS
    return None if known else ASSUMED_FPS


class Timer:
    """CPU seconds spent inside wrapped functions, per stage (nested calls count once, in the outer stage)."""

    def __init__(self) -> None:
        self.spent: dict[str, float] = {}
        self.depth = 0
        self.originals: list[tuple[object, str, object]] = []

    def restore(self) -> None:
        for module, name, fn in self.originals:
            setattr(module, name, fn)

    def wrap(self, module, name: str, stage: str) -> None:
        fn = getattr(module, name)
        self.originals.append((module, name, fn))

        def timed(*args, **kwargs):
            if self.depth:
                return fn(*args, **kwargs)
            self.depth += 1
            start = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.spent[stage] = self.spent.get(stage, 0.0) + time.process_time() - start
                self.depth -= 1

        setattr(module, name, timed)


def animate_stages(path: Path, out: Path, fps: float | None, solver=None, preview: bool = False) -> dict:
    """Run ``scene animate``'s stages on ``path`` (as :func:`workflows.animation.run.animate_file` does with
    ``--export bvh,glb``); CPU seconds per stage (:data:`STAGES`, without ``start``) and the frames."""
    from workflows.animation import clips
    from workflows.animation.files import save_animation
    from workflows.animation.run import export_animation
    from workflows.cli_shared import _solver
    from workflows.scene import recovery

    timer = Timer()
    timer.wrap(clips, "clean_track", "clean")
    timer.wrap(clips, "select_keyframes", "keyframes")
    timer.wrap(recovery, "recover_many", "effectors")
    cpu = {}
    start = time.process_time()
    if solver is None:
        solver = _solver(None)
        cpu["model"] = time.process_time() - start
    start = time.process_time()
    clip = clips.read_clip(path, solver=solver)
    cpu["read"] = time.process_time() - start
    start = time.process_time()
    first = next(iter(clip.tracks.values()))[0][1]
    animation, _ = clips.animation_from_clip(clip, solver, fps=fps, camera=first.camera)
    total = time.process_time() - start
    for stage in ("clean", "keyframes", "effectors"):
        cpu[stage] = timer.spent.get(stage, 0.0)
    cpu["other"] = total - sum(cpu[s] for s in ("clean", "keyframes", "effectors"))
    start = time.process_time()
    out.mkdir(parents=True, exist_ok=True)
    save_animation(animation, out / "animation.json")
    export_animation(animation, out, ("bvh", "glb"))
    cpu["export"] = time.process_time() - start
    if preview:
        from workflows.animation.preview import write_preview

        start = time.process_time()
        try:
            write_preview(animation, out / "preview.gif")
            cpu["preview"] = time.process_time() - start
        except Exception as exc:  # no GL backend here: said, not fatal
            cpu["preview_error"] = f"{type(exc).__name__}: {exc}"[:200]
    timer.restore()
    frames = sum(t.num_frames for t in animation.tracks)
    return {"frames": frames, "tracks": len(animation.tracks),
            "keyframes": sum(len(t.keyframes) for t in animation.tracks), "cpu_s": cpu}


def child(path: Path, out: Path, fps: float | None, preview: bool) -> None:
    """The fresh process of the stage split: prints one JSON line."""
    import torch  # noqa: F401  (the command's own imports: what its start costs)

    import workflows.animation.cli  # noqa: F401
    import workflows.animation.run  # noqa: F401
    import workflows.cli_shared  # noqa: F401

    start = time.process_time()  # the imports above plus the interpreter: the command's start
    row = animate_stages(path, out, fps, preview=preview)
    row["cpu_s"] = {"start": start, **row["cpu_s"]}
    print(json.dumps(row))


def fps_args(fps: float | None) -> list[str]:
    return ["--fps", str(fps)] if fps else []


def bench(path: Path, tmp: Path, solver, preview: bool, fast_off: bool) -> dict:
    fps = source_fps(path)
    rc, _, _, text = child_cpu([sys.executable, __file__, "--child", str(path), "--out", str(tmp / "stages"),
                                 *(["--child-preview"] if preview else []), *fps_args(fps)], child_env(tmp, False))
    if rc != 0:
        raise RuntimeError(text.strip().splitlines()[-1] if text.strip() else f"exit {rc}")
    row = json.loads(text.strip().splitlines()[-1])
    frames = row["frames"]
    cpu = row["cpu_s"]
    end_to_end = sum(cpu[s] for s in STAGES)
    row["stages_end_to_end_cpu_s"] = round(end_to_end, 3)
    row["stages_frames_per_cpu_s"] = round(frames / end_to_end, 1)
    row["cpu_s"] = {k: round(v, 3) if isinstance(v, float) else v for k, v in cpu.items()}
    row["command"] = []
    for hide in (False, True) if fast_off else (False,):
        rc, c, wall, text = child_cpu([sys.executable, "-m", "smplik.cli", "scene", "animate", str(path), "--out",
                                        str(tmp / f"cmd{int(hide)}"), "--export", "bvh,glb", *fps_args(fps)],
                                       child_env(tmp, hide))
        row["command"].append({"fast_backends": not hide, "exit": rc, "cpu_s": round(c, 2), "wall_s": round(wall, 2),
                               "frames_per_cpu_s": round(frames / c, 1) if rc == 0 else None,
                               **({} if rc == 0 else {"error": text.strip()[-300:]})})
    animate_stages(path, tmp / "warm0", fps, solver=solver)  # first-call caches are not the steady speed
    warm = animate_stages(path, tmp / "warm", fps, solver=solver)["cpu_s"]
    total = sum(warm[s] for s in STAGES if s in warm)
    row["warm"] = {"cpu_s": {k: round(v, 3) for k, v in warm.items()}, "end_to_end_cpu_s": round(total, 3),
                   "frames_per_cpu_s": round(frames / total, 1)}
    row["fps"] = fps
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder", type=Path, nargs="?", default=None)
    parser.add_argument("--only", default="", help="Only files whose path contains this.")
    parser.add_argument("--no-preview", action="store_true")
    parser.add_argument("--fast-off", default=None, metavar="PATTERN",
                        help="Also run the command without the [fast] backends, on files whose path contains PATTERN "
                             "('' for every file).")
    parser.add_argument("--demo", action="store_true", help="Also time `smplik demo` with and without [fast].")
    parser.add_argument("--no-save", action="store_true")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--child-preview", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--fps", type=float, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        child(args.child, args.out, args.fps, args.child_preview)
        return
    from smplik.paths import real_estimators_dir

    folder = args.folder or real_estimators_dir()
    files = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix in SUFFIXES
                   and args.only in str(p)) if folder.is_dir() else []
    if not files:
        print(f"no estimator files under {folder} (pass a folder or set SMPLIK_REAL_ESTIMATORS); nothing to do")
        return
    import torch
    from _common import save

    from workflows.cli_shared import _solver

    torch.set_num_threads(1)
    solver = _solver(None)
    rows = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        for k, path in enumerate(files):
            tmp = Path(tmp_dir) / str(k)
            tmp.mkdir()
            try:
                row = bench(path, tmp, solver, not args.no_preview,
                            args.fast_off is not None and args.fast_off in str(path))
            except Exception as exc:  # a file scene animate refuses: listed, not fatal
                print(f"{path}: refused ({type(exc).__name__}: {str(exc)[:160]})")
                continue
            row["file"] = str(path.relative_to(folder))
            rows.append(row)
            cpu = row["cpu_s"]
            split = ", ".join(f"{s} {cpu[s]:.2f}" for s in STAGES)
            print(f"{row['file']}: {row['frames']} frames, {row['keyframes']} keyframes")
            print(f"  fresh process, CPU s per stage: {split}; end to end {row['stages_end_to_end_cpu_s']:.2f} s = "
                  f"{row['stages_frames_per_cpu_s']} frames/CPU s" +
                  (f"; GIF preview {cpu['preview']:.2f} s" if "preview" in cpu else ""))
            for c in row["command"]:
                print(f"  command, {'with' if c['fast_backends'] else 'without'} [fast]: {c['cpu_s']} CPU s = "
                      f"{c['frames_per_cpu_s']} frames/CPU s (exit {c['exit']}, wall {c['wall_s']} s)")
            w = row["warm"]
            print(f"  warm (model loaded): {w['end_to_end_cpu_s']:.2f} CPU s = {w['frames_per_cpu_s']} frames/CPU s "
                  f"({', '.join(f'{s} {v:.2f}' for s, v in w['cpu_s'].items())})")
    demo = []
    if args.demo:
        with tempfile.TemporaryDirectory() as tmp_dir:
            for hide in (False, True):
                out = str(Path(tmp_dir) / f"demo{int(hide)}")
                rc, c, wall, _ = child_cpu([sys.executable, "-m", "smplik.cli", "demo", "--out", out],
                                            child_env(Path(tmp_dir), hide))
                demo.append({"fast_backends": not hide, "exit": rc, "cpu_s": round(c, 2), "wall_s": round(wall, 2)})
                print(f"smplik demo, {'with' if not hide else 'without'} [fast]: {c:.1f} CPU s (exit {rc}, wall "
                      f"{wall:.0f} s)")
    checks = {"command_at_least_60": {r["file"]: r["command"][0]["frames_per_cpu_s"] is not None
                                      and r["command"][0]["frames_per_cpu_s"] >= TARGET for r in rows},
              "warm_at_least_60": {r["file"]: r["warm"]["frames_per_cpu_s"] >= TARGET for r in rows}}
    print(json.dumps(checks))
    if not args.no_save and rows:
        result = {"folder": str(folder), "rows": rows, "demo": demo, "checks": checks}
        print(f"wrote {save('animation_real_speed', result)}")


if __name__ == "__main__":
    main()
