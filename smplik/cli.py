"""The ``smplik`` command line. Each command group lives next to the code it drives."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from smplik.cli_options import GenderOpt, ModelDir, parse_betas
from smplik.conventions import NUM_BETAS, Gender

app = typer.Typer(help="Morphology-aware learned IK on the SMPL body model.", no_args_is_help=True,
                  pretty_exceptions_enable=False)
body_app = typer.Typer(help="Body models: export, inspect and render.", no_args_is_help=True)
app.add_typer(body_app, name="body")
console = Console(stderr=True)

@body_app.command("info")
def body_info(gender: GenderOpt = Gender.NEUTRAL, model_dir: ModelDir = None) -> None:
    """Print where the model comes from, its size and its rest-pose measurements."""
    import torch

    from smplik.body_model import load_body_model

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
    from smplik.atomic import savez_atomic
    from smplik.body_model import load_body_model

    if out.suffix != ".npz":
        raise typer.BadParameter(f"--out must end in .npz, got {out}.")
    model = load_body_model(gender, model_dir)
    savez_atomic(out, **model.export_arrays())
    console.print(f"wrote {out}")


@body_app.command("render")
def body_render(out: Annotated[Path, typer.Option("--out", help="Output PNG.")],
                gender: GenderOpt = Gender.NEUTRAL,
                betas: Annotated[str | None, typer.Option(help="Up to 10 shape values, e.g. '1,0,-0.5'.")] = None,
                pose: Annotated[Path | None, typer.Option(help="Pose JSON (global_orient, body_pose, transl).")] = None,
                model_dir: ModelDir = None,
                width: int = 640, height: int = 800) -> None:
    """Render the body (front and side views) to a PNG."""
    import numpy as np
    import torch

    from smplik.body_model import load_body_model
    from smplik.render import MeshItem, RenderError, View, hstack_images, render, save_png

    model = load_body_model(gender, model_dir)
    beta = torch.tensor([parse_betas(betas)])
    go, bp, tr = torch.zeros(1, 3), torch.zeros(1, 23, 3), torch.zeros(1, 3)
    if pose is not None:
        from smplik.pose import Pose

        p = Pose.load(pose)
        go, bp, tr = (torch.as_tensor(np.asarray(x, np.float32))[None]
                      for x in (p.global_orient, p.body_pose, p.transl))
        if betas is None:
            beta = torch.as_tensor(np.asarray(p.betas, np.float32))[None]
    verts, _ = model.vertices(go, bp, tr, beta)
    mesh = MeshItem(verts[0].detach().numpy(), model.faces)
    try:
        images = [render([mesh], size=(width // 2, height), view=View(direction=d)) for d in ((0, 0, 1), (1, 0, 0))]
    except RenderError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from None
    save_png(hstack_images(images), out)
    console.print(f"wrote {out}")


def _register_optional() -> None:
    """Attach the command groups of the other components."""
    from importlib import import_module

    for module, attr, name in (
        ("smplik.data.cli", "app", "data"),
        ("smplik.train_cli", "app", None),
        ("smplik.solver_cli", "app", None),
        ("smplik.benchmark_cli", "app", "benchmark"),
        ("shape_inversion.cli", "app", None),
        ("workflows.cli", "scene_app", "scene"),
        ("workflows.cli", "demo_app", None),
        ("workflows.editor.cli", "app", None),
    ):
        try:
            mod = import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name and module.startswith(exc.name):
                continue  # component not present in this build
            raise
        sub = getattr(mod, attr)
        if name:
            app.add_typer(sub, name=name)
        else:  # top-level commands: copy each registered command onto the main app
            for info in sub.registered_commands:
                app.command(info.name, help=info.help)(info.callback)


_register_optional()


def main() -> None:
    """Console-script entry point."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless rendering by default
    app()


if __name__ == "__main__":
    main()
