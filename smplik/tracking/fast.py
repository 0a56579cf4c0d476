"""The per-frame inference path in plain numpy (float32): GRU step, prior, decoder, 6D -> matrices, FK and the
anomaly score, with the weights of a :class:`~smplik.tracking.network.TrackingNet`. Small batches (1 to a few
dozen rows) are dominated by per-call overhead, which numpy keeps at a few microseconds per operation; the
torch module stays the reference (``tests/test_tracking.py`` checks that both agree).
"""

from __future__ import annotations

import numpy as np

from smplik.conventions import PARENTS
from smplik.rotations import rot6d_to_matrix_np
from smplik.tracking.features import NUM_OUT_ROT
from smplik.tracking.network import TrackingNet


def _silu(x: np.ndarray) -> np.ndarray:
    return x / (1.0 + np.exp(-x))


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


class NumpyTrackingNet:
    """The weights of a :class:`TrackingNet` as numpy arrays, with its per-frame functions."""

    def __init__(self, net: TrackingNet) -> None:
        sd = {k: v.detach().numpy().astype(np.float32) for k, v in net.state_dict().items()}
        self.x_mean, self.x_inv_std = sd["x_mean"], 1.0 / sd["x_std"]
        self.embed = [(sd[f"embed.{i}.weight"].T.copy(), sd[f"embed.{i}.bias"]) for i in (0, 2)]
        self.W_ih, self.W_hh = sd["gru.weight_ih_l0"].T.copy(), sd["gru.weight_hh_l0"].T.copy()
        self.b_ih, self.b_hh = sd["gru.bias_ih_l0"], sd["gru.bias_hh_l0"]
        self.prior = (sd["prior.weight"].T.copy(), sd["prior.bias"])
        self.decoder = [(sd[f"decoder.{i}.weight"].T.copy(), sd[f"decoder.{i}.bias"]) for i in (0, 2, 4)]
        self.H, self.Z = self.W_hh.shape[0], net.cfg.latent

    def condition_step(self, x: np.ndarray, body: np.ndarray, h: np.ndarray) -> np.ndarray:
        """One GRU step: x (d_x,) raw features, body (13,), h (H,) -> new h (H,) (PyTorch's GRU equations)."""
        e = np.concatenate([(x - self.x_mean) * self.x_inv_std, body])
        for W, b in self.embed:
            e = _silu(e @ W + b)
        gi = e @ self.W_ih + self.b_ih
        gh = h @ self.W_hh + self.b_hh
        H = self.H
        r = _sigmoid(gi[:H] + gh[:H])
        z = _sigmoid(gi[H:2 * H] + gh[H:2 * H])
        n = np.tanh(gi[2 * H:] + r * gh[2 * H:])
        return (1.0 - z) * n + z * h

    def sample(self, h: np.ndarray, eps: np.ndarray, body: np.ndarray) -> np.ndarray:
        """Outputs (N, OUT_DIM) for one state h (H,), noise eps (N, Z), body (13,)."""
        W, b = self.prior
        mu, log_sigma = np.split(h @ W + b, 2)
        z = mu + np.exp(np.clip(log_sigma, -6.0, 2.0)) * eps
        N = eps.shape[0]
        a = np.concatenate([np.broadcast_to(h, (N, self.H)), z, np.broadcast_to(body, (N, body.shape[0]))], axis=1)
        (W0, b0), (W1, b1), (W2, b2) = self.decoder
        return _silu(_silu(a @ W0 + b0) @ W1 + b1) @ W2 + b2


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=np.float32)


def decode_np(out: np.ndarray, yaw: float, origin: np.ndarray, J_rest: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`smplik.tracking.features.decode_pose` for outputs (N, OUT_DIM) of one frame ->
    ``(R_local (N, 24, 3, 3), transl (N, 3), contact_prob (N, 2))``."""
    R = rot6d_to_matrix_np(out[:, :NUM_OUT_ROT].reshape(-1, 24, 6))
    Y = yaw_matrix(yaw)
    R[:, 0] = Y @ R[:, 0]
    pel = out[:, NUM_OUT_ROT:NUM_OUT_ROT + 3] @ Y.T + origin
    return R, pel - J_rest[0], _sigmoid(out[:, NUM_OUT_ROT + 3:])


_OFFSET_PARENTS = np.array([max(p, 0) for p in PARENTS])


def _depth_levels() -> list[tuple[np.ndarray, np.ndarray]]:
    depth = [0] * len(PARENTS)
    for j in range(1, len(PARENTS)):
        depth[j] = depth[PARENTS[j]] + 1
    return [(np.array([j for j in range(len(PARENTS)) if depth[j] == d]),
             np.array([PARENTS[j] for j in range(len(PARENTS)) if depth[j] == d])) for d in range(1, max(depth) + 1)]


_LEVELS = _depth_levels()


def fk_np(R_local: np.ndarray, J_rest: np.ndarray, transl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FK of (N, 24, 3, 3) local rotations on rest joints (24, 3) with transl (N, 3) ->
    ``(R_world (N, 24, 3, 3), p_world (N, 24, 3))``, one batched step per tree depth."""
    N = R_local.shape[0]
    offsets = J_rest - J_rest[_OFFSET_PARENTS]
    G = np.empty_like(R_local)
    p = np.empty((N, 24, 3), dtype=R_local.dtype)
    G[:, 0] = R_local[:, 0]
    p[:, 0] = J_rest[0] + transl
    for js, ps in _LEVELS:
        Gp = G[:, ps]
        G[:, js] = Gp @ R_local[:, js]
        p[:, js] = p[:, ps] + (Gp @ offsets[js][..., None])[..., 0]
    return G, p
