"""Edit benchmark: single-limb edits from real motion (test split), every method side by side.

``python benchmarks/edit_benchmark.py [--data CACHE] [--clips DIR] [--max-pairs 150] ...`` runs
``smplik benchmark edits --out benchmarks/results/edit_benchmark.json`` (the figure beside it,
``edit_benchmark.png``); see :mod:`workflows.edit_benchmark` and docs/editing.md. ``--data`` defaults to
the pose cache of :func:`smplik.paths.pose_cache` (``smplik data build``); ``--clips`` adds a folder of
held-out BVH clips (default ``$SMPLIK_EDIT_CLIPS`` when set; ``--clips-preset``: their retarget preset,
default ``auto``, the rig mapper). The committed results add ``--clips ../shared/data/cmu-dance``.

``python benchmarks/edit_benchmark.py --joints [--clips DIR] [--pairs-per-joint 40]`` runs only the joint drags
(:mod:`workflows.edit_benchmark.joints`: elbows, knees, head, neck, spine, pelvis dragged on real motion; default
clips ``../shared/data/cmu-dance``, held-out subjects) and writes them into the results file as ``joint_drags``,
keeping its other parts.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS  # noqa: E402

from smplik.cli.errors import run_guarded  # noqa: E402
from workflows.benchmark_cli import app  # noqa: E402


def joint_drags(argv: list[str]) -> int:
    """``--joints``: the joint-drag part only, merged into the results file (module docstring)."""
    import argparse
    import json
    import time

    from _common import machine, shared_dir

    from smplik.atomic import write_json_atomic
    from smplik.solver import IKSolver
    from workflows.edit_benchmark.joints import joint_drag_benchmark
    from workflows.edit_benchmark.run import clips_from_folder

    parser = argparse.ArgumentParser(prog="edit_benchmark.py --joints")
    parser.add_argument("--clips", type=Path, default=shared_dir() / "data" / "cmu-dance")
    parser.add_argument("--clips-preset", default="auto")
    parser.add_argument("--pairs-per-joint", type=int, default=40)
    parser.add_argument("--out", type=Path, default=RESULTS / "edit_benchmark.json")
    args = parser.parse_args(argv)
    if not args.clips.is_dir():
        print(f"error: clips folder {args.clips} not found (give --clips DIR of BVH files).", file=sys.stderr)
        return 1
    clips = clips_from_folder(args.clips, preset=args.clips_preset)
    solver = IKSolver.load()
    start = time.process_time()
    part = joint_drag_benchmark(clips, solver, pairs_per_joint=args.pairs_per_joint, progress=print)
    part |= {"folder": str(args.clips), "preset": args.clips_preset, "machine": machine(),
             "cpu_seconds": round(time.process_time() - start, 1)}
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {}
    doc["joint_drags"] = part
    write_json_atomic(args.out, doc)
    print(f"wrote {args.out} (joint_drags)")
    return 0


def main(argv: list[str]) -> int:
    if "--joints" in argv:
        return joint_drags([a for a in argv if a != "--joints"])
    args = ["edits", *argv]
    if "--out" not in argv:
        args += ["--out", str(RESULTS / "edit_benchmark.json")]
    if "--clips" not in argv and os.environ.get("SMPLIK_EDIT_CLIPS"):
        args += ["--clips", os.environ["SMPLIK_EDIT_CLIPS"]]
    run_guarded(app, args)  # exits with the command's status
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
