"""``smplik body ...``: export, inspect and render body models."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from smplik.cli.errors import say, user_errors
from smplik.cli.options import GenderOpt, ModelDir, parse_betas
from smplik.conventions import NUM_BETAS, Gender

body_app = typer.Typer(help="Body models: export, inspect and render.", no_args_is_help=True)

@body_app.command("info")
def body_info(gender: GenderOpt = Gender.NEUTRAL, model_dir: ModelDir = None) -> None:
    """Print where the model comes from, its size and its rest-pose measurements."""
    import torch

    from smplik.body_model import load_body_model

    with user_errors():
        model = load_body_model(gender, model_dir)
        v = model.arrays["v_template"]
        J = model.rest_joints(torch.zeros(NUM_BETAS))
        info = {
            "gender": model.gender.value,
            "source": model.source,
            "fingerprint": model.fingerprint,
            "vertices": int(v.shape[0]),
            "faces": int(model.arrays["f"].shape[0]),
            "stature_m": float(v[:, 1].max() - v[:, 1].min()),
            "rest_pelvis_m": [round(float(x), 4) for x in J[0]],
        }
        if model.source.startswith("builtin"):
            from smplik.builtin_body import BETA_DESCRIPTIONS

            info["betas"] = list(BETA_DESCRIPTIONS)
        print(json.dumps(info, indent=2))


@body_app.command("export")
def body_export(out: Annotated[Path, typer.Option("--out", help="Output .npz (SMPL layout).")],
                gender: GenderOpt = Gender.NEUTRAL, model_dir: ModelDir = None) -> None:
    """Write the body model as an SMPL-layout .npz loadable by smplx.SMPL(data_struct=...)."""
    from smplik.atomic import write_npz_deterministic
    from smplik.body_model import load_body_model

    with user_errors():
        if out.suffix != ".npz":
            raise typer.BadParameter(f"--out must end in .npz, got {out}.")
        model = load_body_model(gender, model_dir)
        write_npz_deterministic(out, model.export_arrays())
        say(f"wrote {out}")


@body_app.command("render")
def body_render(out: Annotated[Path, typer.Option("--out", help="Output PNG.")],
                gender: Annotated[Gender | None, typer.Option("--gender", case_sensitive=False,
                                                              help="Body model gender (default: the pose "
                                                                   "file's, else neutral).")] = None,
                betas: Annotated[str | None, typer.Option(help="Up to 10 shape values, e.g. '1,0,-0.5'.")] = None,
                pose: Annotated[Path | None, typer.Option(help="Pose JSON (global_orient, body_pose, transl; its "
                                                                "betas and gender unless given).")] = None,
                model_dir: ModelDir = None,
                width: Annotated[int, typer.Option(min=16, max=8192)] = 640,
                height: Annotated[int, typer.Option(min=16, max=8192)] = 800) -> None:
    """Render the body (front and side views at one common scale) to a PNG."""
    import numpy as np
    import torch

    from smplik.body_model import load_body_model
    from smplik.render import MeshItem, fit_views, hstack_images, render, save_png

    with user_errors():
        go, bp, tr = torch.zeros(1, 3), torch.zeros(1, 23, 3), torch.zeros(1, 3)
        beta = torch.tensor([parse_betas(betas)])
        if pose is not None:
            from smplik.pose import Pose

            p = Pose.load(pose)
            go, bp, tr = (torch.as_tensor(np.asarray(x, np.float32))[None]
                          for x in (p.global_orient, p.body_pose, p.transl))
            if betas is None:
                beta = torch.as_tensor(np.asarray(p.betas, np.float32))[None]
            if gender is None:
                gender = p.gender
        model = load_body_model(gender or Gender.NEUTRAL, model_dir)
        with torch.no_grad():
            verts, _ = model.vertices(go, bp, tr, beta)
        mesh = MeshItem(verts[0].numpy(), model.faces)
        size = (width // 2, height)
        views = fit_views(mesh.vertices, ((0, 0, 1), (1, 0, 0)), size=size)  # both views at one scale
        save_png(hstack_images([render([mesh], size=size, view=v) for v in views]), out)
        say(f"wrote {out} ({model.gender.value} body)")
