"""Throughput of ``smplik batch`` against a shell loop of ``smplik`` processes, in inputs per minute.

The inputs: ``--inputs`` copies of the demo's ROMP file (two people, built-in material), each a separate file.
The job: ``scene from-estimate --no-previews``. Cases, each timed from the command's start to its end:

* ``loop``: one ``smplik scene from-estimate`` process per input, one after the other (``for f in ...; do smplik
  ...; done``); ``loop_x2``: two such processes at a time (``xargs -P 2``);
* ``batch``: ``smplik batch from-estimate DIR`` with ``--workers 1`` and ``--workers 2`` (local process pool);
  with ``--ray`` also ``--engine ray --workers 2`` (a local Ray with 2 CPUs). Besides the whole run's rate, a
  batch case reports its start (``start_s``: the wall time not spent in inputs: the workers' start, torch, the
  model) and its rate once warm (``warm_inputs_per_min``: the workers over the median input's seconds, each
  worker's first input, which carries its warm-up, left out): the rate a long batch approaches.

Every case writes into a fresh folder, so none skips inputs. Per input: each loop process's wall time, and each
batch input's seconds from ``batch_report.json`` (the first inputs of each worker carry its warm-up).

Run: ``nice python benchmarks/batch.py [--inputs 8] [--ray]``; prints a table and writes
benchmarks/results/batch.json. A few minutes on a 2-core machine; run it on an idle one.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parent.parent)]
from _common import save  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
JOB_OPTIONS = ["--no-previews"]


def smplik(*args: str) -> tuple[float, subprocess.CompletedProcess]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    start = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "smplik.cli", *args], capture_output=True, text=True, env=env)
    return time.perf_counter() - start, res


def loop(files: list[Path], out: Path, parallel: int) -> dict:
    """One process per input, ``parallel`` at a time."""
    def one(f: Path) -> float:
        seconds, res = smplik("scene", "from-estimate", str(f), "--out", str(out / f.stem), *JOB_OPTIONS)
        if res.returncode != 0:
            raise SystemExit(f"smplik failed on {f}: {res.stderr[-2000:]}")
        return seconds

    start = time.perf_counter()
    with ThreadPoolExecutor(parallel) as pool:
        per_input = list(pool.map(one, files))
    wall = time.perf_counter() - start
    return {"wall_s": wall, "inputs_per_min": 60 * len(files) / wall,
            "per_input_s": {f.stem: s for f, s in zip(files, per_input, strict=True)}}


def batch(folder: Path, out: Path, workers: int, engine: str = "local") -> dict:
    wall, res = smplik("batch", "from-estimate", str(folder), "--out", str(out), "--workers", str(workers),
                       "--engine", engine, "--", *JOB_OPTIONS)
    if res.returncode != 0:
        raise SystemExit(f"smplik batch failed: {res.stderr[-2000:]}")
    report = json.loads((out / "batch_report.json").read_text())
    per_input = {r["name"]: r["seconds"] for r in report["inputs"]}
    warm = sorted(per_input.values())[:-workers] or sorted(per_input.values())  # each worker's first: its warm-up
    warm_median = statistics.median(warm)
    return {"wall_s": wall, "inputs_per_min": 60 * len(report["inputs"]) / wall, "workers": workers,
            "start_s": wall - sum(per_input.values()) / workers, "warm_median_s": warm_median,
            "warm_inputs_per_min": 60 * workers / warm_median, "per_input_s": per_input}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--inputs", type=int, default=8, help="number of input files")
    parser.add_argument("--ray", action="store_true", help="also the Ray engine (2 workers)")
    args = parser.parse_args()
    from workflows.examples_gen import write_romp_example

    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        folder = tmp_path / "inputs"
        folder.mkdir()
        first = write_romp_example(folder / "clip_00.npz")
        files = [first] + [folder / f"clip_{i:02d}.npz" for i in range(1, args.inputs)]
        for f in files[1:]:
            f.write_bytes(first.read_bytes())
        load_before = os.getloadavg()[0]
        cases = {"loop": loop(files, tmp_path / "loop", 1), "loop_x2": loop(files, tmp_path / "loop2", 2),
                 "batch_workers_1": batch(folder, tmp_path / "b1", 1),
                 "batch_workers_2": batch(folder, tmp_path / "b2", 2)}
        if args.ray:
            cases["batch_ray_workers_2"] = batch(folder, tmp_path / "ray2", 2, engine="ray")
        same = all((tmp_path / "loop" / f.stem / "scene.json").read_text().replace(str(f), "")
                   == (tmp_path / "b2" / f.stem / "scene.json").read_text().replace(str(f), "") for f in files)
    base = cases["loop"]["inputs_per_min"]
    for case in cases.values():
        case["speedup_vs_loop"] = case["inputs_per_min"] / base
    print(f"{'case':22s} {'wall s':>8s} {'inputs/min':>11s} {'x loop':>7s} {'start s':>8s} {'warm inputs/min':>16s}")
    for name, case in cases.items():
        warm = f"{case['start_s']:8.1f} {case['warm_inputs_per_min']:16.1f}" if "start_s" in case else ""
        print(f"{name:22s} {case['wall_s']:8.1f} {case['inputs_per_min']:11.1f} {case['speedup_vs_loop']:7.2f} {warm}")
    path = save("batch", {"job": "scene from-estimate " + " ".join(JOB_OPTIONS), "inputs": args.inputs,
                          "input": "the demo's ROMP file (2 people), one copy per input",
                          "batch_outputs_equal_loop_outputs": same, "load_average_before": load_before,
                          "load_average_after": os.getloadavg()[0], "cases": cases})
    print(f"batch scene.json equal to the loop's: {same}; wrote {path}")


if __name__ == "__main__":
    main()
