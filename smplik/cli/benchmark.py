"""``smplik benchmark make``, ``run`` and ``calibrate`` (see :mod:`smplik.benchmark`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from smplik.cli.errors import fail
from smplik.cli.options import parse_ensemble

app = typer.Typer(help="Randomized-effector IK benchmark: make the files, run methods on them.",
                  no_args_is_help=True, pretty_exceptions_enable=False)
console = Console(stderr=True, soft_wrap=True)  # status lines are never cut mid-number
LEARNED_METHODS = ("smplik", "smplik_net", "smplik_ens", "smplik_net_ens")
ALL_METHODS = (*LEARNED_METHODS, "optim", "nn", "rest")


@app.command("make")
def make_command(
    data: Annotated[Path, typer.Option("--data", help="Pose cache (`smplik data build`).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder (manifest.json + one .npz per set).")],
    split: Annotated[str, typer.Option(help="Split to draw frames from.")] = "test",
    seed: Annotated[int, typer.Option(help="Seed (stored in the manifest).")] = 0,
    samples_per_count: Annotated[int, typer.Option(help="Poses per set.")] = 500,
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files.")] = None,
) -> None:
    """Write the benchmark files: random N = 6..12 effector sets plus the fixed 5- and 6-point sets."""
    from smplik.benchmark import make_benchmark

    try:
        manifest = make_benchmark(data, out, split=split, seed=seed, samples_per_count=samples_per_count,
                                  model_dir=model_dir)
    except (FileNotFoundError, ValueError) as exc:
        fail(exc)
    console.print(f"wrote {manifest}")


@app.command("run")
def run_command(
    files: Annotated[Path, typer.Option("--files", help="Folder written by `smplik benchmark make`.")],
    out: Annotated[Path, typer.Option("--out", help="Results JSON.")],
    methods: Annotated[str, typer.Option(help="Comma-separated subset of " + ",".join(ALL_METHODS) + ".")] = ",".join(
        m for m in ALL_METHODS if not m.endswith("_ens")),
    checkpoint: Annotated[Path | None, typer.Option(help="Model file (default: the packaged model).")] = None,
    data: Annotated[Path | None, typer.Option(help="Pose cache with the train split for the prior and the "
                                                   "nearest neighbour (default: the manifest's source).")] = None,
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files.")] = None,
    optim_iterations: Annotated[int, typer.Option(help="Adam iterations of the optimization baseline.")] = 200,
    nn_samples: Annotated[int, typer.Option(help="Train poses indexed by the nearest-neighbour baseline.")] = 20_000,
    threads: Annotated[int | None, typer.Option(help="torch intra-op threads.")] = None,
    ensemble: Annotated[str, typer.Option(help="Test-time ensemble of the *_ens methods: none, mirror, yawK or "
                                               "mirror+yawK.")] = "mirror+yaw4",
    markdown: Annotated[Path | None, typer.Option(help="Also write the markdown table here.")] = None,
) -> None:
    """Evaluate methods on benchmark files; writes per-method, per-set metrics and prints a markdown table."""
    import torch

    from smplik.atomic import write_text_atomic
    from smplik.benchmark import (
        build_methods,
        load_benchmark,
        results_markdown,
        run_benchmark,
        sample_subjects,
        save_results,
    )
    from smplik.body_model import BodyModelSet

    if threads:
        torch.set_num_threads(threads)
    ensemble_cfg = parse_ensemble(ensemble)
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    unknown = [m for m in chosen if m not in ALL_METHODS]
    if unknown or not chosen:
        raise typer.BadParameter(f"unknown method(s) {unknown}; choose from {', '.join(ALL_METHODS)}.")
    try:
        bench = load_benchmark(files)
    except (FileNotFoundError, ValueError) as exc:
        fail(exc)
    bodies = BodyModelSet.load(model_dir)
    cache = data or Path(bench.manifest["source"]["data"])
    dataset = None
    if {"optim", "nn"} & set(chosen) or cache.is_file():  # train poses; the samples' subjects
        from smplik.data.dataset import load_cache

        try:
            dataset = load_cache(cache)
        except (FileNotFoundError, ValueError) as exc:
            fail(exc)
    solver = None
    if set(LEARNED_METHODS) & set(chosen):
        from smplik.solver import IKSolver

        try:
            solver = IKSolver.load(checkpoint, model_dir=model_dir)
        except (FileNotFoundError, ValueError) as exc:
            fail(exc)
    try:
        subjects = None if dataset is None else sample_subjects(bench, dataset)
        runners, settings = build_methods(chosen, bodies, solver=solver, optim_iterations=optim_iterations,
                                          nn_samples=nn_samples, ensemble=ensemble_cfg,
                                          train_pose=None if dataset is None else dataset.subset("train").pose)
    except ValueError as exc:
        fail(exc)
    if dataset is not None:
        settings["train_data"] = str(cache)

    def report(method: str, set_name: str, m) -> None:
        console.print(f"{method:10s} {set_name:10s} MPJPE {m.mpjpe_mm:7.1f} mm  PA {m.pa_mpjpe_mm:7.1f} mm  "
                      f"geo {m.geodesic_rad:.4f} rad  {m.time_ms_per_pose:.3f} ms/pose", highlight=False)

    try:
        results = run_benchmark(bench, runners, bodies, settings=settings, subjects=subjects, progress=report)
    except ValueError as exc:
        fail(exc)
    save_results(out, results)
    table = results_markdown(results)
    if markdown is not None:
        write_text_atomic(markdown, table)
    typer.echo(table)
    console.print(f"wrote {out}")


@app.command("calibrate")
def calibrate_command(
    files: Annotated[Path, typer.Option("--files", help="Validation-split folder from `smplik benchmark make "
                                                        "--split validation` (test-split files are refused).")],
    out: Annotated[Path, typer.Option("--out", help="Model file to write: the model with the chosen refinement "
                                                    "settings, its solver's default from then on.")],
    checkpoint: Annotated[Path | None, typer.Option(help="Model file (default: the packaged model).")] = None,
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files.")] = None,
    ensemble: Annotated[str, typer.Option(help="Test-time ensemble the model will run with (none, mirror, "
                                               "mirror+yawK).")] = "none",
    threads: Annotated[int | None, typer.Option(help="torch intra-op threads.")] = None,
    results: Annotated[Path | None, typer.Option(help="Also write the grid's results here (JSON).")] = None,
) -> None:
    """Fit the refinement's per-joint prior to a model on validation files (smplik.benchmark.calibrate)."""
    import torch

    from smplik.atomic import write_json_atomic
    from smplik.benchmark import load_benchmark
    from smplik.benchmark.calibrate import calibrate_refinement
    from smplik.cli.errors import say, user_errors
    from smplik.model_io import write_calibrated_model
    from smplik.solver import IKSolver, packaged_model_path

    if threads:
        torch.set_num_threads(threads)
    with user_errors():
        ensemble_cfg = parse_ensemble(ensemble)
        bench = load_benchmark(files)
        source = checkpoint or packaged_model_path()
        solver = IKSolver.load(source, model_dir=model_dir)

        def report(row: dict) -> None:
            order = "keeps" if row["tolerance_order"] else "loses"
            say(f"alpha {row['alpha']:.1f}  sigma_prior {row['sigma_prior']:.2f}:  geodesic {row['geodesic_rad']:.4f} "
                f"rad  MPJPE {row['mpjpe_mm']:.1f} mm  PA-MPJPE {row['pa_mpjpe_mm']:.1f} mm  ({order} the tolerance "
                "order)")

        cal = calibrate_refinement(solver, bench, ensemble=ensemble_cfg, progress=report)
        record = cal.to_dict(str(files)) | {"ensemble": ensemble_cfg.to_dict()}
        write_calibrated_model(source, out, cal.refine.to_dict(), record)
        if results is not None:
            write_json_atomic(results, {"refine": cal.refine.to_dict(), **record})
        say(f"chosen: alpha {cal.alpha:.1f}, sigma_prior {cal.refine.sigma_prior:.2f}")
        say(f"wrote {out}")
