"""Option types and parsers shared by the ``smplik`` command groups."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from smplik.conventions import NUM_BETAS, Gender

if TYPE_CHECKING:
    from smplik.ensemble import EnsembleConfig

ModelDir = Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files "
                                               "(default: $SMPLIK_MODEL_DIR, else the built-in model).")]
GenderOpt = Annotated[Gender, typer.Option("--gender", case_sensitive=False, help="Body model gender.")]


def parse_betas(text: str | None) -> list[float]:
    """Parse ``--betas`` as up to 10 comma/space separated numbers (missing ones are 0)."""
    if not text:
        return [0.0] * NUM_BETAS
    parts = [p for p in text.replace(",", " ").split() if p]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise typer.BadParameter(f"--betas must be numbers, got {text!r}.") from None
    if len(values) > NUM_BETAS:
        raise typer.BadParameter(f"--betas takes at most {NUM_BETAS} values, got {len(values)}.")
    return values + [0.0] * (NUM_BETAS - len(values))


def parse_ensemble(text: str) -> EnsembleConfig:
    """Parse ``--ensemble`` (``none``, ``mirror``, ``yawK``, ``mirror+yawK``) into an EnsembleConfig."""
    from smplik.ensemble import EnsembleConfig

    try:
        return EnsembleConfig.parse(text)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--ensemble") from None
