"""Pose editor latency: a gizmo update arriving on the server -> the new mesh handed to viser.

``python benchmarks/editor_latency.py [--drags 200] [--checkpoint FILE]`` writes
benchmarks/results/editor_latency.json and prints p50 / p95 (ms).

Set-up: the real :class:`workflows.editor.app.EditorApp` on a viser server (port 0, loopback, no
browser attached: the time to send over the websocket is not included) editing the built-in body
with 6 effectors (position on both wrists, both ankles and the pelvis, a look-at on the head), and
a scene of two such characters. One simulated drag = :meth:`EditorApp.drag`, the method a gizmo's
``on_update`` callback runs: move the effector, re-solve that character (network + refinement),
skin its mesh, assign the vertices to its viser mesh handle, move the other gizmos and look-at ray.
Drags follow smooth random paths, cycling over the effectors; in the two-character scene the edited
character alternates every 20 drags. Also timed without viser: the state update alone (solve +
skinning, :meth:`EditorState.move_effector` + :meth:`EditorState.view`).

One torch thread and one BLAS thread, as ``smplik edit`` runs (a second thread does not speed up a single solve,
benchmarks/results/speed.json). Targets: p50 <= 30 ms, p95 <= 50 ms. The load average at start is
saved with the results: other busy processes on the 2 cores inflate every number.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save  # noqa: E402

from smplik.conventions import NUM_BETAS, Gender  # noqa: E402
from smplik.effectors import Effector  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402
from workflows.scene import Scene, SceneCharacter, solve_scene  # noqa: E402

TARGET_P50_MS, TARGET_P95_MS = 30.0, 50.0


def character(name: str, x: float, gender: Gender, betas: np.ndarray) -> SceneCharacter:
    """A body standing at ``x`` with 6 effectors (5 positions, a head look-at)."""
    effs = (Effector.position("left_wrist", (x + 0.55, 1.25, 0.15)),
            Effector.position("right_wrist", (x - 0.5, 1.1, 0.2)),
            Effector.position("left_ankle", (x + 0.12, 0.08, 0.0)),
            Effector.position("right_ankle", (x - 0.12, 0.08, 0.1)),
            Effector.position("pelvis", (x, 0.92, 0.02)), Effector.look_at("head", (x + 0.3, 1.6, 1.5)))
    return SceneCharacter(name, gender, betas, 1.0, None, effs)


def percentiles(times_s: list[float]) -> dict[str, float]:
    ms = np.asarray(times_s) * 1000.0
    return {"p50_ms": round(float(np.percentile(ms, 50)), 2), "p95_ms": round(float(np.percentile(ms, 95)), 2),
            "mean_ms": round(float(ms.mean()), 2), "max_ms": round(float(ms.max()), 2), "drags": int(ms.size)}


def drag_plan(state, drags: int, rng: np.random.Generator, switch_every: int) -> list[tuple[int, int, np.ndarray]]:
    """(character, effector, new position) per drag: a smooth random walk per effector."""
    plan = []
    n_chars = len(state.scene.characters)
    for d in range(drags):
        c = (d // switch_every) % n_chars
        effs = state.scene.characters[c].effectors
        k = d % len(effs)
        base = np.asarray(effs[k].value)
        phase = 2 * np.pi * d / drags
        plan.append((c, k, base + 0.08 * np.array([np.sin(phase + k), np.cos(1.3 * phase), np.sin(0.7 * phase)])
                     + rng.normal(0, 0.005, 3)))
    return plan


def run(solver: IKSolver, n_chars: int, drags: int, threads: int) -> dict[str, dict[str, float]]:
    from workflows.editor.app import EditorApp
    from workflows.editor.state import EditorState

    torch.set_num_threads(threads)
    threadpool_limits(threads)  # BLAS threads too, as ``smplik edit`` sets them
    chars = [character("a", 0.0, Gender.NEUTRAL, np.zeros(NUM_BETAS)),
             character("b", 1.4, Gender.FEMALE, np.linspace(-0.5, 0.5, NUM_BETAS))][:n_chars]
    scene = solve_scene(Scene(tuple(chars)), solver)
    rng = np.random.default_rng(0)

    state = EditorState(scene, solver)
    plan = drag_plan(state, drags, rng, switch_every=20)
    state_times, state_cpu = [], []
    for c, k, p in plan:
        state.select_character(c)
        t0, c0 = time.perf_counter(), time.thread_time()
        state.move_effector(k, position=p)
        state.view()
        state_times.append(time.perf_counter() - t0)
        state_cpu.append(time.thread_time() - c0)

    app = EditorApp(EditorState(scene, solver), host="127.0.0.1", port=0)
    try:
        for _, k, p in plan[:5]:  # warm-up
            app.drag(k, p, np.array([1.0, 0, 0, 0]))
        app_times, app_cpu = [], []
        for c, k, p in plan:
            if app.state.active != c:
                app.state.select_character(c)
                app.refresh()
            t0, c0 = time.perf_counter(), time.thread_time()
            app.drag(k, p, np.array([1.0, 0.0, 0.0, 0.0]))
            app_times.append(time.perf_counter() - t0)
            app_cpu.append(time.thread_time() - c0)
    finally:
        app.stop()
    return {"gizmo_to_viser": percentiles(app_times), "gizmo_to_viser_cpu": percentiles(app_cpu),
            "state_only": percentiles(state_times), "state_only_cpu": percentiles(state_cpu)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--drags", type=int, default=200)
    parser.add_argument("--checkpoint", type=Path, default=None)
    args = parser.parse_args()
    load_at_start = list(os.getloadavg())
    solver = IKSolver.load(args.checkpoint)
    results: dict[str, dict] = {}
    for n in (1, 2):
        key = f"{n}_character{'s' if n > 1 else ''}"
        results[key] = run(solver, n, args.drags, threads=1)
        r = results[key]["gizmo_to_viser"]
        cpu = results[key]["gizmo_to_viser_cpu"]
        print(f"{key:14s} gizmo->viser wall p50 {r['p50_ms']:6.2f} ms  p95 {r['p95_ms']:6.2f} ms; "
              f"CPU p50 {cpu['p50_ms']:6.2f} ms  p95 {cpu['p95_ms']:6.2f} ms "
              f"(state only wall p50 {results[key]['state_only']['p50_ms']:.2f} ms)")
    path = save("editor_latency", {
        "what": "gizmo update on the server -> new mesh handed to viser (EditorApp.drag), 6 effectors per "
                "character, built-in body, 1 torch thread; state_only: EditorState.move_effector + view "
                "(solve + skinning)",
        "targets_ms": {"p50": TARGET_P50_MS, "p95": TARGET_P95_MS},
        "load_average_at_start": load_at_start, "load_average_at_end": list(os.getloadavg()),
        "model": solver.source, "results": results})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
