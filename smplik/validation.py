"""Input validation shared by the public entry points: arrays, physical ranges, betas, JSON documents.

Documented physical ranges (inputs outside them are refused with a named error; they are far beyond any
real scene, and past them float32 network inputs and the refinement's normal equations lose meaning):

* positions and look-at targets: ``|x| <= MAX_ABS_POSITION_M`` (1 km) per coordinate;
* body shape: ``|beta_i| <= MAX_ABS_BETA`` (SMPL-SI samples U(-5, 5); +-3 spans realistic adults);
* character scale: ``MIN_SCALE <= scale <= MAX_SCALE``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from smplik.conventions import NUM_BETAS

MAX_ABS_POSITION_M = 1000.0
"""Largest accepted |coordinate| of a position effector or look-at target (metres)."""
MAX_ABS_BETA = 20.0
"""Largest accepted |beta_i|."""
MIN_SCALE, MAX_SCALE = 1e-3, 1e3
"""Accepted range of a character's scale factor."""
"""Largest JSON input file read (bytes)."""


def finite_array(value: Any, shape: tuple[int, ...], where: str, error: type[Exception] = ValueError, *,
                 max_abs: float | None = None) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` with no NaN/inf (and ``|x| <= max_abs``), else ``error``
    naming ``where``. Booleans and strings are refused (``True`` is not a number here)."""
    if isinstance(value, (str, bytes, bool, dict)) or value is None or _has_bool(value):
        raise error(f"{where}: must be numbers, got {short_repr(value)}.")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise error(f"{where}: must be numbers, got {short_repr(value)}.") from None
    if arr.shape != shape:
        raise error(f"{where}: has shape {arr.shape}; expected {shape}.")
    if not np.isfinite(arr).all():
        raise error(f"{where}: contains NaN or inf.")
    if max_abs is not None and arr.size and np.abs(arr).max() > max_abs:
        raise error(f"{where}: {np.abs(arr).max():.6g} is outside the accepted range |x| <= {max_abs:g}.")
    return arr


def _has_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    if isinstance(value, (list, tuple)):
        return any(_has_bool(v) for v in value)
    return False


def short_repr(value: Any) -> str:
    """A short JSON-ish rendering of ``value`` for messages (at most 60 characters)."""
    try:
        text = json.dumps(value, default=str)
    except (TypeError, ValueError, RecursionError):
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_betas(betas: Any, batch: int | None = None, *, where: str = "betas",
                error: type[Exception] = ValueError) -> np.ndarray:
    """The one betas validation: None (zeros), (10,) or, with ``batch``, (batch, 10); finite and within
    ``MAX_ABS_BETA``. Returns (10,) or (batch, 10) float64; raises ``error`` naming ``where``."""
    if betas is None:
        return np.zeros(NUM_BETAS) if batch is None else np.zeros((batch, NUM_BETAS))
    if hasattr(betas, "detach"):  # a torch tensor
        betas = betas.detach().cpu().numpy()
    if isinstance(betas, (str, bytes, bool, dict)) or _has_bool(betas):
        raise error(f"{where}: must be {NUM_BETAS} numbers, got {short_repr(betas)}.")
    try:
        arr = np.asarray(betas, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise error(f"{where}: must be {NUM_BETAS} numbers, got {short_repr(betas)}.") from None
    if arr.ndim == 0 or arr.shape[-1] != NUM_BETAS:
        n = arr.shape[-1] if arr.ndim else "a scalar"
        raise error(f"{where}: Wrong number of betas: got {n}, need exactly {NUM_BETAS} (shape {arr.shape}).")
    if batch is None and arr.ndim != 1:
        raise error(f"{where}: has shape {arr.shape}; expected ({NUM_BETAS},).")
    if batch is not None:
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (batch, NUM_BETAS))
        elif arr.shape != (batch, NUM_BETAS):
            raise error(f"{where}: has shape {arr.shape}; expected ({NUM_BETAS},) or ({batch}, {NUM_BETAS}).")
    if not np.isfinite(arr).all():
        raise error(f"{where}: contains NaN or inf.")
    if np.abs(arr).max() > MAX_ABS_BETA:
        raise error(f"{where}: {np.abs(arr).max():.6g} is outside the accepted range |beta| <= {MAX_ABS_BETA:g}.")
    return arr


class JSONPathError:
    """Builds ``source: json.path: message`` errors of one error class (the shared JSON-path convention)."""

    def __init__(self, source: str = "", error: type[Exception] = ValueError) -> None:
        self.source, self.error_class = source, error

    def __call__(self, path: str, message: str) -> Exception:
        text = f"{path}: {message}" if path else message
        return self.error_class(f"{self.source}: {text}" if self.source else text)


def read_text(path: str | Path, error: type[Exception] = ValueError, *, what: str = "text file",
              limit: Any = None) -> str:
    """Read a UTF-8 text file under ``limit`` (default :data:`smplik.limits.TEXT_BYTES`) with one-line errors
    (``error``) naming the file: missing, a folder, unreadable, too big or not UTF-8."""
    from smplik.limits import TEXT_BYTES, LimitError, read_bounded

    path = Path(path)
    try:
        if path.is_dir():
            raise IsADirectoryError(path)
        return read_bounded(path, TEXT_BYTES if limit is None else limit).decode("utf-8")
    except LimitError as exc:
        raise error(f"{what[0].upper()}{what[1:]} {exc}") from None
    except FileNotFoundError:
        raise error(f"{what[0].upper()}{what[1:]} not found: {path}") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, not a {what}.") from None
    except UnicodeDecodeError:
        raise error(f"{path}: {what} is not UTF-8 text.") from None
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc}).") from None


def read_json(path: str | Path, error: type[Exception] = ValueError, *, what: str = "JSON file",
              loads: Callable[[str], Any] = json.loads) -> Any:
    """Read a JSON file with one-line errors (``error``) naming the file: missing, unreadable, too big,
    not UTF-8, invalid JSON or nested too deeply."""
    from smplik.limits import JSON_BYTES

    text = read_text(path, error, what=what, limit=JSON_BYTES)
    try:
        return loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: invalid JSON ({exc}).") from None
    except RecursionError:
        raise error(f"{path}: JSON nested too deeply.") from None
    except ValueError as exc:  # an integer of more than 4300 digits (Python's int conversion limit), ...
        raise error(f"{path}: invalid JSON number ({' '.join(str(exc).split())[:160]}).") from None
