"""``smplik track``: full body from a few VR trackers (logic in :mod:`workflows.tracking.run`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from shape_inversion.options import NO_CHARACTER_CLI, CharacterCLI, with_character_options
from smplik.cli.errors import say, user_errors


@with_character_options
def track_cmd(
    trackers: Annotated[Path, typer.Argument(help="Tracker recording: smplik-trackers JSON (docs/formats.md) or a "
                                             "SteamVR JSON-lines log (.jsonl).")],
    out: Annotated[Path, typer.Option("--out", help="Output folder (animation.json and the exports).")],
    samples: Annotated[int, typer.Option("--samples", help="Latent samples run in one batch; above 1: sample "
                                         "selection with a 10-frame look-ahead.")] = 1,
    betas: Annotated[str | None, typer.Option("--betas", help="The user's SMPL shape, 10 comma-separated numbers "
                                              "(default zeros).")] = None,
    gender: Annotated[str, typer.Option("--gender", help="neutral, male or female.")] = "neutral",
    character: Annotated[Path | None, typer.Option("--character", help="Custom skeleton (BVH, glTF, JSON): animate "
                                                   "its SMPL-SI body; trackers in its units.")] = None,
    character_cli: CharacterCLI = NO_CHARACTER_CLI,
    export: Annotated[str, typer.Option("--export", help="Animated files, comma-separated: bvh, glb; '' for "
                                        "none.")] = "bvh",
    seed: Annotated[int, typer.Option("--seed", help="Seed of the latent samples.")] = 0,
    fit_trackers: Annotated[bool, typer.Option("--fit-trackers", help="Set the root, wrists and head from the "
                                               "trackers (two-bone arm IK).")] = False,
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Tracking model file (default: "
                                                    "the shipped model for the recording's trackers).")] = None,
) -> None:
    """Tracker recording (head, wrists, pelvis; or head and wrists) -> OUT/animation.json and BVH/GLB."""
    from workflows.animation.clips import AnimationError
    from workflows.tracking.run import track_file

    with user_errors():
        values = None
        if betas is not None:
            try:
                values = [float(v) for v in betas.split(",")]
            except ValueError:
                raise AnimationError(f"--betas must be 10 comma-separated numbers, got {betas!r}.") from None
            if len(values) != 10:
                raise AnimationError(f"--betas must be 10 comma-separated numbers, got {len(values)}.")
        options = character_cli()
        outputs = track_file(trackers, out, samples=samples, betas=values, gender=gender, character_path=character,
                             character_options=options, checkpoint=checkpoint, seed=seed,
                             fit_trackers=fit_trackers,
                             formats=[f.strip().lower() for f in export.split(",") if f.strip()])
    anim = outputs.animation
    say(f"{anim.tracks[0].num_frames} frames at {anim.fps:g} frames/s, anomaly rate {outputs.anomaly_rate:.3f}, "
        f"{outputs.switches} sample switches")
    for path in (outputs.animation_file, *outputs.exported):
        say(f"wrote {path}")
