"""``smplik solve``: effector file in, SMPL pose JSON (and optionally a PNG preview) out."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console

from smplik.cli.options import parse_betas
from smplik.conventions import EffectorType, Gender

app = typer.Typer(pretty_exceptions_enable=False)
console = Console(stderr=True)


def _fail(message: str) -> typer.Exit:
    console.print(f"[red]error:[/red] {message}", markup=True, highlight=False)
    return typer.Exit(1)


def effector_markers(effectors: Any, joints: np.ndarray, *, axis_length: float = 0.25,
                     max_distance: float = 1.0) -> tuple[list, list]:
    """Render primitives for effectors, given the solved joints (24, 3). Returns (spheres, segments).

    * position: a red sphere at the target;
    * rotation: the target rotation's x, y, z axes as red, green, blue segments at the solved joint;
    * look-at: an orange sphere at the target and a segment from the solved joint to it. Targets
      farther than ``max_distance`` from the joint are drawn at ``max_distance`` along the ray (smaller,
      paler sphere) so that the body stays large in the picture.
    """
    from smplik.render import Segment, Sphere

    spheres, segments = [], []
    for e in effectors:
        p = joints[e.joint]
        if e.type == EffectorType.POSITION:
            spheres.append(Sphere(e.value, radius=0.025, color=(0.9, 0.15, 0.15, 1.0)))
        elif e.type == EffectorType.ROTATION:
            for k, color in enumerate(((0.9, 0.1, 0.1, 1.0), (0.1, 0.75, 0.1, 1.0), (0.1, 0.2, 0.9, 1.0))):
                segments.append(Segment(p, p + axis_length * e.value[:, k], radius=0.01, color=color))
        else:
            ray = e.value - p
            dist = float(np.linalg.norm(ray))
            if dist > max_distance:
                end = p + ray * (max_distance / dist)
                spheres.append(Sphere(end, radius=0.02, color=(1.0, 0.75, 0.4, 1.0)))
            else:
                end = e.value
                spheres.append(Sphere(end, radius=0.03, color=(1.0, 0.55, 0.0, 1.0)))
            segments.append(Segment(p, end, radius=0.006, color=(1.0, 0.55, 0.0, 1.0)))
    return spheres, segments


def render_solution(pose: Any, effectors: Any, bodies: Any, path: Path, *, width: int = 960, height: int = 720) -> None:
    """Front and side views of the solved body with the effector markers, as one PNG."""
    import torch

    from smplik.render import MeshItem, View, hstack_images, render, save_png

    model = bodies[pose.gender]
    as_t = (lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)[None])  # noqa: E731
    verts, _ = model.vertices(as_t(pose.global_orient), as_t(pose.body_pose), as_t(pose.transl), as_t(pose.betas))
    mesh = MeshItem(verts[0].detach().numpy(), model.faces, color=(0.62, 0.7, 0.86, 0.55))
    spheres, segments = effector_markers(effectors, pose.joints)
    images = [render([mesh], spheres, segments, size=(width // 2, height), view=View(direction=d))
              for d in ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0))]
    save_png(hstack_images(images), path)


@app.command("solve")
def solve_command(
    effectors: Annotated[Path, typer.Argument(help="Effector file (JSON, format smplik-effectors; see "
                                                   "docs/effectors.schema.json).")],
    out: Annotated[Path, typer.Option("--out", help="Output pose JSON (smplx global_orient, body_pose, transl, "
                                                    "betas, gender, joints).")],
    betas: Annotated[str | None, typer.Option(help="Up to 10 shape values, e.g. '1,0,-0.5' (overrides the "
                                                   "file's betas).")] = None,
    gender: Annotated[Gender | None, typer.Option(case_sensitive=False, help="Body gender (overrides the file; "
                                                                             "default neutral).")] = None,
    checkpoint: Annotated[Path | None, typer.Option(help="Model file (default: the packaged model).")] = None,
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files "
                                                   "(default: $SMPLIK_MODEL_DIR, else the built-in model).")] = None,
    render: Annotated[Path | None, typer.Option(help="Also write a PNG preview (body + effector markers).")] = None,
    refine_steps: Annotated[int | None, typer.Option(min=0, help="Refinement steps after the network (default: "
                                                                 "RefineConfig's, 3; 0: the network's pose "
                                                                 "alone).")] = None,
) -> None:
    """Solve an SMPL pose for the effectors in a JSON file."""
    from dataclasses import replace

    from smplik.effector_schema import load_effector_file
    from smplik.refine import DEFAULT_REFINEMENT
    from smplik.solver import IKSolver

    try:
        doc = load_effector_file(effectors)
    except ValueError as exc:
        raise _fail(str(exc)) from None
    beta = np.asarray(parse_betas(betas)) if betas is not None else doc.betas
    g = gender or doc.gender or Gender.NEUTRAL
    try:
        solver = IKSolver.load(checkpoint, model_dir=model_dir, refine=DEFAULT_REFINEMENT if refine_steps is None else
                               replace(DEFAULT_REFINEMENT, iterations=refine_steps))
        pose = solver.solve(list(doc.effectors), betas=beta, gender=g)
    except (FileNotFoundError, ValueError) as exc:
        raise _fail(str(exc)) from None
    pose.save(out)
    console.print(f"wrote {out}")
    if render is not None:
        from smplik.render import RenderError

        try:
            render_solution(pose, doc.effectors, solver.bodies, render)
        except RenderError as exc:
            raise _fail(str(exc)) from None
        console.print(f"wrote {render}")
