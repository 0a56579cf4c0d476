"""``smplik benchmark``: smplik's IK benchmark commands (:mod:`smplik.cli.benchmark`: make, run, calibrate) and
the edit benchmark (``edits``, :mod:`workflows.edit_benchmark`), which needs the workflows' scenes and edits."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from smplik.cli.benchmark import app as ik_app

app = typer.Typer(help=ik_app.info.help, no_args_is_help=True, pretty_exceptions_enable=False)
app.registered_commands.extend(ik_app.registered_commands)


@app.command("edits")
def edits_command(
    out: Annotated[Path, typer.Option("--out", help="Results JSON (the figure is written beside it as .png).")],
    data: Annotated[Path | None, typer.Option(help="Pose cache (`smplik data build`; default: $SMPLIK_POSE_CACHE, "
                                                   "else the cache folder's cmu30.npz).")] = None,
    split: Annotated[str, typer.Option(help="Split whose clips give the edits.")] = "test",
    clips: Annotated[Path | None, typer.Option(help="Also a folder of held-out BVH clips.")] = None,
    clips_preset: Annotated[str, typer.Option("--clips-preset", help="Retarget preset of those clips: a built-in "
                                              "name, a JSON file, or auto (the rig mapper; CMU's cgspeed files read as "
                                              "with cmu).")] = "auto",
    max_pairs: Annotated[int, typer.Option("--max-pairs", min=1, help="At most this many edit pairs "
                                           "(a seeded draw).")] = 150,
    seed: Annotated[int, typer.Option(help="Seed of that draw.")] = 0,
    methods: Annotated[str | None, typer.Option(help="Comma-separated methods (default: all).")] = None,
    checkpoint: Annotated[Path | None, typer.Option(help="Model file (default: the packaged model).")] = None,
    optim_iterations: Annotated[int, typer.Option(min=1, help="Adam steps of the optim method.")] = 200,
    threads: Annotated[int, typer.Option(min=1, help="torch intra-op threads.")] = 2,
) -> None:
    """Single-limb edits from real motion: drag a wrist or ankle of a recovered frame to where the person moved
    it, solve with each method, compare with the real frame (docs/editing.md)."""
    import torch

    from smplik.atomic import write_json_atomic
    from smplik.cli.errors import say, user_errors
    from smplik.paths import pose_cache
    from smplik.solver import IKSolver
    from workflows.edit_benchmark.run import METHODS, EditBenchmarkConfig, edit_benchmark, save_figure

    torch.set_num_threads(threads)
    chosen = tuple(m.strip() for m in (methods or ",".join(METHODS)).split(",") if m.strip())
    unknown = [m for m in chosen if m not in METHODS]
    if unknown or not chosen:
        raise typer.BadParameter(f"unknown method(s) {unknown}; choose from {', '.join(METHODS)}.",
                                 param_hint="--methods")
    if out.suffix != ".json":
        raise typer.BadParameter(f"must end in .json, got {out}.", param_hint="--out")
    with user_errors():
        if clips is not None:  # checked before the minutes of work
            if not clips.is_dir():
                raise FileNotFoundError(f"--clips {clips}: no such folder.")
            if clips_preset != "auto":
                from smplik.data.retarget import load_preset

                load_preset(clips_preset)
        cache = data or pose_cache()
        if not cache.is_file():
            raise FileNotFoundError(f"no pose cache at {cache}: build one with `smplik data build` and pass --data.")
        solver = IKSolver.load(checkpoint)
        results = edit_benchmark(cache, solver, split=split, clips_folder=clips, clips_preset=clips_preset,
                                 methods=chosen,
                                 cfg=EditBenchmarkConfig(max_pairs=max_pairs, seed=seed,
                                                         optim_iterations=optim_iterations),
                                 progress=say)
        write_json_atomic(out, results)
        figure = save_figure(results, out.with_suffix(".png"))
    say(f"wrote {out}")
    say(f"wrote {figure}")
