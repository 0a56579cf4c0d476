"""What ``smplik track`` costs per frame, the measure behind ``SMPLIK_MAX_TRACK_FRAMES`` (docs/security.md).

For each length (frames at 60 frames/s, four trackers walking a slow circle), the real CLI in a subprocess
(``--export ''``): wall seconds, peak resident memory (``os.wait4``), and both per frame; then one file over
the cap, which must be refused in one line before the tracker runs. Writes
``benchmarks/results/track_frames.json``.

    PYTHONPATH=. nice python benchmarks/track_frames.py --frames 2000,10000,36000
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "track_frames.json"


def recording(frames: int, fps: float = 60.0) -> dict:
    """A ``smplik-trackers`` document: head (with rotation), wrists and pelvis moving on a slow circle."""
    t = np.arange(frames) / fps
    circle = np.stack([0.5 * np.sin(0.3 * t), np.zeros_like(t), 0.5 * np.cos(0.3 * t)], 1)

    def rows(offset: list[float]) -> list:
        return np.round(circle + np.asarray(offset), 4).tolist()

    return {"format": "smplik-trackers", "version": 1, "fps": fps, "trackers": {
        "head": {"position": rows([0, 1.6, 0]), "rotation": [[1.0, 0.0, 0.0, 0.0]] * frames},
        "left_wrist": {"position": rows([0.3, 1.0, 0.05])}, "right_wrist": {"position": rows([-0.3, 1.0, 0.05])},
        "pelvis": {"position": rows([0, 0.95, 0])}}}


def run(path: Path, out: Path, env: dict[str, str]) -> dict:
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", "track", str(path), "--out", str(out), "--export",
                             ""], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=ROOT)
    _, status, rusage = os.wait4(proc.pid, 0)
    stderr = proc.stderr.read().decode() if proc.stderr else ""
    return {"rc": os.waitstatus_to_exitcode(status), "wall_s": round(time.monotonic() - start, 2),
            "peak_mb": round(rusage.ru_maxrss / 1024, 1),
            "last_line": ([ln for ln in stderr.splitlines() if ln.strip()] or [""])[-1][:300]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", default="2000,10000,36000", help="Comma-separated lengths at 60 frames/s.")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    from smplik.limits import TRACK_FRAMES

    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    rows = []
    with tempfile.TemporaryDirectory(prefix="smplik-track-") as tmp:
        work = Path(tmp)
        baseline = None
        for frames in [int(f) for f in args.frames.split(",")] + [TRACK_FRAMES.value + 1]:
            path = work / f"t{frames}.json"
            path.write_text(json.dumps(recording(frames)))
            res = {"frames": frames, "file_mb": round(path.stat().st_size / 2**20, 2),
                   **run(path, work / f"o{frames}", env)}
            if res["rc"] == 0:
                baseline = baseline or res
                res["s_per_1000_frames"] = round(1000 * res["wall_s"] / frames, 3)
            rows.append(res)
            print(json.dumps(res), flush=True)
    ok = [r for r in rows if r["rc"] == 0]
    fit = None
    if len(ok) >= 2:  # linear fit: seconds and MB per frame beyond the start-up
        f = np.asarray([r["frames"] for r in ok], float)
        fit = {"s_per_frame": float(np.polyfit(f, [r["wall_s"] for r in ok], 1)[0]),
               "kb_per_frame": float(np.polyfit(f, [r["peak_mb"] for r in ok], 1)[0] * 1024)}
    refused = rows[-1]
    report = {"cap": TRACK_FRAMES.value, "cap_env": TRACK_FRAMES.env, "cpu": platform.processor() or platform.machine(),
              "load_avg_1min": os.getloadavg()[0], "runs": rows, "fit": fit,
              "over_cap_refused": refused["rc"] == 1 and TRACK_FRAMES.env in refused["last_line"]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
