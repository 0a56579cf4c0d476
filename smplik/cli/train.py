"""``smplik train``: CLI over :class:`smplik.train.TrainConfig` (``export-model`` and ``average-models``:
:mod:`smplik.cli.models`).

Precedence: ``TrainConfig``'s defaults, then the ``--config`` file, then the flags actually given.
Every option defaults to "unset" (None), so a flag overrides the file only when it is on the
command line; the defaults shown in ``--help`` are read from the config dataclasses.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import fields, replace
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from smplik.configs import EffectorSamplingConfig, NetworkConfig

console = Console(stderr=True, soft_wrap=True)  # status lines are never cut mid-number


def _default(name: str, cls: type | None = None) -> str:
    """The dataclass default of field ``name`` (of TrainConfig, or ``cls``), for the help text."""
    from smplik.configs import TrainConfig

    value = {f.name: f.default for f in fields(cls or TrainConfig)}[name]
    return f"default {value}"


def _fail(message: str, code: int = 1) -> typer.Exit:
    console.print(f"[red]error:[/red] {escape(message)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)


def _net(help: str, name: str) -> Any:
    return typer.Option(help=f"{help} ({_default(name, NetworkConfig)}).")


def train_command(
    data: Annotated[Path | None, typer.Option("--data", help="Pose cache from `smplik data build` (or 'data' in "
                                              "--config).")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Run folder: checkpoint, config.json, metrics.csv "
                                             "(or 'out' in --config).")] = None,
    config: Annotated[Path | None, typer.Option(help="JSON TrainConfig (partial: e.g. {\"loss\": {...}}); flags "
                                                "given on the command line override it.")] = None,
    steps: Annotated[int | None, typer.Option(help=f"Total optimizer steps ({_default('steps')}).")] = None,
    batch_size: Annotated[int | None, typer.Option(help=f"Global batch size ({_default('batch_size')}).")] = None,
    lr: Annotated[float | None, typer.Option(help=f"Adam learning rate ({_default('lr')}).")] = None,
    lr_final_fraction: Annotated[float | None, typer.Option(help="Cosine decay to lr * this "
                                                            f"({_default('lr_final_fraction')}).")] = None,
    width: Annotated[int | None, _net("Layer width d (paper: 1024)", "width")] = None,
    encoder_blocks: Annotated[int | None, _net("Encoder blocks R", "encoder_blocks")] = None,
    decoder_blocks: Annotated[int | None, _net("Blocks per decoder", "decoder_blocks")] = None,
    layers_per_block: Annotated[int | None, _net("Layers per block L (paper: 3)", "layers_per_block")] = None,
    embedding_dim: Annotated[int | None, _net("Joint-id and type embedding size", "embedding_dim")] = None,
    dropout: Annotated[float | None, _net("Dropout after each hidden layer", "dropout")] = None,
    paper_sizes: Annotated[bool, typer.Option("--paper-sizes", help="Start from the paper's network sizes "
                                              "(size flags still override).")] = False,
    effector_slots: Annotated[bool | None, typer.Option(
        "--effector-slots/--no-effector-slots", help="Also feed the decoders per-joint effector slots (extension; "
        f"off = the paper's architecture) ({_default('effector_slots', NetworkConfig)}).")] = None,
    val_every: Annotated[int | None, typer.Option(help=f"Validate every N steps ({_default('val_every')}).")] = None,
    ckpt_every: Annotated[int | None, typer.Option(help=f"Checkpoint every N steps ({_default('ckpt_every')}).")
                          ] = None,
    val_size: Annotated[int | None, typer.Option(help=f"Validation poses ({_default('val_size')}).")] = None,
    val_fraction: Annotated[float | None, typer.Option(help="For a cache without validation frames: hold out "
                                                       "this fraction of the train clips "
                                                       f"({_default('val_fraction')}: skip validation).")] = None,
    seed: Annotated[int | None, typer.Option(help=f"Seed ({_default('seed')}).")] = None,
    augment: Annotated[bool | None, typer.Option("--augment/--no-augment", help="Vertical rotation and mirroring "
                                                 f"({_default('augment')}).")] = None,
    beta_noise: Annotated[float | None, typer.Option(help=f"Std of the beta noise ({_default('beta_noise')}).")
                          ] = None,
    part_swap: Annotated[float | None, typer.Option(help="Probability per limb that its local rotations come from "
                                                    f"another random frame ({_default('part_swap')}: off).")] = None,
    limb_first: Annotated[float | None, typer.Option(help="Fraction of samples whose first four effectors are "
                                                     "positions, one per limb ("
                                                     f"{_default('limb_first', EffectorSamplingConfig)}: the paper's "
                                                     "sampling).")] = None,
    model_dir: Annotated[Path | None, typer.Option(help="Folder with real SMPL files.")] = None,
    init_from: Annotated[Path | None, typer.Option(help="Start from this model's weights (fine-tuning).")] = None,
    precision: Annotated[str | None, typer.Option(help="fp32, or bf16: the layers under autocast in bfloat16 "
                                                  "(several times faster on CPUs with AMX; FK and loss stay "
                                                  f"float32) ({_default('precision')}).")] = None,
    distill_from: Annotated[Path | None, typer.Option(help="Teacher model: also pull the network towards its "
                                                      "test-time ensemble answer (self-distillation).")] = None,
    distill_weight: Annotated[float | None, typer.Option(help="Weight of the distillation term "
                                                         f"({_default('distill_weight')}).")] = None,
    distill_ensemble: Annotated[str | None, typer.Option(help="The teacher's ensemble, e.g. mirror+yaw4 "
                                                         f"({_default('distill_ensemble')}).")] = None,
    distill_refine: Annotated[bool | None, typer.Option(
        "--distill-refine/--no-distill-refine", help="The teacher's answer also goes through its solver "
        f"refinement ({_default('distill_refine')}).")] = None,
    resume: Annotated[bool, typer.Option(help="Continue from RUN_DIR/checkpoint.pt if present.")] = True,
    threads: Annotated[int | None, typer.Option(min=1, help="torch intra-op threads (default: torch's; on a busy "
                                                "machine 1 can be several times faster).")] = None,
) -> None:
    """Train SMPL-IK (ProtoRes) on a pose cache; resumable; works under torchrun (gloo)."""
    import torch

    from smplik.configs import TrainConfig
    from smplik.model_io import CheckpointError
    from smplik.train import TrainingInterrupted, train

    if threads:
        torch.set_num_threads(threads)
    try:
        base = TrainConfig.from_file(config, data="", out="") if config else TrainConfig(data="", out="")
    except (FileNotFoundError, ValueError) as exc:
        raise _fail(str(exc)) from None
    given = {"data": data, "out": out, "steps": steps, "batch_size": batch_size, "lr": lr,
             "lr_final_fraction": lr_final_fraction, "val_every": val_every, "ckpt_every": ckpt_every,
             "val_size": val_size, "val_fraction": val_fraction, "seed": seed, "augment": augment,
             "beta_noise": beta_noise, "part_swap": part_swap, "model_dir": model_dir, "init_from": init_from,
             "precision": precision,
             "distill_from": distill_from, "distill_weight": distill_weight, "distill_ensemble": distill_ensemble,
             "distill_refine": distill_refine}
    top = {k: str(v) if isinstance(v, Path) else v for k, v in given.items() if v is not None}
    net = base.network
    if paper_sizes:
        net = replace(net, **{k: v for k, v in NetworkConfig.paper().to_dict().items() if k != "effector_slots"})
    net_given = {"width": width, "encoder_blocks": encoder_blocks, "decoder_blocks": decoder_blocks,
                 "layers_per_block": layers_per_block, "embedding_dim": embedding_dim, "dropout": dropout,
                 "effector_slots": effector_slots}
    net = replace(net, **{k: v for k, v in net_given.items() if v is not None})
    effectors = base.effectors if limb_first is None else replace(base.effectors, limb_first=limb_first)
    cfg = replace(base, **top, network=net, effectors=effectors)
    for key in ("data", "out"):
        if not getattr(cfg, key):
            raise _fail(f"--{key} is required (or '{key}' in the --config file).")

    def notice(message: Any, *args: Any, **kwargs: Any) -> None:
        console.print(f"notice: {escape(str(message))}", highlight=False, soft_wrap=True)

    with warnings.catch_warnings():
        warnings.simplefilter("always", UserWarning)
        warnings.showwarning = notice
        try:
            metrics = train(cfg, resume=resume)
        except TrainingInterrupted as exc:
            console.print(str(exc), highlight=False)
            raise typer.Exit(130) from None
        except (FileNotFoundError, CheckpointError, ValueError) as exc:
            raise _fail(str(exc)) from None
    typer.echo(json.dumps({"run": cfg.out, **metrics}, indent=2))
