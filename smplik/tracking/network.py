"""The tracking networks: a GRU conditional VAE (Milef et al. 2023, section 3.1) and an AvatarPoser-style MLP.

:class:`TrackingNet` (``kind="cvae"``), per frame t with tracker features x_t (:mod:`smplik.tracking.features`),
body shape beta (10) and gender one-hot (3):

* condition encoder: ``h_t = GRU(MLP([x_t, beta, gender]), h_{t-1})`` (run once per frame, shared by samples);
* prior ``p(z_t | h_t) = N(mu_p, sigma_p)`` and, for training only, posterior
  ``q(z_t | h_t, y_t) = N(mu_q, sigma_q)`` (y_t the target pose): a learned, history-conditioned prior, so
  inference needs no encoder of the pose (a CVAE, Sohn et al. 2015);
* decoder: ``MLP([h_t, z_t, beta, gender])`` -> 24 local 6D rotations, the pelvis position in the heading frame
  and two contact logits. A sample is a noise vector eps kept over time, ``z_t = mu_p + sigma_p eps``; eps = 0
  is the deterministic output. N samples are N rows of the decoder batch; the GRU runs once.

:class:`WindowMLP` (``kind="mlp"``): the baseline, an MLP over the last ``window`` frames of features
(AvatarPoser's input, with its transformer replaced by an MLP), deterministic.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from smplik.tracking.config import FEATURES_PER_TRACKER, TrackingNetConfig
from smplik.tracking.features import NUM_OUT_ROT, OUT_DIM

TARGET_DIM = NUM_OUT_ROT + 3
"""Columns of a pose target: local 6D rotations and the pelvis in the heading frame."""


def input_dim(cfg: TrackingNetConfig) -> int:
    """Feature columns per frame for ``cfg``'s trackers."""
    return len(cfg.trackers) * FEATURES_PER_TRACKER + 2


def _mlp(d_in: int, d: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(d_in, d), nn.SiLU(), nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d_out))


def init_identity_rotations(head: nn.Linear) -> None:
    """Start an output layer's 24 6D rotations at the identity: the bias of those columns is the identity's 6D
    (1, 0, 0, 0, 1, 0), so a small output is the rest pose. Without it a column near zero is normalised into an
    arbitrary direction (a spine joint twisted by pi, undone by the next one, costs almost no position error and
    the network settled there: the spine-twist anomaly of the first model)."""
    with torch.no_grad():
        head.bias[:NUM_OUT_ROT] += torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]).repeat(24)


class TrackingNet(nn.Module):
    """GRU conditional VAE (see the module docstring). Buffers ``x_mean``/``x_std`` standardise the inputs."""

    def __init__(self, cfg: TrackingNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d_x, H, Z = input_dim(cfg), cfg.hidden, cfg.latent
        self.register_buffer("x_mean", torch.zeros(d_x))
        self.register_buffer("x_std", torch.ones(d_x))
        self.embed = nn.Sequential(nn.Linear(d_x + 13, H), nn.SiLU(), nn.Linear(H, H), nn.SiLU())
        self.gru = nn.GRU(H, H, batch_first=True)
        self.prior = nn.Linear(H, 2 * Z)
        self.posterior = _mlp(H + TARGET_DIM, H, 2 * Z)
        self.decoder = _mlp(H + Z + 13, cfg.decoder, OUT_DIM)
        init_identity_rotations(self.decoder[-1])

    def condition(self, x: Tensor, body: Tensor, h0: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Condition states. x (B, T, d_x) raw features, body (B, 13) [beta, gender one-hot], h0 (1, B, H) or None
        -> ``(h (B, T, H), h_last (1, B, H))``."""
        xs = (x - self.x_mean) / self.x_std
        e = self.embed(torch.cat([xs, body[:, None, :].expand(-1, x.shape[1], -1)], dim=-1))
        return self.gru(e, h0)

    def prior_params(self, h: Tensor) -> tuple[Tensor, Tensor]:
        """(mu, log_sigma) (..., Z) of p(z | h)."""
        mu, log_sigma = self.prior(h).chunk(2, dim=-1)
        return mu, log_sigma.clamp(-6.0, 2.0)

    def decode(self, h: Tensor, z: Tensor, body: Tensor) -> Tensor:
        """Outputs (..., OUT_DIM) from condition states h (..., H), latents z (..., Z), body (..., 13)."""
        return self.decoder(torch.cat([h, z, body], dim=-1))

    def sample(self, h: Tensor, eps: Tensor, body: Tensor) -> Tensor:
        """Outputs for noise vectors: h (..., H), eps (..., Z) (0 = deterministic), body (..., 13)."""
        mu, log_sigma = self.prior_params(h)
        return self.decode(h, mu + log_sigma.exp() * eps, body)

    def forward_train(self, x: Tensor, body: Tensor, target: Tensor, generator: torch.Generator | None = None
                      ) -> tuple[Tensor, Tensor]:
        """Training pass. x (B, T, d_x), body (B, 13), target (B, T, TARGET_DIM) ->
        ``(outputs (B, T, OUT_DIM) decoded from posterior samples, KL (B, T, Z) per latent dimension)``."""
        h, _ = self.condition(x, body)
        mu_p, ls_p = self.prior_params(h)
        mu_q, ls_q = self.posterior(torch.cat([h, target], dim=-1)).chunk(2, dim=-1)
        ls_q = ls_q.clamp(-6.0, 2.0)
        eps = torch.randn(mu_q.shape, generator=generator).to(mu_q)  # a CPU generator on any device
        z = mu_q + ls_q.exp() * eps
        out = self.decode(h, z, body[:, None, :].expand(-1, x.shape[1], -1))
        kl = ls_p - ls_q + ((2 * ls_q).exp() + (mu_q - mu_p) ** 2) / (2 * (2 * ls_p).exp()) - 0.5
        return out, kl

    def forward(self, x: Tensor, body: Tensor, eps: Tensor | None = None) -> Tensor:
        """Whole sequences with one noise vector per sequence: x (B, T, d_x), body (B, 13), eps (B, Z) or None
        (deterministic) -> outputs (B, T, OUT_DIM)."""
        h, _ = self.condition(x, body)
        e = h.new_zeros(h.shape[0], self.cfg.latent) if eps is None else eps
        return self.sample(h, e[:, None, :].expand(-1, h.shape[1], -1), body[:, None, :].expand(-1, h.shape[1], -1))


class WindowMLP(nn.Module):
    """AvatarPoser-style baseline: an MLP over the last ``cfg.window`` frames of features (zero-padded at the
    start), deterministic."""

    def __init__(self, cfg: TrackingNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d_x = input_dim(cfg)
        self.register_buffer("x_mean", torch.zeros(d_x))
        self.register_buffer("x_std", torch.ones(d_x))
        self.net = nn.Sequential(nn.Linear(d_x * cfg.window + 13, 512), nn.SiLU(), nn.Linear(512, 512), nn.SiLU(),
                                 nn.Linear(512, 512), nn.SiLU(), nn.Linear(512, OUT_DIM))
        init_identity_rotations(self.net[-1])

    def forward(self, x: Tensor, body: Tensor, eps: Tensor | None = None) -> Tensor:
        """x (B, T, d_x), body (B, 13) -> outputs (B, T, OUT_DIM); frame t sees frames t - window + 1 .. t."""
        W = self.cfg.window
        xs = (x - self.x_mean) / self.x_std
        pad = torch.cat([xs.new_zeros(xs.shape[0], W - 1, xs.shape[2]), xs], dim=1)
        win = pad.unfold(1, W, 1).transpose(-1, -2).flatten(-2)  # (B, T, W * d_x)
        return self.net(torch.cat([win, body[:, None, :].expand(-1, x.shape[1], -1)], dim=-1))

    def forward_train(self, x: Tensor, body: Tensor, target: Tensor, generator: torch.Generator | None = None
                      ) -> tuple[Tensor, Tensor]:
        out = self.forward(x, body)
        return out, out.new_zeros(*out.shape[:2], 1)


def build_network(cfg: TrackingNetConfig) -> TrackingNet | WindowMLP:
    """The network of ``cfg.kind``."""
    return TrackingNet(cfg) if cfg.kind == "cvae" else WindowMLP(cfg)
