"""The jobs ``smplik batch`` runs: each one an existing command's Python entry point, on one input.

A :class:`Job` names the command whose options it takes (parsed by that command's own click parser, so the
options and their defaults are the command's), the files a folder of inputs holds for it, how a worker loads
its model once (:func:`model_key`, :func:`load_model`) and how one input runs into one output folder
(:func:`run_job`). The top level is light (no torch, no numpy): ``smplik batch --help`` and the option checks
import nothing heavy; the entry points are imported where they run.

=================  ======================================================  ===========================
job                entry point                                             model held by a worker
=================  ======================================================  ===========================
``animate``        :func:`workflows.animation.run.animate_file`            the IK solver (``--checkpoint``)
``from-estimate``  :func:`workflows.scene.pipeline.from_estimate`          the IK solver (``--checkpoint``)
``track``          :func:`workflows.tracking.run.track_file`               none (its model file, ~10 ms, is
                                                                           read per input; the worker keeps
                                                                           the imports and compiled kernels)
``invert-shape``   :class:`shape_inversion.estimator.ShapeEstimator`       the body model and sample bank
``export``         :func:`workflows.scene.export.export_scene`             none
=================  ======================================================  ===========================
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ESTIMATE_SUFFIXES = (".npz", ".pk", ".pkl", ".json", ".pt")
"""The estimator files a folder of inputs holds for ``animate`` and ``from-estimate``."""


@dataclass(frozen=True)
class Job:
    """One job of ``smplik batch``."""

    name: str
    """The job's name on the ``smplik batch`` command line."""
    command: tuple[str, ...]
    """The ``smplik`` command whose options the job takes (``("scene", "animate")``)."""
    input_param: str
    """That command's argument naming its input file (click's parameter name)."""
    suffixes: tuple[str, ...]
    """The files (lower-case suffixes) a folder given as inputs contributes."""
    output_files: tuple[str, ...] = ()
    """Options naming one more file to write: in a batch, a bare file name written into each input's folder."""
    summary: str = ""
    """What one input gives (``smplik batch --help``)."""


JOBS: dict[str, Job] = {job.name: job for job in (
    Job("animate", ("scene", "animate"), "results", ESTIMATE_SUFFIXES, ("preview",),
        "video estimates -> animation.json and per-track BVH/GLB (smplik scene animate)"),
    Job("from-estimate", ("scene", "from-estimate"), "results", ESTIMATE_SUFFIXES, (),
        "estimator output -> scene.json, previews (smplik scene from-estimate)"),
    Job("track", ("track",), "trackers", (".json", ".jsonl"), (),
        "tracker recording -> animation.json and BVH/GLB (smplik track)"),
    Job("invert-shape", ("invert-shape",), "character", (".bvh", ".glb", ".gltf", ".vrm", ".json"), ("render_png",),
        "character skeleton -> shape.json (SMPL betas, scale; smplik invert-shape)"),
    Job("export", ("scene", "export"), "scene", (".json",), (),
        "scene.json -> per character a posed BVH and GLB (smplik scene export)"),
)}
"""Every job, in the order ``smplik batch --help`` lists them."""



def _scene_app() -> Any:
    from workflows.cli import scene_app

    return scene_app


def _track_cmd() -> Any:
    from workflows.tracking.cli import track_cmd

    return track_cmd


def _invert_shape() -> Any:
    from shape_inversion.cli import invert_shape

    return invert_shape


JOB_COMMANDS = {"scene": _scene_app, "track": _track_cmd, "invert-shape": _invert_shape}
"""The top-level command of each job's ``command`` -> its loader (the typer group or function). The batch does
not read the ``smplik`` command table (:mod:`workflows.commands`, which loads the batch itself): the jobs'
commands are imports of this module."""

SHAPE_FILE = "shape.json"
"""``invert-shape``'s output in each input's folder (the command's ``--out SHAPE.json``)."""


@dataclass(frozen=True)
class JobResult:
    """What one input's run wrote (inside its output folder) and the lines the command would have printed."""

    notes: tuple[str, ...] = ()


def check_options(job: str, params: Mapping[str, Any]) -> None:
    """The checks the command makes before its work, without loading anything heavy: raise the command's
    one-line error (``typer.BadParameter`` naming the option, or a project error) for a bad option value."""
    import typer

    from smplik.cli.options import check_fps, check_image

    if "rig" in params:  # the character options (shape_inversion.options.with_character_options)
        character_options(params)
    if job == "animate":
        check_fps(params["fps"])
        preview = params.get("preview")
        if preview is not None and Path(str(preview)).suffix.lower() not in (".gif", ".mp4"):
            raise typer.BadParameter(f"{preview}: a preview is a .gif or .mp4 file.", param_hint="--preview")
    elif job == "from-estimate":
        from workflows.cli import FORMATS

        if params["format"] not in FORMATS:
            raise typer.BadParameter(f"must be one of {', '.join(FORMATS)}, got {params['format']!r}.",
                                     param_hint="--format")
        if params["space"] not in (None, "camera", "world"):
            raise typer.BadParameter(f"must be 'camera' or 'world', got {params['space']!r}.", param_hint="--space")
        check_image(params["image"])
    elif job == "track":
        track_betas(params["betas"])


def character_options(params: Mapping[str, Any]) -> Any:
    """The :class:`shape_inversion.options.CharacterOptions` of the parsed character options."""
    from shape_inversion.options import character_options_from_cli

    names = ("rig", "map_file", "units", "up", "rest", "bind", "positions", "max_joints", "root")
    return character_options_from_cli(**{name: params[name] for name in names})


def track_betas(text: str | None) -> list[float] | None:
    """``smplik track --betas``: 10 comma-separated numbers, or None."""
    import typer

    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise typer.BadParameter(f"must be 10 comma-separated numbers, got {text!r}.", param_hint="--betas") from None
    if len(values) != 10 or not all(math.isfinite(v) for v in values):
        raise typer.BadParameter(f"must be 10 comma-separated finite numbers, got {text!r}.", param_hint="--betas")
    return values


def model_key(job: str, params: Mapping[str, Any]) -> tuple | None:
    """What a worker loads once for ``job`` with these options and keeps for every input (None: nothing)."""
    if job in ("animate", "from-estimate"):
        checkpoint = params["checkpoint"]
        return ("solver", None if checkpoint is None else str(checkpoint))
    if job == "invert-shape":
        model_dir = params["model_dir"]
        return ("shape", str(getattr(params["gender"], "value", params["gender"])),
                None if model_dir is None else str(model_dir), int(params["bank_samples"]), bool(params["refine"]))
    return None


def load_model(key: tuple) -> Any:
    """Load what :func:`model_key` names: an :class:`smplik.solver.IKSolver`, or ``(body model, shape
    estimator)``. Raises the project's one-line errors (a bad model file, a missing body model)."""
    if key[0] == "solver":
        from smplik.solver import IKSolver

        return IKSolver.load(key[1])
    if key[0] == "shape":
        from shape_inversion.bank import BankConfig
        from shape_inversion.estimator import EstimatorConfig, ShapeEstimator
        from smplik.body_model import load_body_model

        _, gender, model_dir, bank_samples, refine = key
        model = load_body_model(gender, model_dir)
        return model, ShapeEstimator.build(model, BankConfig(num_samples=bank_samples), EstimatorConfig(refine=refine))
    raise ValueError(f"unknown model kind {key[0]!r}")


def run_job(job: str, model: Any, source: Path, out: Path, params: Mapping[str, Any]) -> JobResult:
    """Run ``job`` on the input ``source`` into the (existing, empty) folder ``out`` with the command's parsed
    options ``params``; raise the command's errors."""
    return _RUNNERS[job](model, source, out, params)


def _formats(text: str) -> list[str]:
    return [f.strip().lower() for f in text.split(",") if f.strip()]


def _animate(solver: Any, source: Path, out: Path, p: Mapping[str, Any]) -> JobResult:
    from workflows.animation.clean import CleanConfig
    from workflows.animation.clips import AnimateConfig
    from workflows.animation.run import animate_file
    from workflows.scene.recovery import RecoveryConfig

    preview = p["preview"]
    if preview is not None:
        from workflows.animation.preview import check_preview_path

        check_preview_path(out / str(preview))
    config = AnimateConfig(CleanConfig(smoothing=p["smoothing"], smoothness=p["smoothness"], foot_lock=p["foot_lock"],
                                       pose_budget_mm=p["pose_budget"] or None),
                           keyframe_threshold_m=p["keyframe_threshold"],
                           camera_fov_deg=None if p["keep_depth"] else AnimateConfig().camera_fov_deg,
                           recovery=RecoveryConfig(max_effectors=p["max_effectors"], threshold=0.03))
    outputs = animate_file(source, out, solver, format=p["format"], frames=p["frames"], fps=p["fps"],
                           track=p["track"], character_path=p["character"], character_options=character_options(p),
                           config=config, trust_pickle=p["trust_pickle"], space=p["space"],
                           formats=_formats(p["export"]), max_frames=p["max_frames"])
    anim = outputs.animation
    notes = list(anim.notes)
    if anim.depth_change is not None:
        notes.append(anim.depth_change.describe())
    if preview is not None:
        from workflows.animation.preview import write_preview

        notes.append(write_preview(anim, out / str(preview), video=p["video"], every=p["preview_every"]).describe())
    return JobResult(tuple(notes))


def _from_estimate(solver: Any, source: Path, out: Path, p: Mapping[str, Any]) -> JobResult:
    from workflows.scene.pipeline import from_estimate
    from workflows.scene.recovery import RecoveryConfig

    outputs = from_estimate(source, out, solver, format=p["format"], character_path=p["character"],
                            character_options=character_options(p),
                            config=RecoveryConfig(max_effectors=p["max_effectors"], threshold=p["threshold"]),
                            trust_pickle=p["trust_pickle"], image_path=p["image"], frame=p["frame"],
                            previews=not p["no_previews"], max_people=p["max_people"], max_bytes=p["max_bytes"],
                            ground=p["ground"], space=p["space"], focal=p["focal"])
    notes = list(outputs.notes)
    if outputs.character is not None:
        notes += outputs.character.character.map_report()
        notes += [f"warning: {note}" for note in outputs.character.estimate.warnings]
    return JobResult(tuple(notes))


def _track(_: Any, source: Path, out: Path, p: Mapping[str, Any]) -> JobResult:
    from workflows.tracking.run import track_file

    outputs = track_file(source, out, samples=p["samples"], betas=track_betas(p["betas"]), gender=p["gender"],
                         character_path=p["character"], character_options=character_options(p),
                         checkpoint=p["checkpoint"], seed=p["seed"], fit_trackers=p["fit_trackers"],
                         formats=_formats(p["export"]))
    return JobResult((f"anomaly rate {outputs.anomaly_rate:.3f}, {outputs.switches} sample switches",))


def _invert_shape(loaded: Any, source: Path, out: Path, p: Mapping[str, Any]) -> JobResult:
    from shape_inversion.cli import joint_fit_note, shape_payload
    from shape_inversion.skeleton_io import read_character
    from smplik.atomic import write_json_atomic

    model, estimator = loaded
    options = character_options(p)
    char = read_character(source, options)
    start = time.perf_counter()
    with warnings.catch_warnings():  # its notes are reported below, once
        warnings.simplefilter("ignore")
        estimate = estimator.estimate(char.features, char.mapped_rest())
    payload = shape_payload(char, estimate, model, rest=options.rest, elapsed_s=time.perf_counter() - start)
    payload["character"]["options"] = options.to_dict()
    write_json_atomic(out / SHAPE_FILE, payload)
    if p["render_png"] is not None:
        from shape_inversion.preview import render_comparison
        from smplik.render import save_png

        save_png(render_comparison(char, estimate, model), out / str(p["render_png"]))
    notes = [*char.map_report(), *(f"warning: {note}" for note in estimate.warnings)]
    if note := joint_fit_note(char, estimate):
        notes.append(note)
    return JobResult(tuple(notes))


def _export(_: Any, source: Path, out: Path, p: Mapping[str, Any]) -> JobResult:
    from workflows.scene import load_scene
    from workflows.scene.export import export_scene, glb_notes

    scene = load_scene(source)
    formats = _formats(p["format"])
    paths = export_scene(scene, out, formats=formats, base_dir=source.parent, bvh_frame=p["bvh_frame"])
    return JobResult(tuple(glb_notes(scene, formats, source.parent)) if paths else ("no posed character to export",))


_RUNNERS = {"animate": _animate, "from-estimate": _from_estimate, "track": _track, "invert-shape": _invert_shape,
            "export": _export}
