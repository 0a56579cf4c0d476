"""Tracking model files: a ``torch.save`` dict of tensors and plain values, read by the one model-file reader
(:func:`smplik.model_io.read_torch_file`, ``weights_only=True``) and checked key by key (:func:`read_tracking_file`).

Layout: ``{"info": {"format": "smplik-tracking", "version": 1, "net": TrackingNetConfig dict, "train": ...,
"val_mpjpe_mm": ...}, "state_dict": {...}, "pose_lo": (24, 3), "pose_hi": (24, 3)}`` (the 0.1 and 99.9
percentiles of the training set's axis-angle local rotations, for the anomaly score).
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from smplik.atomic import write_bytes_atomic
from smplik.tracking.config import TrackingNetConfig
from smplik.tracking.network import TrackingNet, WindowMLP, build_network

CHECKPOINT_FORMAT = "smplik-tracking"
CHECKPOINT_VERSION = 1
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent.parent / "checkpoints" / "smplik_tracking.pt"
THREE_TRACKER_CHECKPOINT = DEFAULT_CHECKPOINT.with_name("smplik_tracking_3.pt")
"""The shipped model for head and hands only (no waist tracker)."""


class TrackingModelError(ValueError):
    """A tracking model file cannot be used (one line, names the file)."""


def shipped_checkpoint(tracker_names: Iterable[str]) -> Path:
    """The shipped model for a recording with trackers ``tracker_names``: the 4-tracker model (head, hands,
    pelvis) when the recording has all four, else the 3-tracker model (head and hands) when it has those (a
    recording without them gets the 4-tracker model, whose one-line error names the first missing tracker)."""
    from smplik.tracking.config import TRACKER_SETS

    have = set(tracker_names)
    if set(TRACKER_SETS["4"]) <= have or not set(TRACKER_SETS["3"]) <= have:
        return DEFAULT_CHECKPOINT
    return THREE_TRACKER_CHECKPOINT


@dataclass(frozen=True)
class TrackingModel:
    """A loaded model: the network (eval mode), its config, the training rotation range and the file's info."""

    net: TrackingNet | WindowMLP
    cfg: TrackingNetConfig
    pose_lo: Tensor
    pose_hi: Tensor
    info: dict[str, Any]


def save_checkpoint(path: str | Path, net: TrackingNet | WindowMLP, info: dict[str, Any], *, pose_lo: Tensor,
                    pose_hi: Tensor) -> Path:
    """Write a model file atomically."""
    buf = io.BytesIO()
    torch.save({"info": info, "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
                "pose_lo": pose_lo.clone(), "pose_hi": pose_hi.clone()}, buf)
    path = Path(path)
    write_bytes_atomic(path, buf.getvalue())
    return path


def read_tracking_file(path: str | Path | None = None) -> dict[str, Any]:
    """A tracking model file's contents, read by the one model-file reader (:func:`smplik.model_io.read_torch_file`:
    zip and size checks, ``weights_only``, tensor sizes and layout) and checked key by key: ``info`` (format,
    version, ``net`` typed and within :data:`~smplik.tracking.config.TRACKING_NET_RANGES`, its ``fps`` a frame
    rate), ``state_dict`` names -> tensors, ``pose_lo``/``pose_hi`` finite float (24, 3) tensors with lo <= hi.

    Returns: the file's dict with ``info["net"]`` replaced by its :class:`TrackingNetConfig`.

    Raises: TrackingModelError (one line naming the file and key); LimitError (a size over a limit).
    """
    from smplik.model_io import read_torch_file

    path = Path(path) if path is not None else DEFAULT_CHECKPOINT
    if not path.is_file():
        raise TrackingModelError(f"{path}: tracking model not found.")
    blob = read_torch_file(path, what="tracking model", error=TrackingModelError)
    if not isinstance(blob, dict) or not isinstance(blob.get("info"), dict):
        raise TrackingModelError(f"{path}: not a tracking model (no 'info').")
    info = blob["info"]
    if info.get("format") != CHECKPOINT_FORMAT or info.get("version") != CHECKPOINT_VERSION:
        raise TrackingModelError(f"{path}: format {info.get('format')!r:.40} version {info.get('version')!r:.20}; "
                                 f"expected {CHECKPOINT_FORMAT!r} version {CHECKPOINT_VERSION}.")
    try:
        cfg = TrackingNetConfig.from_dict(info.get("net"))
    except (TypeError, ValueError) as exc:
        raise TrackingModelError(f"{path}: info.{exc}") from None
    weights = blob.get("state_dict")
    if not isinstance(weights, dict) or not all(isinstance(k, str) and isinstance(v, Tensor)
                                                for k, v in weights.items()):
        raise TrackingModelError(f"{path}: key 'state_dict' must map names to tensors.")
    for key in ("pose_lo", "pose_hi"):
        value = blob.get(key)
        if (not isinstance(value, Tensor) or tuple(value.shape) != (24, 3) or not value.is_floating_point()
                or not bool(torch.isfinite(value).all())):
            raise TrackingModelError(f"{path}: key '{key}' must be a finite float tensor of shape (24, 3), got "
                                     f"{type(value).__name__}{tuple(getattr(value, 'shape', ()))}.")
    if bool((blob["pose_lo"] > blob["pose_hi"]).any()):
        raise TrackingModelError(f"{path}: key 'pose_lo' exceeds 'pose_hi' (the training range is empty).")
    return {**blob, "info": {**info, "net": cfg}}


def load_model(path: str | Path | None = None) -> TrackingModel:
    """Read a model file (default: the shipped one) with :func:`read_tracking_file` and build its network.

    Raises: TrackingModelError (missing file, another format, bad config values, mismatched weights).
    """
    path = Path(path) if path is not None else DEFAULT_CHECKPOINT
    blob = read_tracking_file(path)
    cfg = blob["info"]["net"]
    try:
        net = build_network(cfg)
        net.load_state_dict(blob["state_dict"])
    except (KeyError, TypeError, RuntimeError, ValueError) as exc:
        raise TrackingModelError(f"{path}: weights do not match the config ({str(exc).splitlines()[0][:200]})."
                                 ) from None
    net.eval()
    info = {**blob["info"], "net": cfg.to_dict()}
    return TrackingModel(net=net, cfg=cfg, pose_lo=blob["pose_lo"].float(), pose_hi=blob["pose_hi"].float(),
                         info=info)
