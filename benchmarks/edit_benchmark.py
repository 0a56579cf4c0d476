"""Edit benchmark: single-limb edits from real motion (test split), every method side by side.

``python benchmarks/edit_benchmark.py [--data CACHE] [--clips DIR] [--max-pairs 150] ...`` runs
``smplik benchmark edits --out benchmarks/results/edit_benchmark.json`` (the figure beside it,
``edit_benchmark.png``); see :mod:`workflows.edit_benchmark` and docs/editing.md. ``--data`` defaults to
the pose cache of :func:`smplik.paths.pose_cache` (``smplik data build``); ``--clips`` adds a folder of
held-out BVH clips (default ``$SMPLIK_EDIT_CLIPS`` when set; ``--clips-preset``: their retarget preset,
default ``auto``, the rig mapper). The committed results add ``--clips ../shared/data/cmu-dance``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import RESULTS  # noqa: E402

from smplik.cli.errors import run_guarded  # noqa: E402
from workflows.benchmark_cli import app  # noqa: E402


def main(argv: list[str]) -> int:
    args = ["edits", *argv]
    if "--out" not in argv:
        args += ["--out", str(RESULTS / "edit_benchmark.json")]
    if "--clips" not in argv and os.environ.get("SMPLIK_EDIT_CLIPS"):
        args += ["--clips", os.environ["SMPLIK_EDIT_CLIPS"]]
    run_guarded(app, args)  # exits with the command's status
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
