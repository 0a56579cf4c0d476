"""Option types and parsers shared by the ``smplik`` command groups."""

from __future__ import annotations

import math
import re
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from smplik.conventions import NUM_BETAS, Gender
from smplik.limits import MAX_FPS, MIN_FPS

if TYPE_CHECKING:
    from smplik.ensemble import EnsembleConfig

ModelDir = Annotated[Path | None, typer.Option("--model-dir", help="Folder with real SMPL files "
                                               "(default: $SMPLIK_MODEL_DIR, else the built-in model).")]
GenderOpt = Annotated[Gender, typer.Option("--gender", case_sensitive=False, help="Body model gender.")]


_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
"""A plain decimal number: no underscores (``float("1_0")`` is 10), no ``nan``/``inf``, no hex."""

FPS_RANGE = (MIN_FPS, MAX_FPS)  # smplik.limits: the one frame-rate range, for options and files alike
"""Accepted frame rates (frames per second) of every ``--fps`` option."""


def parse_number(text: str, option: str) -> float:
    """One plain, finite decimal number (:data:`_NUMBER`), or a ``typer.BadParameter`` naming ``option``."""
    if not _NUMBER.fullmatch(text.strip()):
        raise typer.BadParameter(f"{option} must be plain decimal numbers, got {text.strip()!r:.40}.")
    value = float(text)
    if not math.isfinite(value):
        raise typer.BadParameter(f"{option}: {text.strip()!r:.40} is beyond the float range.")
    return value


def parse_betas(text: str | None) -> list[float]:
    """Parse ``--betas`` as 1 to 10 comma- or space-separated plain numbers (missing ones are 0); None (the
    option not given) is all zeros. An empty value, an empty item (``1,,2``), ``nan``/``inf`` or ``1_0`` is a
    ``typer.BadParameter``."""
    if text is None:
        return [0.0] * NUM_BETAS
    parts = re.split(r"\s*,\s*|\s+", text.strip())
    if not text.strip() or any(not p for p in parts):
        raise typer.BadParameter(f"--betas must be 1 to {NUM_BETAS} numbers separated by commas or spaces, got "
                                 f"{text!r:.60}.")
    values = [parse_number(p, "--betas") for p in parts]
    if len(values) > NUM_BETAS:
        raise typer.BadParameter(f"--betas takes at most {NUM_BETAS} values, got {len(values)}.")
    return values + [0.0] * (NUM_BETAS - len(values))


def check_fps(fps: float | None, option: str = "--fps") -> float | None:
    """``fps`` when it is None (not given) or a finite rate within :data:`FPS_RANGE`; else ``typer.BadParameter``."""
    low, high = FPS_RANGE
    if fps is not None and not (math.isfinite(fps) and low <= fps <= high):
        raise typer.BadParameter(f"must be a frame rate in [{low:g}, {high:g}] frames per second, got {fps:g}.",
                                 param_hint=option)
    return fps


def check_image(path: Path | None, option: str = "--image") -> Path | None:
    """``path`` when None or a local, non-empty, regular file; else one ``typer.BadParameter``: a URL, a folder,
    a device or pipe, a missing or empty file are never ignored silently. Its content is checked where it is
    decoded (``scene from-estimate --no-previews`` only records the path)."""
    if path is None:
        return None
    text = str(path)
    if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:/", text):
        raise typer.BadParameter(f"must be a local image file, got the URL {text!r:.80}.", param_hint=option)
    try:
        info = path.stat()
    except OSError as exc:
        raise typer.BadParameter(f"{text}: {exc.strerror or exc}.", param_hint=option) from None
    if stat.S_ISDIR(info.st_mode):
        raise typer.BadParameter(f"{text} is a folder; give an image file.", param_hint=option)
    if not stat.S_ISREG(info.st_mode):
        raise typer.BadParameter(f"{text} is not a regular file (a device or a pipe); give an image file.",
                                 param_hint=option)
    if info.st_size == 0:
        raise typer.BadParameter(f"{text} is empty; give an image file.", param_hint=option)
    return path


def parse_ensemble(text: str) -> EnsembleConfig:
    """Parse ``--ensemble`` (``none``, ``mirror``, ``yawK``, ``mirror+yawK``) into an EnsembleConfig."""
    from smplik.ensemble import EnsembleConfig

    try:
        return EnsembleConfig.parse(text)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--ensemble") from None
