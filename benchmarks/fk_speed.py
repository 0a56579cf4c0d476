"""FK throughput: our depth-level skeleton FK vs smplx's joints path (full LBS), same run.

Prints a table and writes benchmarks/results/fk_speed.json.
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save, time_call  # noqa: E402

from smplik.body_model import load_body_model  # noqa: E402


def main() -> None:
    torch.set_num_threads(2)
    model = load_body_model("neutral")
    layer = model.smplx_layer
    rows = []
    for batch in (1, 1024):
        g = torch.Generator().manual_seed(0)
        go, bp = torch.randn(batch, 3, generator=g), torch.randn(batch, 23, 3, generator=g) * 0.4
        tr, betas = torch.randn(batch, 3, generator=g), torch.randn(batch, 10, generator=g)
        with torch.no_grad():
            ours = time_call(lambda go=go, bp=bp, tr=tr, betas=betas: model.joints(go, bp, tr, betas))
            theirs = time_call(lambda go=go, bp=bp, tr=tr, betas=betas: layer(
                global_orient=go, body_pose=bp.reshape(-1, 69), transl=tr, betas=betas))
        for name, times in (("smplik_fk", ours), ("smplx_joints", theirs)):
            med = statistics.median(times)
            rows.append({"method": name, "batch": batch, "median_ms": med * 1e3, "poses_per_s": batch / med})
    print(f"{'method':<14}{'batch':>7}{'median ms':>12}{'poses/s':>14}")
    for r in rows:
        print(f"{r['method']:<14}{r['batch']:>7}{r['median_ms']:>12.3f}{r['poses_per_s']:>14.0f}")
    print("wrote", save("fk_speed", {"vertices": model.num_vertices, "results": rows}))


if __name__ == "__main__":
    main()
