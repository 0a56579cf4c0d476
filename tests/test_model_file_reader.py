"""One model-file reader: every kind of ``.pt`` file smplik opens (IK model and training checkpoint, tracking
model, the pose range the variants read, estimator tensor files) is refused the same way through its public
loader: a file that is not a ``torch.save`` zip, a file whose declared storages are over the size limits, and a
pickle naming a global outside the allow-list (whose payload must not run), each in one line naming the file.
And ``torch.load`` is called in one module of the packages only."""

from __future__ import annotations

import ast
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch

from smplik.limits import LimitError
from smplik.model_io import CheckpointError, load_checkpoint, load_model
from smplik.tracking import model_io as tracking_io
from smplik.tracking.model_io import TrackingModelError
from workflows.estimators.reading import EstimateFormatError, read_estimate

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("smplik", "workflows", "shape_inversion", "benchmarks")


class Payload:
    """Unpickling this creates the directory ``marker`` (``os.mkdir``: a global no safe loader allows)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return (os.mkdir, (str(self.marker),))


def _variant_range(path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    """What the variants' plausibility check reads from ``path`` (None: the file was refused, range skipped)."""
    from smplik import variants

    monkeypatch.setattr(tracking_io, "DEFAULT_CHECKPOINT", path)
    variants.training_range.cache_clear()
    try:
        return variants.training_range()
    finally:
        variants.training_range.cache_clear()


LOADERS: dict[str, tuple[Callable[[Path], Any], type[Exception]]] = {
    "IK model": (load_model, CheckpointError),
    "IK checkpoint": (load_checkpoint, CheckpointError),
    "tracking model": (tracking_io.load_model, TrackingModelError),
    "estimator tensor file": (lambda p: read_estimate(p, format="gvhmr"), EstimateFormatError),
}


def _ik_state(model: dict[str, Any]) -> dict[str, Any]:
    return {"format": "smplik-checkpoint", "version": 2, "network": {}, "model": model, "step": 0}


def _tracking_state(extra: Any) -> dict[str, Any]:
    return {"info": {"format": "smplik-tracking", "version": 1, "net": {}}, "state_dict": {"w": extra},
            "pose_lo": torch.zeros(24, 3), "pose_hi": torch.ones(24, 3)}


def _state(kind: str, value: Any) -> dict[str, Any]:
    """A file of ``kind`` in its outline, with ``value`` where a tensor goes."""
    if kind.startswith("IK"):
        return _ik_state({"w": value})
    if kind == "tracking model":
        return _tracking_state(value)
    return {"smpl_params_global": {"body_pose": value}}


def _refusal(kind: str, path: Path) -> Exception:
    load, error = LOADERS[kind]
    with pytest.raises((error, LimitError)) as info:
        load(path)
    text = str(info.value)
    assert "\n" not in text.strip() and str(path) in text, text
    return info.value


@pytest.mark.parametrize("kind", sorted(LOADERS))
def test_a_file_that_is_not_a_torch_zip_is_refused_in_one_line(tmp_path, kind):
    path = tmp_path / "model.pt"
    path.write_bytes(b"PK\x03\x04 but not an archive\n" * 40)
    exc = _refusal(kind, path)
    assert isinstance(exc, LOADERS[kind][1]) and "zip" in str(exc), exc


@pytest.mark.parametrize("kind", sorted(LOADERS))
def test_declared_sizes_over_the_limits_are_refused_before_loading(tmp_path, monkeypatch, kind):
    path = tmp_path / "model.pt"
    torch.save(_state(kind, torch.zeros(4096)), path)  # one 16 KiB storage
    monkeypatch.setenv("SMPLIK_MAX_ARRAY_BYTES", "4K")
    exc = _refusal(kind, path)
    assert "SMPLIK_MAX_ARRAY_BYTES" in str(exc) and "16384" in str(exc), exc
    monkeypatch.setenv("SMPLIK_MAX_ARRAY_BYTES", "1M")
    monkeypatch.setenv("SMPLIK_MAX_INPUT_BYTES", "8K")  # the storage plus the pickle, all together
    exc = _refusal(kind, path)
    assert "SMPLIK_MAX_INPUT_BYTES" in str(exc), exc


@pytest.mark.parametrize("kind", sorted(LOADERS))
def test_a_pickled_global_is_refused_and_never_runs(tmp_path, kind):
    marker = tmp_path / "PAYLOAD_RAN"
    path = tmp_path / "model.pt"
    torch.save(_state(kind, Payload(marker)), path)
    exc = _refusal(kind, path)
    assert not marker.exists(), "the payload ran"
    assert isinstance(exc, LOADERS[kind][1]) and "mkdir" in str(exc) and "refused" in str(exc), exc


def test_the_payload_is_live(tmp_path):
    """The refusals above are the reader's: the same file loaded without ``weights_only`` runs its payload."""
    marker = tmp_path / "PAYLOAD_RAN"
    path = tmp_path / "model.pt"
    torch.save(_tracking_state(Payload(marker)), path)
    torch.load(path, weights_only=False)
    assert marker.is_dir()


def test_the_variants_pose_range_skips_a_refused_file(tmp_path, monkeypatch):
    shipped = tracking_io.DEFAULT_CHECKPOINT
    if not shipped.is_file():
        pytest.skip(f"the shipped tracking model is absent: {shipped}")
    lo, hi = _variant_range(shipped, monkeypatch)
    assert lo.shape == hi.shape == (24, 3) and (lo <= hi).all()
    marker = tmp_path / "PAYLOAD_RAN"
    bad = tmp_path / "tracking.pt"
    torch.save(_tracking_state(Payload(marker)), bad)
    assert _variant_range(bad, monkeypatch) is None
    assert not marker.exists(), "the payload ran"
    bad.write_bytes(b"not a zip")
    assert _variant_range(bad, monkeypatch) is None


def _torch_load_calls(path: Path) -> list[int]:
    """Line numbers of ``torch.load(...)`` calls in a Python file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute) and node.func.attr == "load"
            and isinstance(node.func.value, ast.Name) and node.func.value.id == "torch"]


def test_torch_load_is_called_by_the_one_reader_only():
    calls = {str(p.relative_to(REPO)): lines for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))
             if (lines := _torch_load_calls(p))}
    assert calls.keys() == {"smplik/model_io.py"}, calls
