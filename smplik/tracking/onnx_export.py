"""The tracking network's per-frame step as ONNX (for engines: Unity Sentis, Unreal NNE, onnxruntime-web).

Graph (opset :data:`smplik.onnx_runtime.ONNX_OPSET`, TorchScript exporter as for the IK model), one frame:

==========  =========  =======  ==============================================================
name        shape      dtype    meaning
==========  =========  =======  ==============================================================
x           (1, F)     float32  the frame's features (:func:`smplik.tracking.features.tracker_features`)
body        (1, 13)    float32  beta (10) and the gender one-hot (neutral, male, female)
h           (1, H)     float32  the GRU state of the previous frame (zeros at the first frame)
eps         (N, Z)     float32  one noise vector per sample (zeros: deterministic); N dynamic
==========  =========  =======  ==============================================================

Outputs: ``h_next`` (1, H), ``out`` (N, 24 * 6 + 3 + 2): local 6D rotations (root in the heading frame), the
pelvis in the heading frame and the contact logits (decoded by :func:`smplik.tracking.features.decode_pose`).
"""

from __future__ import annotations

import io
from pathlib import Path

import torch
from torch import Tensor, nn

from smplik.atomic import write_bytes_atomic
from smplik.tracking.network import TrackingNet, input_dim

INPUT_NAMES = ("x", "body", "h", "eps")
OUTPUT_NAMES = ("h_next", "out")


class _Step(nn.Module):
    def __init__(self, net: TrackingNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: Tensor, body: Tensor, h: Tensor, eps: Tensor) -> tuple[Tensor, Tensor]:
        hs, h_next = self.net.condition(x[:, None, :], body, h[None])
        h_t = hs[:, 0]
        N = eps.shape[0]
        out = self.net.sample(h_t.expand(N, -1), eps, body.expand(N, -1))
        return h_next[0], out


def export_tracking_onnx(net: TrackingNet, path: str | Path) -> Path:
    """Write the step graph of ``net`` (module docstring) atomically."""
    import warnings

    from smplik.onnx_runtime import ONNX_OPSET

    net = net.eval()
    H, Z = net.cfg.hidden, net.cfg.latent
    example = (torch.zeros(1, input_dim(net.cfg)), torch.zeros(1, 13), torch.zeros(1, H), torch.zeros(4, Z))
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(_Step(net), example, buf, dynamo=False, opset_version=ONNX_OPSET,
                          input_names=list(INPUT_NAMES), output_names=list(OUTPUT_NAMES),
                          dynamic_axes={"eps": {0: "samples"}, "out": {0: "samples"}})
    return write_bytes_atomic(Path(path), buf.getvalue())
