"""Readers for image-to-SMPL estimator outputs, one module per format (see each module's docstring).

:func:`read_estimate` picks the reader by ``format`` or detects it from the file's content; every
reader returns people in smplik's y-up world (:mod:`workflows.estimators.base`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from workflows.estimators import hybrik, phalp, plain, pymafx, romp, wham
from workflows.estimators.base import (
    M_WORLD_CAMERA,
    CameraInfo,
    EstimatedPerson,
    EstimateFormatError,
    camera_to_world,
)

FormatName = Literal["auto", "romp", "bev", "hybrik", "phalp", "wham", "pymafx", "plain"]
FORMATS: tuple[str, ...] = ("romp", "bev", "hybrik", "phalp", "wham", "pymafx", "plain")
_MODULES = {"romp": romp, "bev": romp, "hybrik": hybrik, "phalp": phalp, "wham": wham, "pymafx": pymafx,
            "plain": plain}
_DETECT_ORDER = (romp, hybrik, phalp, wham, pymafx, plain)

__all__ = ["M_WORLD_CAMERA", "CameraInfo", "EstimatedPerson", "EstimateFormatError", "FORMATS", "camera_to_world",
           "detect_format", "read_estimate"]


def _load_raw(path: Path, trust_pickle: bool) -> Any:
    import json

    from workflows.safe_pickle import load_npz, load_pickle

    suffix = path.suffix.lower()
    if suffix == ".npz":
        return load_npz(path)
    if suffix == ".json":
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise EstimateFormatError(f"{path}: cannot read JSON ({exc}).") from exc
    if suffix in (".pk", ".pkl", ".pickle", ".joblib"):
        return load_pickle(path, trust_pickle=trust_pickle)
    raise EstimateFormatError(f"{path}: unsupported file type {suffix!r} (expected .npz, .json, .pk or .pkl).")


def detect_format(data: Any) -> str:
    """The format whose layout ``data`` (a loaded file) matches, or :class:`EstimateFormatError`."""
    for module in _DETECT_ORDER:
        if module.matches(data):
            return module.FORMAT
    keys = ", ".join(map(str, list(data)[:8])) if isinstance(data, dict) else type(data).__name__
    raise EstimateFormatError(f"Cannot detect the estimator format (top-level keys: {keys}); pass --format "
                              f"({', '.join(FORMATS)}).")


def read_estimate(path: str | Path, *, format: FormatName = "auto", trust_pickle: bool = False,
                  frame: int | None = None) -> list[EstimatedPerson]:
    """Read an estimator output file into people in the y-up world.

    Args:
        path: the results file.
        format: one of :data:`FORMATS` or ``"auto"`` (detect from the content).
        trust_pickle: load pickles with plain joblib/pickle (runs code from the file).
        frame: for video outputs (HybrIK, PHALP, WHAM, PyMAF-X), which frame; default the first.

    Raises:
        EstimateFormatError: unknown format or a layout mismatch (naming the key).
        workflows.safe_pickle.UnsafePickleError: a pickle names a refused global.
    """
    path = Path(path)
    if not path.is_file():
        raise EstimateFormatError(f"Estimator output not found: {path}")
    if format != "auto" and format not in _MODULES:
        raise EstimateFormatError(f"Unknown format {format!r}; expected auto or one of {', '.join(FORMATS)}.")
    data = _load_raw(path, trust_pickle)
    name = detect_format(data) if format == "auto" else format
    module = _MODULES[name]
    source = str(path)
    if module is romp:
        people = romp.from_data(data, source=source)
    elif module is plain:
        people = plain.from_data(data, source=source)
    else:
        people = module.from_data(data, source=source, frame=frame)
    if not people:
        raise EstimateFormatError(f"{path}: no people found.")
    return people
