"""Training loop of the tracking model, top to bottom (nanoGPT style): batch, loss, step, validate, keep best.

Loss per frame (Milef et al. eq. 1, with our terms): mean joint position error of the FK of the predicted pose
(metres, world frame) + ``leg_weight`` times that of the leg joints + ``velocity_weight`` times the
frame-to-frame joint velocity error (m/s / 10) + ``rotation_weight`` times the L1 of the local 6D rotations +
``matrix_weight`` times the L1 of the normalised local rotation matrices (root excluded) + ``foot_weight`` times
the predicted ankle/foot speed on the truth's contact frames (m/s / 10) + ``contact_weight`` times the contact BCE +
``kl_weight`` times KL(q || p) (with ``free_bits`` nats per latent dimension, against posterior collapse).
Validation: deterministic (eps = 0) MPJPE on fixed windows of the validation
split; the best state is the one saved.

Usage: ``smplik track-train CACHE OUT.pt [--minutes M] [--kind cvae|mlp]`` (:mod:`smplik.cli.track_train`).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from smplik.atomic import write_json_atomic
from smplik.body_model import BodyModelSet
from smplik.conventions import JOINT_INDEX
from smplik.data.dataset import load_cache
from smplik.kinematics import forward_kinematics
from smplik.tracking.config import TrackingTrainConfig
from smplik.tracking.data import WindowBatch, WindowSampler
from smplik.tracking.features import NUM_OUT_ROT, decode_pose
from smplik.tracking.model_io import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, save_checkpoint
from smplik.tracking.network import TrackingNet, WindowMLP, build_network

LEG_JOINTS = [JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("hip", "knee", "ankle", "foot")]
FOOT_JOINTS = [JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("ankle", "foot")]
FOOT_SIDES = [0, 0, 1, 1]
"""The contact column (left, right) of each of :data:`FOOT_JOINTS`."""


def batch_loss(net: TrackingNet | WindowMLP, b: WindowBatch, cfg: TrackingTrainConfig, fps: float,
               generator: torch.Generator) -> tuple[Tensor, dict[str, float]]:
    """The training loss of one batch and its terms."""
    out, kl = net.forward_train(b.x, b.body, b.target, generator)
    R, transl, _ = decode_pose(out, b.yaw, b.origin, b.J_rest[:, None])
    _, p = forward_kinematics(R, b.J_rest[:, None], transl)
    pos = (p - b.p_world).norm(dim=-1).mean()
    dv = ((p[:, 1:] - p[:, :-1]) - (b.p_world[:, 1:] - b.p_world[:, :-1])) * (fps * 0.1)
    vel = dv.norm(dim=-1).mean()
    rot = (out[..., :NUM_OUT_ROT] - b.target[..., :NUM_OUT_ROT]).abs().mean()
    mat = (R[..., 1:, :, :] - b.R_local[..., 1:, :, :]).abs().mean()
    legs = (p[..., LEG_JOINTS, :] - b.p_world[..., LEG_JOINTS, :]).norm(dim=-1).mean()
    on = (b.contact[:, 1:] * b.contact[:, :-1])[..., FOOT_SIDES]  # (B, T - 1, 4) both frames in contact
    foot_v = (p[:, 1:, FOOT_JOINTS] - p[:, :-1, FOOT_JOINTS]).norm(dim=-1) * (fps * 0.1)
    foot = (foot_v * on).sum() / on.sum().clamp_min(1.0)
    bce = torch.nn.functional.binary_cross_entropy_with_logits(out[..., NUM_OUT_ROT + 3:], b.contact)
    kl_m = kl.sum(-1).mean()
    kl_free = torch.clamp(kl.mean((0, 1)), min=cfg.free_bits).sum()  # free bits per latent dimension
    loss = (pos + cfg.velocity_weight * vel + cfg.rotation_weight * rot + cfg.matrix_weight * mat
            + cfg.leg_weight * legs + cfg.foot_weight * foot + cfg.contact_weight * bce + cfg.kl_weight * kl_free)
    return loss, {"pos_mm": 1000 * pos.item(), "vel": vel.item(), "rot": rot.item(), "mat": mat.item(),
                  "legs_mm": 1000 * legs.item(), "foot": foot.item(), "bce": bce.item(), "kl": kl_m.item()}


def to_device(b: WindowBatch, device: torch.device | str) -> WindowBatch:
    """The batch with every tensor on ``device``."""
    return WindowBatch(**{f.name: getattr(b, f.name).to(device, non_blocking=True) for f in dataclasses.fields(b)})


class _BatchStream(torch.utils.data.IterableDataset):
    """Endless training batches drawn in a worker process, each worker with its own seeded generator."""

    def __init__(self, make_sampler: Any, seed: int) -> None:
        self.make_sampler, self.seed = make_sampler, seed

    def __iter__(self) -> Any:
        info = torch.utils.data.get_worker_info()
        torch.set_num_threads(1)
        sampler = self.make_sampler(torch.Generator().manual_seed(self.seed + 1000 * (info.id + 1 if info else 0)))
        while True:
            yield sampler.sample()


def batch_stream(make_sampler: Any, seed: int, workers: int) -> Any:
    """An iterator of training batches: drawn inline (``workers`` 0) or by ``workers`` background processes."""
    if workers <= 0:
        sampler = make_sampler(torch.Generator().manual_seed(seed))
        while True:
            yield sampler.sample()
    loader = torch.utils.data.DataLoader(_BatchStream(make_sampler, seed), batch_size=None, num_workers=workers,
                                         prefetch_factor=4, persistent_workers=True,
                                         multiprocessing_context="fork")
    yield from loader


@torch.no_grad()
def evaluate(net: TrackingNet | WindowMLP, batches: list[WindowBatch]) -> float:
    """Deterministic MPJPE (mm, world frame) over fixed batches."""
    net.eval()
    errs = []
    for b in batches:
        out = net(b.x, b.body)
        R, transl, _ = decode_pose(out, b.yaw, b.origin, b.J_rest[:, None])
        _, p = forward_kinematics(R, b.J_rest[:, None], transl)
        errs.append((p - b.p_world).norm(dim=-1).mean())
    net.train()
    return 1000 * float(torch.stack(errs).mean())


def train(cfg: TrackingTrainConfig, out: str | Path, log: Any = print, init: str | Path | None = None
          ) -> dict[str, Any]:
    """Train, validate, save the best checkpoint at ``out`` (+ ``out`` with ``.json``: config and figures).
    ``init``: a model file to continue from (its weights and input statistics; a fresh optimizer and schedule)."""
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    g = torch.Generator().manual_seed(cfg.seed)
    data = load_cache(cfg.cache)
    fps = data.fps
    if abs(fps - cfg.net.fps) > 1e-6:
        raise ValueError(f"{cfg.cache}: the cache is at {fps:g} fps; the network config expects {cfg.net.fps:g}.")
    bodies = BodyModelSet.load()
    train_data, val_data = data.subset("train"), data.subset("validation")
    device = torch.device(cfg.device)

    def make_sampler(generator: torch.Generator) -> WindowSampler:
        return WindowSampler(train_data, bodies, trackers=cfg.net.trackers, length=cfg.length, batch=cfg.batch,
                             generator=generator, beta_noise=cfg.beta_noise, noise_m=cfg.noise_m,
                             rotation_dropout=cfg.rotation_dropout)

    sampler = make_sampler(g)
    val_sampler = WindowSampler(val_data, bodies, trackers=cfg.net.trackers, length=128, batch=32,
                                generator=torch.Generator().manual_seed(1234), beta_noise=cfg.beta_noise,
                                augment=False)
    val_batches = [to_device(val_sampler.sample(), device) for _ in range(4)]
    net = build_network(cfg.net)
    previous: dict[str, Any] = {}
    if init is not None:
        from smplik.tracking.model_io import load_model

        start_model = load_model(init)
        net.load_state_dict(start_model.net.state_dict())
        previous = {k: start_model.info.get(k) for k in ("steps", "seconds", "val_mpjpe_mm")}
    else:
        xs = torch.cat([sampler.sample().x.flatten(0, 1) for _ in range(10)])
        net.x_mean.copy_(xs.mean(0))
        net.x_std.copy_(xs.std(0).clamp_min(1e-3))
    net.to(device)
    batches = batch_stream(make_sampler, cfg.seed + 1, cfg.workers) if cfg.workers > 0 else None
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    start = time.perf_counter()
    best, best_state, history, step = math.inf, None, [], 0
    if init is not None:  # a continued run never ends worse than the model it started from
        best, best_state = evaluate(net, val_batches), copy.deepcopy(net.state_dict())
        log(json.dumps({"step": 0, "val_mpjpe_mm": best}))
    budget = 60.0 * cfg.minutes
    while step < cfg.max_steps:
        frac = min(1.0, (time.perf_counter() - start) / budget)
        if frac >= 1.0:
            break
        for group in opt.param_groups:
            group["lr"] = cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * frac)))
        batch = next(batches) if batches is not None else sampler.sample()
        loss, terms = batch_loss(net, to_device(batch, device), cfg, fps, g)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        step += 1
        if step % cfg.validate_every == 0:
            val = evaluate(net, val_batches)
            history.append({"step": step, "seconds": round(time.perf_counter() - start, 1), "val_mpjpe_mm": val,
                            **{k: round(v, 4) for k, v in terms.items()}})
            log(json.dumps(history[-1]))
            if val < best:
                best, best_state = val, copy.deepcopy(net.state_dict())
    val = evaluate(net, val_batches)
    if val < best or best_state is None:
        best, best_state = val, copy.deepcopy(net.state_dict())
    net.load_state_dict(best_state)
    net.to("cpu")
    pose = train_data.pose.float()
    lo = torch.quantile(pose[::7].flatten(1), 0.001, dim=0).reshape(24, 3)
    hi = torch.quantile(pose[::7].flatten(1), 0.999, dim=0).reshape(24, 3)
    info = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "net": cfg.net.to_dict(),
            "train": {k: v for k, v in cfg.to_dict().items() if k != "net"}, "val_mpjpe_mm": best, "steps": step,
            "seconds": round(time.perf_counter() - start, 1), "history": history, "continued_from": previous or None}
    save_checkpoint(out, net, info, pose_lo=lo, pose_hi=hi)
    write_json_atomic(Path(out).with_suffix(".json"), info)
    return info
