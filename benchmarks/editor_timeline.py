"""The editor's timeline: one playback tick and one Apply, on an animation of a real video estimate.

``python benchmarks/editor_timeline.py [--animation FILE | --data DIR] [--ticks 300] [--checkpoint FILE]``
writes benchmarks/results/editor_timeline.json and prints p50 / p95 (ms).

The animation: ``--animation`` (an ``animation.json`` of ``smplik scene animate``), else the one that
``scene animate --fps 30`` (defaults otherwise) makes of GVHMR's ``gvhmr_video2smpl/1/hmr4d_results.pt`` in the
real-estimator folder (``--data``, else ``$SMPLIK_REAL_ESTIMATORS``, else ``<cache>/real/estimators``;
third-party, outside the repository). Without either it says so and exits 0.

Measured on the real :class:`workflows.editor.timeline_app.AnimationEditorApp` (viser server on a loopback
port, no browser attached: sending over the websocket is not included):

* ``tick``: :meth:`AnimationEditorApp.play_step` -- what the playback thread runs per frame: the next frame's
  scene, every track's skinned mesh and the panel values handed to viser. Budget: one frame at the source
  rate (33.3 ms at 30 frames/s); a slower tick makes playback skip frames, never slow down.
* ``apply``: a left-wrist handle added on a keyframe and dragged 15 cm up, then :meth:`apply` (blend window
  10): ``edit_keyframe`` (the solve with refinement + the blend) and the redraw.

One torch thread and one BLAS thread, as ``smplik edit`` runs. The load average is saved with the results.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import torch
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save  # noqa: E402
from editor_latency import percentiles  # noqa: E402

from smplik.paths import real_estimators_dir  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402

GVHMR = Path("gvhmr_video2smpl") / "1" / "hmr4d_results.pt"


def stats(times_s: list[float]) -> dict[str, float]:
    """p50 / p95 / mean / max in ms and the sample count (``n``)."""
    out = percentiles(times_s)
    out["n"] = out.pop("drags")
    return out


def measure(animation: Path, solver: IKSolver, ticks: int, applies: int) -> dict:
    from workflows.editor.timeline import AnimationTimeline
    from workflows.editor.timeline_app import AnimationEditorApp

    timeline = AnimationTimeline.open(animation, solver, window=10)
    app = AnimationEditorApp(timeline, solver, host="127.0.0.1", port=0)
    try:
        for _ in range(5):  # warm-up
            app.play_step()
        wall, cpu = [], []
        for _ in range(ticks):
            t0, c0 = time.perf_counter(), time.thread_time()
            app.play_step()
            wall.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
        keys = timeline.keyframes()
        apply_wall = []
        for i in range(applies):
            app.goto(keys[i % len(keys)])
            k = app.state.add_effector("left_wrist", "position")
            app.state.move_effector(k, position=app.state.view().joints[20] + [0.0, 0.15, 0.0])
            app.state.end_gesture()
            t0 = time.perf_counter()
            app.apply()
            apply_wall.append(time.perf_counter() - t0)
        frames, tracks = len(timeline.frames), len(timeline.animation.tracks)
        fps = timeline.animation.fps
    finally:
        app.stop()
    return {"animation": animation.name, "frames": frames, "tracks": tracks, "fps": fps,
            "budget_ms": round(1000.0 / fps, 2), "tick": stats(wall), "tick_cpu": stats(cpu),
            "apply": stats(apply_wall)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--animation", type=Path, default=None, help="animation.json of smplik scene animate")
    parser.add_argument("--data", type=Path, default=real_estimators_dir(), help="real estimator outputs folder")
    parser.add_argument("--ticks", type=int, default=300)
    parser.add_argument("--applies", type=int, default=10)
    parser.add_argument("--checkpoint", type=Path, default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    threadpool_limits(1)
    load_at_start = list(os.getloadavg())
    solver = IKSolver.load(args.checkpoint)
    with tempfile.TemporaryDirectory() as tmp:
        animation, source = args.animation, None
        if animation is None:
            source = args.data / GVHMR
            if not source.is_file():
                print(f"no animation given and no {source} (pass --animation, --data or set "
                      "SMPLIK_REAL_ESTIMATORS); nothing to do")
                return
            from workflows.animation.run import animate_file

            animation = animate_file(source, Path(tmp), solver, fps=30.0, formats=()).animation_file
        result = measure(animation, solver, args.ticks, args.applies)
    tick, cpu, apply = result["tick"], result["tick_cpu"], result["apply"]
    print(f"{result['animation']} ({result['frames']} frames, {result['tracks']} track(s), {result['fps']:g} fps): "
          f"tick wall p50 {tick['p50_ms']:.2f} ms p95 {tick['p95_ms']:.2f} ms (CPU p50 {cpu['p50_ms']:.2f}), "
          f"budget {result['budget_ms']} ms; apply p50 {apply['p50_ms']:.1f} ms p95 {apply['p95_ms']:.1f} ms")
    path = save("editor_timeline", {
        "what": "AnimationEditorApp.play_step (one playback tick: next frame's meshes and panel handed to viser) and "
                "apply (edit_keyframe of a 15 cm wrist drag on a keyframe, window 10, and the redraw); 1 torch thread",
        "source": None if source is None else str(GVHMR), "load_average_at_start": load_at_start,
        "load_average_at_end": list(os.getloadavg()), "model": solver.source, "results": result})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
