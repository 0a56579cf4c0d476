"""How tolerance changes adherence: the shipped model on 12 cm effector pulls, network alone vs solver.

Scenario (:mod:`smplik.benchmark.tolerance`, the one ``tests/test_shipped_model.py`` asserts on): 256 random
bodies; six position effectors (pelvis, head, wrists, ankles) at the joints of a plausible pose
the model itself produced; then every effector pulled 12 cm in a random direction (some pulls are
out of reach). For tolerances 0, 0.25, 0.5, 0.75, 1, with the network alone and with the solver's
default refinement: how far the effector joints move along the pull (tracking, mm) and how far
they end from the pulled targets (residual, mm).

Prints a table and writes ``benchmarks/results/tolerance_tracking.json``.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import save  # noqa: E402

from smplik.benchmark.tolerance import (  # noqa: E402
    PULL_M,
    make_fixed_set,
    pulled,
    residual_mm,
    tracked_joints,
    tracking_mm,
)
from smplik.refine import NO_REFINEMENT  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402

TOLERANCES = (0.0, 0.25, 0.5, 0.75, 1.0)


def main() -> None:
    torch.set_num_threads(1)
    solver = IKSolver.load()
    truth, betas, gender = make_fixed_set(solver.model)
    targets = pulled(truth)
    rows: dict[str, dict[str, dict[str, float]]] = {}
    print(f"{'path':<10}{'tolerance':>10}{'tracking mm':>13}{'residual mm':>13}")
    for name, refine in (("network", NO_REFINEMENT), ("solver", None)):
        solve = functools.partial(solver.solve_tensors, refine=refine)
        base = tracked_joints(solve, truth, betas, gender, 0.0)
        rows[name] = {}
        for tol in TOLERANCES:
            moved = tracked_joints(solve, targets, betas, gender, tol)
            tracking, residual = tracking_mm(base, moved, truth, targets), residual_mm(moved, targets)
            rows[name][str(tol)] = {"tracking_mm": round(tracking, 1), "residual_mm": round(residual, 1)}
            print(f"{name:<10}{tol:>10.2f}{tracking:>13.1f}{residual:>13.1f}")
    path = save("tolerance_tracking", {"model": solver.source, "model_step": solver.meta.get("step"),
                                       "poses": int(truth.shape[0]), "pull_m": PULL_M,
                                       "refine": solver.refine.to_dict(), "results": rows})
    print("wrote", path)


if __name__ == "__main__":
    main()
