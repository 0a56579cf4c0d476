"""Training SMPL-IK (ProtoRes Algorithm 1), readable top to bottom.

``smplik train --data CACHE.npz --out RUN_DIR``; for data-parallel training on CPU run the same
command under ``torchrun --nproc_per_node K`` (gloo backend; no code change). Each checkpoint
(``RUN_DIR/checkpoint.pt``, written atomically) holds the model, optimizer, step and every RNG
state, so an interrupted run resumes exactly; ``RUN_DIR/config.json`` sits next to it.
"""

from __future__ import annotations

import csv
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist

from smplik.atomic import atomic_path, write_json_atomic
from smplik.body_model import BodyModelSet
from smplik.effectors import EffectorSamplingConfig, sample_effectors
from smplik.losses import LossConfig, protores_loss
from smplik.metrics import local_geodesic, mpjpe, pa_mpjpe
from smplik.network import NetworkConfig, ProtoResIK

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"
METRICS = "metrics.csv"


@dataclass(frozen=True)
class TrainConfig:
    """One training run."""

    data: str
    """Dataset cache written by ``smplik data build``."""
    out: str
    """Run folder: checkpoint, config, metrics.csv, loss_curve.png."""
    steps: int = 20_000
    """Optimizer steps in total (across resumes)."""
    batch_size: int = 512
    """Global batch size (split across torchrun processes)."""
    lr: float = 1e-3
    """Adam learning rate (paper: 2e-4 at batch 2048 on GPU; larger here for short CPU runs)."""
    lr_final_fraction: float = 0.05
    """Cosine decay from lr to lr * this fraction over ``steps``."""
    val_every: int = 500
    """Validate (and log) every this many steps."""
    ckpt_every: int = 500
    """Write the checkpoint every this many steps (and at the end or on Ctrl-C)."""
    val_size: int = 2048
    """Validation poses (fixed set, fixed effectors)."""
    seed: int = 0
    augment: bool = True
    """Random rotation about the vertical axis and left/right mirroring."""
    beta_noise: float = 1.0
    """Std of the Gaussian added to dataset betas (or of betas when the source has none)."""
    model_dir: str | None = None
    """Folder with real SMPL files (default: built-in model)."""
    init_from: str | None = None
    """Start a new run from this model's weights (a checkpoint or exported model; same network sizes)."""
    network: NetworkConfig = field(default_factory=NetworkConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    effectors: EffectorSamplingConfig = field(default_factory=EffectorSamplingConfig)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        nested = {"network": NetworkConfig, "loss": LossConfig, "effectors": EffectorSamplingConfig}
        kwargs = {f.name: d[f.name] for f in fields(cls) if f.name in d}
        for key, typ in nested.items():
            if key in kwargs and isinstance(kwargs[key], dict):
                kwargs[key] = typ(**kwargs[key])
        return cls(**kwargs)


def build_model(cfg: NetworkConfig, bodies: BodyModelSet) -> ProtoResIK:
    return ProtoResIK(cfg, bodies.J_template, bodies.J_dirs)


@torch.no_grad()
def evaluate(model: ProtoResIK, batch: Any, effectors: Any) -> dict[str, float]:
    """Validation metrics on a fixed batch: MPJPE / PA-MPJPE in mm, local geodesic in rad."""
    was_training = model.training
    model.eval()
    out = model(effectors, batch.betas, batch.gender)
    model.train(was_training)
    return {
        "mpjpe_mm": float(mpjpe(out.p_world, batch.p_world).mean() * 1000),
        "pa_mpjpe_mm": float(pa_mpjpe(out.p_world, batch.p_world).mean() * 1000),
        "geodesic_rad": float(local_geodesic(out.R_local, batch.R_local).mean()),
    }


def _distributed() -> tuple[int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("gloo")
    return (dist.get_rank(), world) if world > 1 else (0, 1)


def _save_checkpoint(path: Path, model: ProtoResIK, opt: torch.optim.Optimizer, step: int, cfg: TrainConfig,
                     gens: dict[str, torch.Generator], bodies: BodyModelSet, metrics: dict[str, float]) -> None:
    state = {
        "format": "smplik-checkpoint",
        "version": 1,
        "step": step,
        "config": cfg.to_dict(),
        "network": cfg.network.to_dict(),
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "rng": {name: g.get_state() for name, g in gens.items()} | {"torch": torch.get_rng_state()},
        "body_fingerprint": bodies.fingerprint,
        "metrics": metrics,
    }
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def _plot_curve(run: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(open(run / METRICS)))
    if not rows:
        return
    steps = [int(r["step"]) for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    axes[0].plot(steps, [float(r["loss"]) for r in rows], label="train loss")
    axes[0].set_yscale("log")
    axes[0].set_xlabel("step")
    axes[0].legend()
    axes[1].plot(steps, [float(r["mpjpe_mm"]) for r in rows], label="val MPJPE (mm)")
    axes[1].plot(steps, [float(r["pa_mpjpe_mm"]) for r in rows], label="val PA-MPJPE (mm)")
    axes[1].set_xlabel("step")
    axes[1].legend()
    fig.tight_layout()
    with atomic_path(run / "loss_curve.png", suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def train(cfg: TrainConfig, *, resume: bool = True, progress: bool = True,
          callback: Callable[[int, float], None] | None = None) -> dict[str, float]:
    """Train (or resume) a run; returns the last validation metrics.

    ``callback(step, loss)`` runs after every step (tests use it to interrupt a run).
    """
    from smplik.data.dataset import load_cache
    from smplik.data.sampler import PoseSampler

    rank, world = _distributed()
    run = Path(cfg.out)
    if rank == 0:
        run.mkdir(parents=True, exist_ok=True)
    bodies = BodyModelSet.load(cfg.model_dir)
    dataset = load_cache(cfg.data)
    train_set, val_set = dataset.subset("train"), dataset.subset("validation")

    torch.manual_seed(cfg.seed + rank)
    model = build_model(cfg.network, bodies)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    gens = {"poses": torch.Generator().manual_seed(cfg.seed * 1000 + 2 * rank),
            "effectors": torch.Generator().manual_seed(cfg.seed * 1000 + 2 * rank + 1)}
    step, metrics = 0, {}
    ckpt_path = run / CHECKPOINT
    if cfg.init_from and not (resume and ckpt_path.exists()):
        init_model, init_meta = load_model(cfg.init_from)
        if NetworkConfig(**init_meta["network"]) != cfg.network:
            raise ValueError(f"--init-from {cfg.init_from}: network sizes {init_meta['network']} differ from this "
                             f"run's {cfg.network.to_dict()}.")
        model.load_state_dict(init_model.state_dict())
    if resume and ckpt_path.exists():
        state = torch.load(ckpt_path, map_location="cpu", weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        for name, g in gens.items():
            g.set_state(state["rng"][name])
        torch.set_rng_state(state["rng"]["torch"])
        step, metrics = state["step"], state.get("metrics", {})
    net: torch.nn.Module = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(model)

    per_rank = max(1, cfg.batch_size // world)
    sampler = PoseSampler(train_set, bodies, batch_size=per_rank, generator=gens["poses"], augment=cfg.augment,
                          beta_noise=cfg.beta_noise)
    val_gen = torch.Generator().manual_seed(12345)
    val_batch = PoseSampler(val_set, bodies, batch_size=cfg.val_size, generator=val_gen, augment=False,
                            beta_noise=cfg.beta_noise).sample()
    val_eff = sample_effectors(val_batch.p_world, val_batch.R_world,
                               replace(cfg.effectors, sigma_max=0.0), val_gen).effectors
    if rank == 0:
        write_json_atomic(run / CONFIG, cfg.to_dict())
        if not (run / METRICS).exists():
            with atomic_path(run / METRICS) as tmp:
                tmp.write_text("step,loss,mpjpe_mm,pa_mpjpe_mm,geodesic_rad,samples_per_s\n")

    def lr_at(s: int) -> float:
        t = min(s / max(cfg.steps, 1), 1.0)
        return cfg.lr * (cfg.lr_final_fraction + (1 - cfg.lr_final_fraction) * 0.5 * (1 + torch.cos(torch.tensor(
            t * torch.pi)).item()))

    bar = None
    if progress and rank == 0:
        from tqdm import tqdm

        bar = tqdm(total=cfg.steps, initial=step, desc="train", dynamic_ncols=True)
    t_last, n_last, loss_avg = time.perf_counter(), 0, float("nan")
    model.train()
    try:
        while step < cfg.steps:
            batch = sampler.sample()
            sampled = sample_effectors(batch.p_world, batch.R_world, cfg.effectors, gens["effectors"])
            out = net(sampled.effectors, batch.betas, batch.gender)
            loss, _ = protores_loss(out, batch.R_local, batch.R_world, batch.p_world, sampled.effectors,
                                    sampled.weight, cfg.loss)
            for group in opt.param_groups:
                group["lr"] = lr_at(step)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            n_last += per_rank * world
            loss_avg = loss.item() if loss_avg != loss_avg else 0.95 * loss_avg + 0.05 * loss.item()
            if bar is not None:
                bar.update(1)
            if rank == 0 and (step % cfg.val_every == 0 or step == cfg.steps):
                rate = n_last / (time.perf_counter() - t_last)
                t_last, n_last = time.perf_counter(), 0
                metrics = evaluate(model, val_batch, val_eff)
                with open(run / METRICS, "a") as fh:
                    fh.write(f"{step},{loss_avg:.6f},{metrics['mpjpe_mm']:.3f},{metrics['pa_mpjpe_mm']:.3f},"
                             f"{metrics['geodesic_rad']:.5f},{rate:.1f}\n")
                if bar is not None:
                    bar.set_postfix(loss=f"{loss_avg:.4f}", mpjpe=f"{metrics['mpjpe_mm']:.1f}mm",
                                    samples_s=f"{rate:.0f}")
                _plot_curve(run)
            if rank == 0 and (step % cfg.ckpt_every == 0 or step == cfg.steps):
                _save_checkpoint(ckpt_path, model, opt, step, cfg, gens, bodies, metrics)
            if callback is not None:
                callback(step, loss.item())
    except KeyboardInterrupt:
        if rank == 0:
            _save_checkpoint(ckpt_path, model, opt, step, cfg, gens, bodies, metrics)
        raise
    finally:
        if bar is not None:
            bar.close()
    if world > 1:
        dist.barrier()
    return metrics


def export_model(checkpoint: str | Path, out: str | Path, *, half: bool = True) -> Path:
    """Write a compact inference file (config + weights, fp16 by default) from a training checkpoint."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    weights = {k: (v.half() if half and v.is_floating_point() and not k.startswith(("J_", "identity"))
                   else v) for k, v in state["model"].items()}
    slim = {"format": "smplik-model", "version": 1, "network": state["network"], "model": weights,
            "body_fingerprint": state["body_fingerprint"], "metrics": state.get("metrics", {}),
            "step": state["step"], "train_config": state["config"]}
    with atomic_path(out) as tmp:
        torch.save(slim, tmp)
    return Path(out)


def load_model(path: str | Path) -> tuple[ProtoResIK, dict[str, Any]]:
    """Load a model from a training checkpoint or an exported model file (float32, eval mode)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Model file not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises several types for corrupt files
        raise ValueError(f"{path}: not a readable smplik model ({exc}).") from exc
    if not isinstance(state, dict) or state.get("format") not in {"smplik-model", "smplik-checkpoint"}:
        raise ValueError(f"{path}: not an smplik model or checkpoint (missing 'format').")
    cfg = NetworkConfig(**state["network"])
    weights = {k: v.float() if v.is_floating_point() else v for k, v in state["model"].items()}
    model = ProtoResIK(cfg, weights["J_template"], weights["J_dirs"])
    model.load_state_dict(weights)
    model.eval()
    return model, {k: v for k, v in state.items() if k not in {"model", "optimizer", "rng"}}

