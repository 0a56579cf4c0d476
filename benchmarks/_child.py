"""Timing a command in a fresh child process (numpy/torch-free, so a benchmark's own child stays light): its CPU
seconds, with or without the ``[fast]`` backends (numba, onnxruntime)."""

from __future__ import annotations

import os
import resource
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HIDE_FAST = "import sys\nfor _m in ('numba', 'onnxruntime'):\n    sys.modules[_m] = None\n"
"""A ``sitecustomize`` that makes the ``[fast]`` backends unimportable in the child."""


def child_cpu(cmd: list[str], env: dict[str, str]) -> tuple[int, float, float, str]:
    """Run ``cmd``: its exit status, CPU seconds (user + system of the child), wall seconds and its output."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return res.returncode, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall, \
        res.stdout + res.stderr


def child_env(tmp: Path, hide_fast: bool) -> dict[str, str]:
    """The child's environment: one thread, headless rendering, this checkout first on the path, and with
    ``hide_fast`` a ``sitecustomize`` (written under ``tmp``) that hides the ``[fast]`` backends."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM", "egl")}
    paths = [str(ROOT)]
    if hide_fast:
        site = tmp / "hide_fast"
        site.mkdir(exist_ok=True)
        (site / "sitecustomize.py").write_text(HIDE_FAST)
        paths.insert(0, str(site))
    env["PYTHONPATH"] = os.pathsep.join(paths + [env.get("PYTHONPATH", "")])
    return env
