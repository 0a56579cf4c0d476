"""Training SMPL-IK (ProtoRes Algorithm 1), readable top to bottom.

``smplik train --data CACHE.npz --out RUN_DIR``; for data-parallel training on CPU run the same
command under ``torchrun --nproc_per_node K`` (gloo backend; no code change). Each checkpoint
(``RUN_DIR/checkpoint.pt``, written atomically in the safe format of :mod:`smplik.model_io`) holds
the model, optimizer, step, loss average and every RNG state (torch, numpy, python, the samplers'),
so an interrupted run resumes exactly; ``RUN_DIR/config.json`` sits next to it.

Interrupts: Ctrl-C (SIGINT) never cuts a step in half. The first one lets the current step
finish, writes the checkpoint and raises :class:`TrainingInterrupted` ("checkpoint saved at step
N"); a second one stops at once and drops the unfinished step (the last checkpoint on disk is the
resume point). Either way rerunning the command gives bit for bit the run that was never stopped.
On resume ``metrics.csv`` is cut back to the checkpoint's step, so it never holds a step twice.
"""

from __future__ import annotations

import contextlib
import csv
import os
import random
import signal
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist

from smplik.atomic import atomic_path, write_json_atomic, write_text_atomic
from smplik.body_model import BodyModelSet
from smplik.configs import PRECISIONS, TRAIN_RANGES, TrainConfig  # noqa: F401 - re-exported
from smplik.data.effector_sampling import sample_effectors
from smplik.losses import distillation_loss, protores_loss
from smplik.metrics import local_geodesic, mpjpe, pa_mpjpe
from smplik.model_io import CHECKPOINT_FORMAT, FORMAT_VERSION, load_checkpoint, load_model, write_model_file
from smplik.network import IKOutput, NetworkConfig, ProtoResIK

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"
METRICS = "metrics.csv"
METRIC_COLUMNS = ("step", "loss", "mpjpe_mm", "pa_mpjpe_mm", "geodesic_rad", "samples_per_s")


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped by Ctrl-C. ``step``: the step of the checkpoint on disk (None: none yet);
    ``dropped``: a second Ctrl-C stopped a step half-way and it was dropped."""

    def __init__(self, step: int | None, *, dropped: bool = False) -> None:
        self.step, self.dropped = step, dropped
        if dropped:
            message = (f"stopped mid-step; the step was dropped and the checkpoint at step {step} is the resume point"
                       if step is not None else "stopped mid-step before the first checkpoint; nothing saved")
        else:
            message = f"checkpoint saved at step {step}" if step is not None else "interrupted; nothing saved"
        super().__init__(message)


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


def _distributed() -> tuple[int, int, bool]:
    """``(rank, world size, whether this call created the process group)``."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    created = world > 1 and not dist.is_initialized()
    if created:
        dist.init_process_group("gloo")
    return (dist.get_rank(), world, created) if world > 1 else (0, 1, False)


# ----------------------------------------------------------------------------- RNG states as plain data


def _rng_state(gens: dict[str, torch.Generator]) -> dict[str, Any]:
    """Every RNG state as tensors and numbers (readable by :func:`smplik.model_io.read_torch_file`, weights only)."""
    np_kind, np_key, np_pos, np_has_gauss, np_gauss = np.random.get_state()
    py_version, py_state, py_gauss = random.getstate()
    return {**{name: g.get_state() for name, g in gens.items()}, "torch": torch.get_rng_state(),
            "numpy": {"kind": str(np_kind), "key": torch.from_numpy(np_key.astype(np.int64)), "pos": int(np_pos),
                      "has_gauss": int(np_has_gauss), "cached_gaussian": float(np_gauss)},
            "python": {"version": int(py_version), "state": torch.tensor(py_state, dtype=torch.int64),
                       "gauss_next": py_gauss}}


def _set_rng_state(rng: dict[str, Any], gens: dict[str, torch.Generator]) -> None:
    for name, g in gens.items():
        g.set_state(rng[name])
    torch.set_rng_state(rng["torch"])
    if "numpy" in rng:  # format version 1 checkpoints have torch states only
        n = rng["numpy"]
        np.random.set_state((n["kind"], n["key"].numpy().astype(np.uint32), n["pos"], n["has_gauss"],
                             n["cached_gaussian"]))
    if "python" in rng:
        p = rng["python"]
        random.setstate((p["version"], tuple(int(x) for x in p["state"].tolist()), p["gauss_next"]))


def _save_checkpoint(path: Path, model: ProtoResIK, opt: torch.optim.Optimizer, step: int, cfg: TrainConfig,
                     gens: dict[str, torch.Generator], bodies: BodyModelSet, metrics: dict[str, float],
                     loss_ema: float) -> None:
    write_model_file(path, {
        "format": CHECKPOINT_FORMAT,
        "version": FORMAT_VERSION,
        "step": step,
        "config": cfg.to_dict(),
        "network": cfg.network.to_dict(),
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "rng": _rng_state(gens),
        "body_fingerprint": bodies.fingerprint,
        "metrics": metrics,
        "loss_ema": loss_ema,
    })


# ----------------------------------------------------------------------------- metrics.csv


def _read_metric_rows(path: Path, up_to: int) -> list[str]:
    """The rows of ``metrics.csv`` up to step ``up_to``, each step once (later duplicates and partial
    lines from a kill are dropped)."""
    if not path.is_file():
        return []
    rows, last = [], 0
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines()[1:]:
        cells = line.split(",")
        if len(cells) != len(METRIC_COLUMNS) or not cells[0].isdigit():
            continue
        step = int(cells[0])
        if last < step <= up_to:
            rows.append(line)
            last = step
    return rows


def progress_postfix(loss: float, mpjpe_mm: float, samples_per_s: float) -> dict[str, str]:
    """The training progress bar's fields; a metric not measured yet (NaN: no evaluation so far, or no
    validation split) shows as ``-``, never ``nanmm``."""

    def shown(value: float, fmt: str, unit: str = "") -> str:
        return "-" if value != value else f"{value:{fmt}}{unit}"

    return {"loss": shown(loss, ".4f"), "mpjpe": shown(mpjpe_mm, ".1f", "mm"), "samples_s": shown(samples_per_s, ".0f")}


def _write_metric_rows(path: Path, rows: list[str]) -> None:
    write_text_atomic(path, ",".join(METRIC_COLUMNS) + "\n" + "".join(r + "\n" for r in rows))


def _plot_curve(run: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(run / METRICS, newline="") as fh:
        rows = list(csv.DictReader(fh))
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


# ----------------------------------------------------------------------------- interrupts


class _InterruptFlag:
    requested = False


@contextlib.contextmanager
def _deferred_sigint() -> Iterator[_InterruptFlag]:
    """While active, the first SIGINT only sets ``flag.requested`` (checked between steps); the
    handler then steps aside, so a second SIGINT raises ``KeyboardInterrupt`` at once."""
    flag = _InterruptFlag()
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or previous in (signal.SIG_IGN, None):
        yield flag  # signals are delivered to the main thread only; an ignored SIGINT stays ignored
        return

    def on_sigint(signum: int, frame: Any) -> None:
        flag.requested = True
        signal.signal(signal.SIGINT, previous)

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, previous)


def _any_rank(flag: bool, world: int) -> bool:
    if world == 1:
        return flag
    t = torch.tensor([int(flag)])
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return bool(t.item())


# ----------------------------------------------------------------------------- the loop


def _load_teacher(cfg: TrainConfig) -> Callable[..., IKOutput] | None:
    """``cfg.distill_from``'s ensemble as a function of (effectors, betas, gender), without gradients;
    None without a teacher."""
    if not cfg.distill_from:
        return None
    from smplik.ensemble import EnsembleConfig, run_ensemble
    from smplik.onnx_runtime import select_network
    from smplik.refine import DEFAULT_REFINEMENT, RefineConfig, refine_output

    ensemble = EnsembleConfig.parse(cfg.distill_ensemble)
    teacher, meta = load_model(cfg.distill_from)
    teacher.requires_grad_(False)
    refine = RefineConfig(iterations=0)
    if cfg.distill_refine:
        refine = DEFAULT_REFINEMENT if meta.get("refine") is None else \
            RefineConfig.from_dict(meta["refine"], f"{cfg.distill_from}: key 'refine'")
    # onnxruntime runs the teacher (its K * B rows) about twice as fast when its graph lies beside it
    network = select_network("auto", teacher, cfg.distill_from, threads=torch.get_num_threads()) or teacher

    def answer(eff: Any, betas: torch.Tensor, gender: torch.Tensor) -> IKOutput:
        with torch.no_grad():
            J_rest = teacher.rest_joints(betas, gender)
            return refine_output(run_ensemble(network, eff, betas, gender, J_rest, ensemble), J_rest, eff, refine)

    return answer


def _train_val_sets(cfg: TrainConfig) -> tuple[Any, Any]:
    """The cache's train and validation frames (validation held out from train clips by ``val_fraction``)."""
    from smplik.data.dataset import load_cache

    dataset = load_cache(cfg.data)
    train_set, val_set = dataset.subset("train"), dataset.subset("validation")
    if not 0.0 <= cfg.val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {cfg.val_fraction}.")
    if cfg.val_fraction > 0:
        if len(val_set):
            raise ValueError(f"{cfg.data} has {len(val_set)} validation frames; val_fraction (--val-fraction) is "
                             "for caches without a validation split: leave it at 0.")
        train_set, val_set = train_set.hold_out_clips(cfg.val_fraction, cfg.seed)
    if not len(train_set):
        raise ValueError(f"{cfg.data} has no train frames; rebuild it with train clips (`smplik data build` "
                         "puts every clip in train when no --split is given).")
    if not len(val_set):
        warnings.warn(f"{cfg.data} has no validation frames: validation is skipped (metrics.csv logs the loss "
                      "only); --val-fraction F holds out a fraction F of the train clips instead.", stacklevel=3)
    return train_set, val_set


def train(cfg: TrainConfig, *, resume: bool = True, progress: bool = True,
          callback: Callable[[int, float], None] | None = None) -> dict[str, float]:
    """Train (or resume) a run; returns the last validation metrics (empty without validation).

    ``callback(step, loss)`` runs after every finished step (tests use it to interrupt a run).

    Raises:
        TrainingInterrupted: on Ctrl-C (see the module docstring), after saving the checkpoint.
        CheckpointError: ``--init-from`` or the run's checkpoint is not a safe smplik model file.
        ValueError: a bad config or cache; ``init_from`` with other network sizes.
    """
    with _deferred_sigint() as interrupt:
        try:
            return _train(cfg, interrupt, resume=resume, progress=progress, callback=callback)
        except TrainingInterrupted:
            raise
        except KeyboardInterrupt:  # a second Ctrl-C while setting up: nothing was written
            raise TrainingInterrupted(None) from None


def _train(cfg: TrainConfig, interrupt: _InterruptFlag, *, resume: bool, progress: bool,
           callback: Callable[[int, float], None] | None) -> dict[str, float]:
    from smplik.configs import check_network_memory
    from smplik.data.sampler import PoseSampler

    # the memory these sizes imply at this batch (weights, gradients, Adam, kept activations), before anything
    # is allocated or written: every size may be inside its range while their product is not
    check_network_memory(cfg.network, "training config", batch=cfg.batch_size, tokens=cfg.effectors.max_effectors,
                         training=True)
    rank, world, own_group = _distributed()
    run = Path(cfg.out)
    if rank == 0:
        run.mkdir(parents=True, exist_ok=True)
    bodies = BodyModelSet.load(cfg.model_dir)
    train_set, val_set = _train_val_sets(cfg)

    if cfg.precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {cfg.precision!r}.")
    if not cfg.distill_weight >= 0:
        raise ValueError(f"distill_weight must be >= 0, got {cfg.distill_weight}.")
    teacher = _load_teacher(cfg)
    torch.manual_seed(cfg.seed + rank)
    model = build_model(cfg.network, bodies)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    gens = {"poses": torch.Generator().manual_seed(cfg.seed * 1000 + 2 * rank),
            "effectors": torch.Generator().manual_seed(cfg.seed * 1000 + 2 * rank + 1)}
    step, metrics, loss_avg = 0, {}, float("nan")
    ckpt_path = run / CHECKPOINT
    resuming = resume and ckpt_path.exists()
    if cfg.init_from and not resuming:
        init_model, init_meta = load_model(cfg.init_from)
        if NetworkConfig(**init_meta["network"]) != cfg.network:
            raise ValueError(f"--init-from {cfg.init_from}: network sizes {init_meta['network']} differ from this "
                             f"run's {cfg.network.to_dict()}.")
        model.load_state_dict(init_model.state_dict())
    if resuming:
        state = load_checkpoint(ckpt_path)
        if NetworkConfig(**state["network"]) != cfg.network:
            raise ValueError(f"{ckpt_path}: the run was trained with network sizes {state['network']}, this config "
                             f"has {cfg.network.to_dict()}; give the same sizes, another --out, or --no-resume.")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        _set_rng_state(state["rng"], gens)
        step, metrics = state["step"], state.get("metrics", {})
        loss_avg = float(state.get("loss_ema", float("nan")))
    saved_step = step if resuming else None
    net: torch.nn.Module = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(model)

    per_rank = max(1, cfg.batch_size // world)
    sampler = PoseSampler(train_set, bodies, batch_size=per_rank, generator=gens["poses"], augment=cfg.augment,
                          beta_noise=cfg.beta_noise, part_swap=cfg.part_swap)
    val_batch = val_eff = None
    if len(val_set):
        val_gen = torch.Generator().manual_seed(12345)
        val_batch = PoseSampler(val_set, bodies, batch_size=cfg.val_size, generator=val_gen, augment=False,
                                beta_noise=cfg.beta_noise).sample()
        # exact effectors in the paper's layout, whatever the run's sampling options: curves compare across runs
        val_eff = sample_effectors(val_batch.p_world, val_batch.R_world,
                                   replace(cfg.effectors, sigma_max=0.0, limb_first=0.0), val_gen).effectors
    rows: list[str] = []
    if rank == 0:
        write_json_atomic(run / CONFIG, cfg.to_dict())
        rows = _read_metric_rows(run / METRICS, up_to=step)  # a resume never repeats a step
        _write_metric_rows(run / METRICS, rows)

    def lr_at(s: int) -> float:
        t = min(s / max(cfg.steps, 1), 1.0)
        return cfg.lr * (cfg.lr_final_fraction + (1 - cfg.lr_final_fraction) * 0.5 * (1 + torch.cos(torch.tensor(
            t * torch.pi)).item()))

    bar = None
    if progress and rank == 0:
        from tqdm import tqdm

        bar = tqdm(total=cfg.steps, initial=step, desc="train", dynamic_ncols=True)
    t_last, n_last = time.perf_counter(), 0
    model.train()
    whole = True  # the state is a finished step's (False while a step runs)
    try:
        while step < cfg.steps:
            if _any_rank(interrupt.requested, world):  # Ctrl-C during the last step or the setup
                raise KeyboardInterrupt
            whole = False
            batch = sampler.sample()
            sampled = sample_effectors(batch.p_world, batch.R_world, cfg.effectors, gens["effectors"])
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=cfg.precision == "bf16"):
                out = net(sampled.effectors, batch.betas, batch.gender)
            loss, _ = protores_loss(out, batch.R_local, batch.R_world, batch.p_world, sampled.effectors,
                                    sampled.weight, cfg.loss)
            if teacher is not None:
                loss = loss + cfg.distill_weight * distillation_loss(
                    out, teacher(sampled.effectors, batch.betas, batch.gender), cfg.loss)
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
                if val_batch is not None:
                    metrics = evaluate(model, val_batch, val_eff)
                shown = [metrics.get(k, float("nan")) for k in ("mpjpe_mm", "pa_mpjpe_mm", "geodesic_rad")]
                rows.append(f"{step},{loss_avg:.6f},{shown[0]:.3f},{shown[1]:.3f},{shown[2]:.5f},{rate:.1f}")
                _write_metric_rows(run / METRICS, rows)
                if bar is not None:
                    bar.set_postfix(progress_postfix(loss_avg, shown[0], rate))
                _plot_curve(run)
            if rank == 0 and (step % cfg.ckpt_every == 0 or step == cfg.steps):
                _save_checkpoint(ckpt_path, model, opt, step, cfg, gens, bodies, metrics, loss_avg)
                saved_step = step
            whole = True
            if callback is not None:
                callback(step, loss.item())
    except KeyboardInterrupt:
        # Between steps the state is whole: save it. Mid-step (a second Ctrl-C) it is not: drop the
        # step; the checkpoint on disk is the resume point.
        if not whole:
            raise TrainingInterrupted(saved_step, dropped=True) from None
        if rank == 0 and saved_step != step:
            _save_checkpoint(ckpt_path, model, opt, step, cfg, gens, bodies, metrics, loss_avg)
        raise TrainingInterrupted(step) from None
    finally:
        if bar is not None:
            bar.close()
    if world > 1:
        dist.barrier()
        if own_group:  # a clean shutdown: no rank tears down connections another still uses
            dist.destroy_process_group()
    return metrics
