"""``smplik train`` and ``smplik export-model``: CLI over :class:`smplik.train.TrainConfig`."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer()


@app.command("train")
def train_command(
    data: Annotated[Path, typer.Option("--data", help="Pose cache from `smplik data build`.")],
    out: Annotated[Path, typer.Option("--out", help="Run folder (checkpoint, config.json, metrics.csv).")],
    steps: Annotated[int, typer.Option(help="Total optimizer steps.")] = 20_000,
    batch_size: Annotated[int, typer.Option(help="Global batch size.")] = 512,
    lr: Annotated[float, typer.Option(help="Adam learning rate.")] = 1e-3,
    width: Annotated[int, typer.Option(help="Layer width d (paper: 1024).")] = 128,
    encoder_blocks: Annotated[int, typer.Option(help="Encoder blocks R.")] = 3,
    decoder_blocks: Annotated[int, typer.Option(help="Blocks per decoder.")] = 3,
    layers_per_block: Annotated[int, typer.Option(help="Layers per block L (paper: 3).")] = 2,
    paper_sizes: Annotated[bool, typer.Option("--paper-sizes", help="Use the paper's network sizes.")] = False,
    effector_slots: Annotated[bool, typer.Option(help="Also feed the decoders per-joint effector slots "
                                                 "(extension; off = the paper's architecture).")] = False,
    val_every: int = 500,
    ckpt_every: int = 500,
    seed: int = 0,
    model_dir: Annotated[Path | None, typer.Option(help="Folder with real SMPL files.")] = None,
    config: Annotated[Path | None, typer.Option(help="JSON TrainConfig to start from (flags override).")] = None,
    resume: Annotated[bool, typer.Option(help="Continue from RUN_DIR/checkpoint.pt if present.")] = True,
    threads: Annotated[int | None, typer.Option(help="torch intra-op threads.")] = None,
    init_from: Annotated[Path | None, typer.Option(help="Start from this model's weights (fine-tuning).")] = None,
) -> None:
    """Train SMPL-IK (ProtoRes) on a pose cache; resumable; works under torchrun (gloo)."""
    import torch

    from smplik.network import NetworkConfig
    from smplik.train import TrainConfig, train

    if threads:
        torch.set_num_threads(threads)
    base = TrainConfig.from_dict({"data": "", "out": "", **json.loads(config.read_text())}) if config else \
        TrainConfig(data="", out="")
    net = NetworkConfig.paper() if paper_sizes else NetworkConfig(
        width=width, encoder_blocks=encoder_blocks, decoder_blocks=decoder_blocks,
        layers_per_block=layers_per_block, embedding_dim=base.network.embedding_dim, dropout=base.network.dropout,
        effector_slots=effector_slots)
    cfg = replace(base, data=str(data), out=str(out), steps=steps, batch_size=batch_size, lr=lr, network=net,
                  val_every=val_every, ckpt_every=ckpt_every, seed=seed,
                  model_dir=str(model_dir) if model_dir else None,
                  init_from=str(init_from) if init_from else base.init_from)
    metrics = train(cfg, resume=resume)
    typer.echo(json.dumps({"run": str(out), **metrics}, indent=2))


@app.command("export-model")
def export_command(
    checkpoint: Annotated[Path, typer.Argument(help="Training checkpoint (RUN_DIR/checkpoint.pt); with only "
                                               "--onnx also an exported model file.")],
    out: Annotated[Path | None, typer.Option(
        "--out", help="Compact model file for `smplik solve --checkpoint`.")] = None,
    full_precision: bool = False,
    onnx: Annotated[Path | None, typer.Option("--onnx", help="Also (or only) write the network + FK as ONNX "
                                              "(opset 15, dynamic batch and effector count; needs smplik[fast]). "
                                              "With --out it is exported from that file's weights.")] = None,
) -> None:
    """Write a compact inference model (fp16 weights by default) from a training checkpoint, and/or its ONNX graph."""
    from smplik.train import export_model

    if out is None and onnx is None:
        typer.echo("error: nothing to write; give --out FILE.pt and/or --onnx FILE.onnx.", err=True)
        raise typer.Exit(2)
    if out is not None:
        export_model(checkpoint, out, half=not full_precision)
        typer.echo(f"wrote {out}")
    if onnx is not None:
        from smplik.onnx_runtime import OnnxUnavailableError, export_onnx
        from smplik.solver import IKSolver

        try:
            solver = IKSolver.load(out or checkpoint)
            export_onnx(solver.model, onnx, meta={"source": solver.source, "step": solver.meta.get("step"),
                                                  "body_fingerprint": solver.bodies.fingerprint})
        except (FileNotFoundError, ValueError, OnnxUnavailableError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from None
        typer.echo(f"wrote {onnx}")
