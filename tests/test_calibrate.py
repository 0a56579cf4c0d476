"""Calibrating the refinement's per-joint prior (smplik.benchmark.calibrate, `smplik benchmark calibrate`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from smplik.benchmark import load_benchmark, make_benchmark
from smplik.benchmark.calibrate import (
    calibrate_refinement,
    joint_prior_from_errors,
    keeps_tolerance_order,
    network_joint_errors,
)
from smplik.model_io import read_model_file, write_calibrated_model, write_model_file
from smplik.refine import DEFAULT_REFINEMENT, RefineConfig
from smplik.solver import IKSolver


@pytest.fixture(scope="module")
def val_files(tmp_path_factory, tiny_cache):
    out = tmp_path_factory.mktemp("val")
    make_benchmark(tiny_cache, out, split="validation", seed=0, samples_per_count=6)
    return out


def test_joint_errors_are_the_networks_rms_geodesic(stand_in_solver, val_files):
    bench = load_benchmark(val_files)
    errors = network_joint_errors(stand_in_solver, bench)
    assert errors.shape == (24,) and np.all(errors > 0)
    # recompute joint 7 (left ankle) by hand over the random sets
    sq = []
    for bset in bench.sets:
        if bset.kind == "random":
            out = stand_in_solver.solve_tensors(bset.effectors, bset.betas, bset.gender,
                                                refine=RefineConfig(iterations=0))
            M = out.R_local[:, 7].double() @ bset.R_local[:, 7].double().transpose(-1, -2)
            sq.append(torch.arccos(((M.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1)).square())
    assert errors[7] == pytest.approx(float(torch.cat(sq).mean().sqrt()), rel=1e-6)


def test_joint_prior_weights():
    e = np.array([0.1, 0.2, 0.4])
    assert joint_prior_from_errors(e, 0.0) is None
    w = joint_prior_from_errors(e, 1.0)
    np.testing.assert_allclose(w, (e.mean() / e) ** 2)
    assert w[0] > w[1] > w[2]  # the joint the network gets right is held closest


def test_tolerance_order_rule():
    assert keeps_tolerance_order([1.0, 2.0, 3.0], [9.0, 8.0, 7.0])
    assert not keeps_tolerance_order([2.0, 1.0, 3.0], [9.0, 8.0, 7.0])
    assert not keeps_tolerance_order([1.0, 2.0, 3.0], [9.0, 9.0, 7.0])


def test_calibration_picks_the_best_setting_that_keeps_the_tolerance_order(stand_in_solver, val_files):
    bench = load_benchmark(val_files)
    cal = calibrate_refinement(stand_in_solver, bench, alphas=(0.0, 2.0), sigma_priors=(0.3, 0.5, 3.0))
    assert len(cal.grid) == 6
    kept = [row for row in cal.grid if row["tolerance_order"]]
    assert kept, cal.grid
    best = min(kept, key=lambda row: (row["geodesic_rad"], row["mpjpe_mm"]))
    assert (cal.alpha, cal.refine.sigma_prior) == (best["alpha"], best["sigma_prior"])
    assert (cal.refine.joint_prior is None) == (cal.alpha == 0.0)
    assert cal.refine.iterations == stand_in_solver.refine.iterations


def test_test_split_files_are_refused(stand_in_solver, tmp_path, tiny_cache):
    make_benchmark(tiny_cache, tmp_path, split="test", seed=0, samples_per_count=2)
    with pytest.raises(ValueError, match="come from the test split; calibrate on validation-split files"):
        calibrate_refinement(stand_in_solver, load_benchmark(tmp_path))


def test_calibrated_model_file_sets_the_solvers_default(tiny_model, tmp_path):
    cfg = RefineConfig(sigma_prior=0.7, joint_prior=[2.0] * 24)
    out = write_calibrated_model(tiny_model, tmp_path / "cal.pt", cfg.to_dict(), {"alpha": 2.0})
    assert IKSolver.load(tiny_model).refine == DEFAULT_REFINEMENT
    solver = IKSolver.load(out)
    assert solver.refine == cfg
    assert IKSolver.load(out, refine=RefineConfig(iterations=0)).refine.iterations == 0  # an explicit one wins
    from smplik.model_io import export_model

    again = export_model(out, tmp_path / "again.pt")  # re-export keeps the calibration
    assert IKSolver.load(again).refine == cfg and read_model_file(again)["refine_calibration"] == {"alpha": 2.0}
    bad = dict(read_model_file(out))
    bad["refine"] = {"sigma_prior": 0.7, "smoothing": 1.0}
    write_model_file(tmp_path / "bad.pt", bad)
    with pytest.raises(ValueError, match=r"bad.pt: key 'refine': unknown key\(s\) \['smoothing'\]"):
        IKSolver.load(tmp_path / "bad.pt")


def test_cli_calibrate(tmp_path, tiny_model, val_files):
    from smplik.cli import benchmark as benchmark_cli

    root = typer.Typer()
    root.add_typer(benchmark_cli.app, name="benchmark")
    out = tmp_path / "cal.pt"
    res = CliRunner().invoke(root, ["benchmark", "calibrate", "--files", str(val_files), "--checkpoint",
                                    str(tiny_model), "--out", str(out), "--results", str(tmp_path / "cal.json")])
    assert res.exit_code == 0, res.output
    assert "chosen: alpha" in res.output and out.is_file()
    assert IKSolver.load(out).refine == RefineConfig.from_dict(read_model_file(out)["refine"])
    res = CliRunner().invoke(root, ["benchmark", "calibrate", "--files", str(tmp_path / "none"), "--out",
                                    str(tmp_path / "x.pt")])
    assert res.exit_code == 1 and "No manifest.json" in res.output and "Traceback" not in res.output
