"""``smplik track-train``: train the tracking model (:func:`smplik.tracking.train.train`) on a 60 Hz pose cache.

The options are :class:`smplik.tracking.config.TrackingTrainConfig`'s (defaults read from it); they are checked
before torch is imported, so ``--help`` and a bad option answer fast with one ``error:`` line.
"""

from __future__ import annotations

import dataclasses
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from smplik.cli.errors import fail, user_errors
from smplik.tracking.config import TRACKER_SETS, TrackingTrainConfig


class NetKind(str, Enum):
    cvae = "cvae"
    mlp = "mlp"


class TrackerSet(str, Enum):
    four = "4"
    three = "3"


def track_train_command(
    cache: Annotated[Path, typer.Argument(help="60 Hz pose cache from `smplik data build --fps 60` (train and "
                                          "validation splits).")],
    out: Annotated[Path, typer.Argument(help="Model file to write (.pt; its figures go beside it as .json).")],
    minutes: Annotated[float, typer.Option(help="Training time in minutes.")] = TrackingTrainConfig.minutes,
    kind: Annotated[NetKind, typer.Option(help="Network: cvae (the shipped model) or mlp (the ablation).")
                    ] = NetKind.cvae,
    trackers: Annotated[TrackerSet, typer.Option(help="Tracker set: 4 (head, wrists, pelvis) or 3 (no pelvis).")
                        ] = TrackerSet.four,
    threads: Annotated[int, typer.Option(help="Torch threads.")] = 1,
    device: Annotated[str, typer.Option(help="Torch device of the network, e.g. cuda.")] = "cpu",
    workers: Annotated[int, typer.Option(help="Background processes drawing batches (0: inline).")] = 0,
    batch: Annotated[int, typer.Option(help="Windows per batch.")] = TrackingTrainConfig.batch,
    lr: Annotated[float | None, typer.Option(help="Adam learning rate (default: the config's; half of it when "
                                             "continuing with --init).")] = None,
    seed: Annotated[int, typer.Option(help="Seed (plus 1 when continuing with --init).")] = 0,
    init: Annotated[Path | None, typer.Option(help="Model file to continue from.")] = None,
    rotation_weight: Annotated[float, typer.Option(help="Weight of the L1 of the local 6D rotations.")
                               ] = TrackingTrainConfig.rotation_weight,
) -> None:
    """Train the tracking model (VR trackers -> body) on a 60 Hz pose cache; keep the best validation state."""
    checks = [(minutes > 0, "--minutes", f"must be > 0, got {minutes:g}"),
              (threads >= 1, "--threads", f"must be >= 1, got {threads}"),
              (workers >= 0, "--workers", f"must be >= 0, got {workers}"),
              (batch >= 1, "--batch", f"must be >= 1, got {batch}"),
              (lr is None or lr > 0, "--lr", f"must be > 0, got {lr}"),
              (rotation_weight >= 0, "--rotation-weight", f"must be >= 0, got {rotation_weight:g}"),
              (out.suffix == ".pt", "OUT", f"must end in .pt, got {out}")]
    for ok, hint, message in checks:
        if not ok:
            raise typer.BadParameter(message, param_hint=hint)
    if not cache.is_file():
        fail(f"{cache}: no such pose cache (build one with `smplik data build --fps 60`).")
    if init is not None and not init.is_file():
        fail(f"{init}: no such model file (--init).")
    from smplik.tracking.config import TrackingNetConfig
    from smplik.tracking.train import train

    net = TrackingNetConfig(kind=kind.value, trackers=TRACKER_SETS[trackers.value])
    cfg = dataclasses.replace(TrackingTrainConfig(), cache=str(cache), net=net, minutes=minutes, threads=threads,
                              seed=seed + (1 if init else 0),
                              lr=lr or TrackingTrainConfig.lr * (0.5 if init else 1.0),
                              rotation_weight=rotation_weight, device=device, workers=workers, batch=batch)
    with user_errors():
        info = train(cfg, out, log=typer.echo, init=init)
    typer.echo(f"best validation MPJPE {info['val_mpjpe_mm']:.1f} mm after {info['steps']} steps")
