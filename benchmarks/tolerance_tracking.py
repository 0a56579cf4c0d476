"""How tolerance changes adherence: the shipped model on 12 cm effector pulls, network alone vs solver.

Scenario (the one ``tests/test_shipped_model.py`` asserts on, imported from there): 256 random
bodies; six position effectors (pelvis, head, wrists, ankles) at the joints of a plausible pose
the model itself produced; then every effector pulled 12 cm in a random direction (some pulls are
out of reach). For tolerances 0, 0.25, 0.5, 0.75, 1, with the network alone and with the solver's
default refinement: how far the effector joints move along the pull (tracking, mm) and how far
they end from the pulled targets (residual, mm).

Prints a table and writes ``benchmarks/results/tolerance_tracking.json``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
from _common import save  # noqa: E402
from test_shipped_model import JOINTS, make_fixed_set, positions, pulled  # noqa: E402

from smplik.refine import NO_REFINEMENT  # noqa: E402
from smplik.solver import IKSolver  # noqa: E402

TOLERANCES = (0.0, 0.25, 0.5, 0.75, 1.0)


def main() -> None:
    torch.set_num_threads(1)
    solver = IKSolver.load()
    fixed = make_fixed_set(solver.model)
    truth, betas, gender = fixed
    targets = pulled(fixed)
    rows: dict[str, dict[str, dict[str, float]]] = {}
    print(f"{'path':<10}{'tolerance':>10}{'tracking mm':>13}{'residual mm':>13}")
    for name, refine in (("network", NO_REFINEMENT), ("solver", None)):
        base = solver.solve_tensors(positions(truth, 0.0), betas, gender, refine=refine).p_world[:, JOINTS]
        rows[name] = {}
        for tol in TOLERANCES:
            moved = solver.solve_tensors(positions(targets, tol), betas, gender, refine=refine).p_world[:, JOINTS]
            tracking = float(((moved - base) * (targets - truth)).sum(-1).mean() / 0.12 * 1000)
            residual = float((moved - targets).norm(dim=-1).mean() * 1000)
            rows[name][str(tol)] = {"tracking_mm": round(tracking, 1), "residual_mm": round(residual, 1)}
            print(f"{name:<10}{tol:>10.2f}{tracking:>13.1f}{residual:>13.1f}")
    path = save("tolerance_tracking", {"model": solver.source, "model_step": solver.meta.get("step"),
                                       "poses": int(truth.shape[0]), "pull_m": 0.12,
                                       "refine": solver.refine.to_dict(), "results": rows})
    print("wrote", path)


if __name__ == "__main__":
    main()
