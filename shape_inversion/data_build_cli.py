"""``smplik data build``: BVH or AMASS folder -> pose cache ``.npz`` (see :mod:`smplik.data.dataset`).

It lives above smplik: ``--preset auto`` is the rig mapper of shape_inversion.

:func:`build` is a typer command function; mount it with ``app.command("build")(build)``.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from smplik.cli.options import check_fps

__all__ = ["build", "StorageDtype"]

console = Console(stderr=True, soft_wrap=True)  # status lines are never cut mid-number


class StorageDtype(str, Enum):
    """Storage dtype of the cached axis-angle rotations."""

    float32 = "float32"
    float16 = "float16"


OutOpt = Annotated[Path, typer.Option("--out", help="Cache file to write (.npz); replaced atomically.")]
SplitOpt = Annotated[Path | None, typer.Option("--split", help="Split file (CMU split.json format; default: every "
                                                "clip in train, or see --split-by-subject).")]
SplitSeedOpt = Annotated[int | None, typer.Option("--split-by-subject", metavar="SEED", min=0, help="Instead of a "
                                                  "split file: a seeded random split of the subjects (10 % "
                                                  "validation, 10 % test).")]
BvhOpt = Annotated[Path | None, typer.Option("--bvh", help="Folder of BVH and FBX files (searched recursively).")]
AmassOpt = Annotated[Path | None, typer.Option("--amass", help="Folder of AMASS .npz files (searched recursively).")]
FpsOpt = Annotated[float, typer.Option("--fps", help="Target frame rate (subsampled from the source; a slower "
                                                        "clip keeps its own rate).")]
PresetOpt = Annotated[str, typer.Option("--preset", help="BVH rig preset for retargeting: auto (each clip mapped "
                                        "by the rig mapper; no map needed), or cmu, mixamo, unity, unreal, "
                                        "makehuman (smplik/data/presets), or a JSON file.")]
DtypeOpt = Annotated[StorageDtype, typer.Option("--dtype", help="Storage dtype of the cached rotations.")]
SkipOpt = Annotated[bool, typer.Option("--skip-unassigned", help="Leave out clips of no split instead of failing.")]
ModelDirOpt = Annotated[Path | None, typer.Option("--model-dir", help="Real SMPL files for AMASS's rest pelvis "
                                                  "(default: $SMPLIK_MODEL_DIR, else the built-in model).")]


def build(
    out: OutOpt,
    split: SplitOpt = None,
    split_by_subject: SplitSeedOpt = None,
    bvh: BvhOpt = None,
    amass: AmassOpt = None,
    fps: FpsOpt = 30.0,
    preset: PresetOpt = "auto",
    dtype: DtypeOpt = StorageDtype.float32,
    skip_unassigned: SkipOpt = False,
    model_dir: ModelDirOpt = None,
) -> None:
    """Build a training cache from a BVH folder (--bvh) or an AMASS folder (--amass)."""
    from shape_inversion.auto_preset import auto_preset
    from smplik.data import dataset

    if (bvh is None) == (amass is None):
        raise typer.BadParameter("give exactly one of --bvh DIR or --amass DIR.")
    kind, root, option = ("bvh", bvh, "--bvh") if bvh is not None else ("amass", amass, "--amass")
    assert root is not None
    if out.suffix != ".npz":
        raise typer.BadParameter(f"must end in .npz, got {out}.", param_hint="--out")
    check_fps(fps)
    try:
        sources = dataset.find_sources(root, kind)  # type: ignore[arg-type]
    except (FileNotFoundError, ValueError) as exc:
        raise typer.BadParameter(str(exc), param_hint=option) from None
    from smplik.output_files import OutputPathError, check_writes

    model_files = [p for p in Path(model_dir).iterdir() if p.is_file()] if model_dir and Path(model_dir).is_dir() \
        else []
    try:  # the cache never replaces a clip it reads (an AMASS .npz) or a body model file
        check_writes([out], [s.path for s in sources] + model_files)
    except OutputPathError as exc:
        raise typer.BadParameter(str(exc), param_hint="--out") from None
    if split is not None and split_by_subject is not None:
        raise typer.BadParameter("give --split FILE or --split-by-subject SEED, not both.")
    if split is not None:
        try:
            spec = dataset.load_split(split)
        except (FileNotFoundError, ValueError) as exc:
            raise typer.BadParameter(str(exc), param_hint="--split") from None
        how = f"split file {split}"
    elif split_by_subject is not None:
        spec = dataset.split_by_subject(sources, split_by_subject)
        how = f"split by subject with seed {split_by_subject}: " + "; ".join(
            f"{name} {', '.join(sorted(spec.subjects[name])) or '-'}" for name in dataset.SPLIT_NAMES)
    else:
        spec = dataset.split_all_train(sources)
        how = "every clip in train (no --split given; --split-by-subject SEED makes a seeded subject split)"

    body_models = None
    if kind == "amass":
        from smplik.body_model import BodyModelSet

        body_models = BodyModelSet.load(model_dir)

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("{task.fields[clip]}"))
    with Progress(*columns, console=console, transient=True, disable=not console.is_terminal) as progress:
        task = progress.add_task(f"reading {kind}", total=len(sources), clip="")

        def advance(src: object) -> None:
            progress.update(task, advance=1, clip=getattr(src, "name", ""))

        try:
            summary = dataset.build_cache(sources, fps=fps, split=spec, out=out, preset=preset,
                                          dtype=dtype.value, body_models=body_models,
                                          skip_unassigned=skip_unassigned, progress=advance,
                                          rig_mapper=auto_preset)
        except (ValueError, FileNotFoundError) as exc:
            progress.stop()
            from smplik.cli.errors import fail

            fail(exc)

    console.print(f"split: {escape(how)}", highlight=False)
    total = sum(summary.frames.values())
    console.print(f"wrote {summary.path} ({summary.num_bytes / 2**20:.1f} MiB, {total} frames at {fps:g} fps, "
                  f"{summary.seconds:.1f} s)", highlight=False)
    for name in summary.frames:
        console.print(f"  {name:<10} {summary.frames[name]:>8} frames  {summary.clips[name]:>5} clips", highlight=False)
    if summary.skipped:
        console.print(f"  skipped {len(summary.skipped)} clip(s) of no split", highlight=False)
