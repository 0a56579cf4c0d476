"""``smplik data ...``: motion data commands (mounted by :mod:`smplik.cli`).

Add further commands to :data:`app` with ``@app.command(...)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from smplik.cli.errors import fail
from smplik.conventions import Gender
from smplik.paths import CMU_DIR_ENV, cmu_dir, missing_cmu_reason

app = typer.Typer(help="Motion data: BVH import, retargeting, previews.", no_args_is_help=True)
console = Console(stderr=True, soft_wrap=True, highlight=False)  # a line is never cut mid-path or mid-number

def resolve_clip(clip: str) -> Path:
    """A BVH path, or a clip name such as ``07_01`` looked up in :func:`smplik.paths.cmu_dir`."""
    path = Path(clip)
    if path.is_file():
        return path
    folder = cmu_dir()
    if folder is None:
        raise typer.BadParameter(f"{clip!r} is not a file, and {missing_cmu_reason()}")
    candidate = folder / (clip if clip.endswith(".bvh") else f"{clip}.bvh")
    if candidate.is_file():
        return candidate
    raise typer.BadParameter(f"{clip!r} is neither a file nor a clip in {folder} (set ${CMU_DIR_ENV}).")


_VIEWS = {"front": (0.0, 0.15, 1.0), "side": (1.0, 0.15, 0.0), "three-quarter": (1.0, 0.3, 1.0)}


@app.command("preview")
def preview(
    clip: Annotated[str, typer.Argument(help="BVH or FBX file, or a CMU clip name such as 07_01.")],
    out: Annotated[Path, typer.Option("--out", help="Output PNG.")],
    frames: Annotated[int, typer.Option("--frames", min=1, max=24, help="Number of frames in the strip.")] = 5,
    gender: Annotated[Gender, typer.Option("--gender", case_sensitive=False, help="Body model.")] = Gender.NEUTRAL,
    preset: Annotated[str, typer.Option("--preset", help="Retarget preset: auto (mapped from the rig, as "
                                                          "data build does), a preset name or a JSON file.")] = "auto",
    view: Annotated[str, typer.Option("--view", help="front, side or three-quarter.")] = "three-quarter",
    model_dir: Annotated[Path | None, typer.Option("--model-dir", help="Real SMPL files (default: built-in).")] = None,
    panel: Annotated[int, typer.Option("--panel", help="Panel width in pixels (height is 1.6x).")] = 320,
) -> None:
    """Render N retargeted frames side by side: SMPL mesh (grey) with the source skeleton (red) beside it."""
    import numpy as np
    import torch

    from shape_inversion.auto_preset import auto_preset
    from smplik.body_model import load_body_model
    from smplik.data.bvh import BVHError
    from smplik.data.retarget import RetargetError, read_motion, retarget_bvh
    from smplik.render import MeshItem, RenderError, Segment, View, hstack_images, render, save_png

    if view not in _VIEWS:
        raise typer.BadParameter(f"--view must be one of {', '.join(_VIEWS)}, got {view!r}.")
    path = resolve_clip(clip)
    try:
        motion = read_motion(path)
        rc = retarget_bvh(motion, preset, gender=gender, model_dir=model_dir, rig_mapper=auto_preset)
    except (BVHError, RetargetError) as exc:
        fail(exc)
    picks = np.linspace(rc.motion_start, rc.num_frames - 1, frames).round().astype(int)
    model = load_body_model(gender, model_dir)
    verts, joints = model.vertices(torch.from_numpy(rc.global_orient[picks]), torch.from_numpy(rc.body_pose[picks]),
                                   torch.from_numpy(rc.transl[picks]),
                                   torch.from_numpy(rc.betas).expand(len(picks), -1))
    verts, joints = verts.detach().numpy(), joints.detach().numpy()
    direction = np.asarray(_VIEWS[view])
    lateral = np.cross([0.0, 1.0, 0.0], direction)
    lateral /= np.linalg.norm(lateral)
    parents = motion.parents
    images = []
    for k, f in enumerate(picks):
        centre = joints[k, 0] * np.array([1.0, 0.0, 1.0])
        mesh = MeshItem(verts[k] - centre, model.faces)
        sj = rc.source_joints[f].astype(np.float64)
        sj = sj - sj[0] * np.array([1.0, 0.0, 1.0]) + 0.9 * lateral
        segments = [Segment(sj[p], sj[j], radius=0.012, color=(0.85, 0.15, 0.15, 1.0))
                    for j, p in enumerate(parents) if p >= 0 and np.linalg.norm(sj[j] - sj[p]) > 1e-6]
        try:
            images.append(render([mesh], segments=segments, size=(panel, int(panel * 1.6)),
                                 view=View(direction=tuple(direction))))
        except RenderError as exc:
            fail(exc)
    save_png(hstack_images(images), out)
    console.print(f"wrote {out} ({path.name}: frames {', '.join(str(int(f)) for f in picks)} of {rc.num_frames}, "
                  f"rest pose {rc.rest_mode}, root scale {rc.root_scale:.3f})")



from shape_inversion.data_build_cli import build  # noqa: E402

app.command("build")(build)
