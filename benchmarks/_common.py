"""Helpers shared by the benchmark scripts: timing, machine facts, result files."""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from smplik import paths
from smplik.atomic import write_json_atomic

RESULTS = Path(__file__).resolve().parent / "results"


def shared_dir() -> Path:
    """:func:`smplik.paths.shared_dir` (``$SMPLIK_SHARED_DIR``, else ``../shared``), or the default path when absent."""
    return paths.shared_dir() or paths.repo_root().parent / "shared"


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else :func:`platform.processor`: runs on
    different CPUs of the same 2-core machine kind differ severalfold in speed."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def machine() -> dict[str, Any]:
    return {"cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(), "torch": torch.__version__,
            "platform": platform.platform(), "processor": cpu_model(),
            "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE")}


def time_call(fn: Callable[[], Any], *, min_time: float = 0.5, warmup: int = 3) -> list[float]:
    """Per-call wall times (seconds) after ``warmup`` calls, repeating for at least ``min_time``."""
    for _ in range(warmup):
        fn()
    times: list[float] = []
    start = time.perf_counter()
    while time.perf_counter() - start < min_time or len(times) < 5:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def save(name: str, data: dict[str, Any]) -> Path:
    data = {"machine": machine(), **data}
    return write_json_atomic(RESULTS / f"{name}.json", data)
