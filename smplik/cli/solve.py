"""``smplik solve``: effector file in, SMPL pose JSON (and optionally a PNG preview) out."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from smplik.cli.errors import say, user_errors
from smplik.cli.options import parse_betas, parse_ensemble
from smplik.conventions import EffectorType, Gender

if TYPE_CHECKING:
    import numpy as np

app = typer.Typer(pretty_exceptions_enable=False)


def effector_markers(effectors: Any, joints: np.ndarray, *, axis_length: float = 0.25,
                     max_distance: float = 1.0) -> tuple[list, list]:
    """Render primitives for effectors, given the solved joints (24, 3). Returns (spheres, segments).

    * position: a red sphere at the target;
    * rotation: the target rotation's x, y, z axes as red, green, blue segments at the solved joint;
    * look-at: an orange sphere at the target and a segment from the solved joint to it. Targets
      farther than ``max_distance`` from the joint are drawn at ``max_distance`` along the ray (smaller,
      paler sphere) so that the body stays large in the picture.
    """
    import numpy as np

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
    """Front and side views (one common scale) of the solved body with the effector markers drawn over
    it, as one PNG."""
    import numpy as np
    import torch

    from smplik.render import MeshItem, fit_views, hstack_images, render, save_png

    model = bodies[pose.gender]
    as_t = (lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)[None])  # noqa: E731
    with torch.no_grad():
        verts, _ = model.vertices(as_t(pose.global_orient), as_t(pose.body_pose), as_t(pose.transl),
                                  as_t(pose.betas))
    mesh = MeshItem(verts[0].numpy(), model.faces, color=(0.62, 0.7, 0.86, 0.55))
    spheres, segments = effector_markers(effectors, pose.joints)
    size = (width // 2, height)
    points = np.concatenate([mesh.vertices, *(np.asarray(s.center, float)[None] for s in spheres)])
    views = fit_views(points, ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)), size=size)
    save_png(hstack_images([render([mesh], spheres, segments, size=size, view=v) for v in views]), path)


def report_residuals(network: Any, refined: Any, effectors: Any, bodies: Any, steps: int) -> list[str]:
    """Lines giving each effector's residual (mm / degrees) after the network and after the refinement."""
    from smplik.solver import effector_residuals

    before = effector_residuals(network, effectors, bodies)
    after = effector_residuals(refined, effectors, bodies) if steps else before
    lines = []
    for b, a in zip(before, after, strict=True):
        line = f"  {b.effector.joint_name} {b.effector.type.name.lower()} (tolerance {b.effector.tolerance:g}): "
        line += f"{a.value:.1f} {a.unit}" + (f" (network {b.value:.1f} {b.unit})" if steps else "")
        lines.append(line)
    header = (f"effector residuals after the network and {steps} refinement steps:" if steps
              else "effector residuals of the network alone (no refinement):")
    return [header, *lines]


@app.command("solve")
def solve_command(
    effectors: Annotated[Path, typer.Argument(help="Effector file (JSON, format smplik-effectors; see "
                                                   "docs/effectors.schema.json).")],
    out: Annotated[Path, typer.Option("--out", help="Output pose JSON (smplx global_orient, body_pose, transl, "
                                                    "betas, gender, joints).")],
    betas: Annotated[str | None, typer.Option(help="Up to 10 shape values, e.g. '1,0,-0.5' (overrides the "
                                                   "file's betas).")] = None,
    gender: Annotated[Gender | None, typer.Option(case_sensitive=False, help="Body gender (overrides the file's) "
                                                                             "(default: neutral).")] = None,
    checkpoint: Annotated[Path | None, typer.Option(help="Model file (default: the packaged model).")] = None,
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files "
                                                   "(default: $SMPLIK_MODEL_DIR, else the built-in model).")] = None,
    render: Annotated[Path | None, typer.Option(help="Also write a PNG preview (body + effector markers).")] = None,
    refine_steps: Annotated[int | None, typer.Option(min=0, max=1000, help="Refinement steps after the network "
                                                                           "(default: RefineConfig's, 3; 0: the "
                                                                           "network's pose alone).")] = None,
    ensemble: Annotated[str, typer.Option(help="Test-time ensemble of the network: none, mirror, yawK or "
                                               "mirror+yawK (e.g. mirror+yaw4: 8 copies, more accurate, "
                                               "~8x the network's batched cost).")] = "none",
) -> None:
    """Solve an SMPL pose for the effectors in a JSON file; print each effector's residual."""
    from dataclasses import replace

    import numpy as np

    from smplik.effector_schema import load_effector_file
    from smplik.refine import RefineConfig
    from smplik.solver import IKSolver

    with user_errors():
        ensemble_cfg = parse_ensemble(ensemble)
        doc = load_effector_file(effectors)
        beta = np.asarray(parse_betas(betas)) if betas is not None else doc.betas
        g = gender or doc.gender or Gender.NEUTRAL
        solver = IKSolver.load(checkpoint, model_dir=model_dir, ensemble=ensemble_cfg)
        if refine_steps is not None:
            solver = replace(solver, refine=replace(solver.refine, iterations=refine_steps))
        refine = solver.refine
        pose = solver.solve(list(doc.effectors), betas=beta, gender=g)
        network = replace(solver, refine=RefineConfig(iterations=0)).solve(list(doc.effectors), betas=beta, gender=g)
        pose.save(out)
        if render is not None:
            render_solution(pose, doc.effectors, solver.bodies, render)
        for line in report_residuals(network, pose, doc.effectors, solver.bodies, refine.iterations):
            say(line)
        say(f"wrote {out}")
        if render is not None:
            say(f"wrote {render}")
