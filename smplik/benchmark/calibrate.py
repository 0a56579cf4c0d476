"""Calibrating the refinement to a model on validation-split benchmark files (``smplik benchmark calibrate``).

The refinement's prior holds every joint near the network's answer with the weight ``1 / sigma_prior^2``
(:mod:`smplik.refine`). The network is not equally right on every joint (on the CMU validation split its
local-rotation error ranges from 0.07 rad at the hands to 0.55 rad at the wrists), so a joint it usually
gets right should be held closer and one it often gets wrong should be left to the effectors. The
calibration measures the network's RMS geodesic error ``e_j`` per joint on the random sets, sets each
joint's relative weight to ``(mean(e) / e_j)^(2 alpha)`` (``alpha = 1``: the Gaussian whose spread is the
measured error; 0: uniform), and picks ``alpha`` and ``sigma_prior`` from a grid by the solver's mean
geodesic error over the random N = 6..12 sets (ties: MPJPE), among the settings that keep the meaning of
tolerance: on the tolerance check of :mod:`smplik.benchmark.tolerance` (six effectors pulled 12 cm, some
out of reach) tighter effectors must still be met more closely and tracked further (tolerance 0, 0.5, 1).
A weak prior loses that order (every effector is then met as far as it can be), which is why the grid's
most accurate settings are not always the chosen ones. Use validation-split files only: the test split
stays for the final report (files of the test split are refused).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from smplik.ensemble import EnsembleConfig
from smplik.refine import NO_REFINEMENT, RefineConfig

from .files import Benchmark
from .methods import LearnedMethod
from .runner import run_benchmark
from .tolerance import make_fixed_set, pulled, residual_mm, tracked_joints, tracking_mm

TOLERANCES = (0.0, 0.5, 1.0)

ALPHAS = (0.0, 1.0, 2.0, 3.0)
"""Exponents of the per-joint weights tried (0: the same weight for every joint)."""
SIGMA_PRIORS = (0.5, 0.7, 1.0, 1.5, 2.5)
"""``sigma_prior`` values tried (radians)."""


def network_joint_errors(solver: Any, bench: Benchmark, ensemble: EnsembleConfig | None = None) -> np.ndarray:
    """(J,) RMS geodesic error (radians) of the network's local rotations per joint, over the random sets."""
    squares, count = 0.0, 0
    with torch.inference_mode():
        for bset in bench.sets:
            if bset.kind != "random":
                continue
            out = solver.solve_tensors(bset.effectors, bset.betas, bset.gender, refine=NO_REFINEMENT,
                                       ensemble=ensemble)
            M = out.R_local.double() @ bset.R_local.double().transpose(-1, -2)
            cos = ((M.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0).clamp(-1.0, 1.0)
            squares = squares + torch.arccos(cos).square().sum(0)
            count += len(bset)
    if count == 0:
        raise ValueError(f"{bench.folder}: no random sets to calibrate on.")
    return (squares / count).sqrt().numpy()


def joint_prior_from_errors(errors: np.ndarray, alpha: float) -> tuple[float, ...] | None:
    """Relative prior weights ``(mean(e) / e_j)^(2 alpha)``; None (uniform) for ``alpha == 0``."""
    if alpha == 0:
        return None
    e = np.maximum(np.asarray(errors, dtype=np.float64), 1e-6)
    return tuple(float(v) for v in (e.mean() / e) ** (2.0 * alpha))


def tolerance_order(solver: Any, refine: RefineConfig, ensemble: EnsembleConfig | None = None,
                    fixed: tuple | None = None) -> tuple[list[float], list[float]]:
    """Residual and tracking (mm) of the pulled tolerance check at :data:`TOLERANCES` with ``refine``.

    ``fixed``: :func:`~smplik.benchmark.tolerance.make_fixed_set` of the solver's model (made when None).
    """
    truth, betas, gender = make_fixed_set(solver.model) if fixed is None else fixed
    targets = pulled(truth)

    def solve(eff, b, g):
        return solver.solve_tensors(eff, b, g, refine=refine, ensemble=ensemble)

    base = tracked_joints(solve, truth, betas, gender, 0.0)
    residual, tracking = [], []
    for tol in TOLERANCES:
        moved = tracked_joints(solve, targets, betas, gender, tol)
        residual.append(residual_mm(moved, targets))
        tracking.append(tracking_mm(base, moved, truth, targets))
    return residual, tracking


def keeps_tolerance_order(residual: Sequence[float], tracking: Sequence[float]) -> bool:
    """Strictly increasing residuals and strictly decreasing tracking over increasing tolerance."""
    rising = all(a < b for a, b in zip(residual[:-1], residual[1:], strict=True))
    return rising and all(a > b for a, b in zip(tracking[:-1], tracking[1:], strict=True))


@dataclass(frozen=True)
class Calibration:
    """The chosen refinement, the grid's results and the errors they came from."""

    refine: RefineConfig
    alpha: float
    joint_errors: tuple[float, ...]
    grid: tuple[dict[str, float], ...]
    """One row per (alpha, sigma_prior): the solver's random-set mean geodesic (rad), MPJPE and PA-MPJPE (mm),
    and whether it keeps the tolerance order (``tolerance_order``)."""

    def to_dict(self, source: str = "") -> dict[str, Any]:
        """The record stored beside the settings in a calibrated model file (``refine_calibration``)."""
        return {"files": source, "alpha": self.alpha, "joint_errors_rad": list(self.joint_errors),
                "grid": [dict(row) for row in self.grid]}


def calibrate_refinement(solver: Any, bench: Benchmark, *, alphas: Sequence[float] = ALPHAS,
                         sigma_priors: Sequence[float] = SIGMA_PRIORS, ensemble: EnsembleConfig | None = None,
                         progress: Callable[[dict[str, float]], None] | None = None) -> Calibration:
    """Grid search of the per-joint prior (module docstring) for ``solver`` on ``bench``.

    Args:
        solver: an :class:`smplik.solver.IKSolver`; its ``refine`` gives every setting not searched.
        bench: validation-split benchmark files (:func:`smplik.benchmark.load_benchmark`).
        ensemble: the test-time ensemble the solver will run with (None: the solver's).

    Raises:
        ValueError: files of the test split, or without random sets, or no setting keeps the tolerance order.
    """
    split = bench.manifest.get("source", {}).get("split")
    if split == "test":
        raise ValueError(f"{bench.folder}: these benchmark files come from the test split; calibrate on "
                         "validation-split files (`smplik benchmark make --split validation`).")
    errors = network_joint_errors(solver, bench, ensemble)
    fixed = make_fixed_set(solver.model)
    grid, best = [], None
    for alpha in alphas:
        for sigma in sigma_priors:
            cfg = replace(solver.refine, sigma_prior=float(sigma), joint_prior=joint_prior_from_errors(errors, alpha))
            res = run_benchmark(bench, {"smplik": LearnedMethod(solver, refine=cfg, ensemble=ensemble)}, solver.bodies)
            mean = res["methods"]["smplik"]["random_mean"]
            residual, tracking = tolerance_order(solver, cfg, ensemble, fixed)
            ordered = keeps_tolerance_order(residual, tracking)
            row = {"alpha": float(alpha), "sigma_prior": float(sigma), "geodesic_rad": mean["geodesic_rad"],
                   "mpjpe_mm": mean["mpjpe_mm"], "pa_mpjpe_mm": mean["pa_mpjpe_mm"], "tolerance_order": ordered,
                   "tolerance_residual_mm": residual, "tolerance_tracking_mm": tracking}
            grid.append(row)
            if progress is not None:
                progress(row)
            key = (row["geodesic_rad"], row["mpjpe_mm"])
            if ordered and (best is None or key < best[0]):
                best = (key, cfg, float(alpha))
    if best is None:
        raise ValueError("no setting of the grid keeps the tolerance order (tighter effectors met more closely); "
                         "try smaller sigma_prior values.")
    return Calibration(best[1], best[2], tuple(float(e) for e in errors), tuple(grid))
