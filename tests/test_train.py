"""Training loop: exact resume after interruption, artefacts, and 2-process torchrun on CPU."""

import json
import os
import subprocess
import sys
from dataclasses import replace

import pytest
import torch

from smplik.network import NetworkConfig
from smplik.train import TrainConfig, export_model, load_model, train

TINY = NetworkConfig(width=32, encoder_blocks=2, decoder_blocks=1, layers_per_block=1)


def config(cache, out, **kw):
    base = TrainConfig(data=str(cache), out=str(out), steps=6, batch_size=16, val_every=3, ckpt_every=3,
                       val_size=32, network=replace(TINY, dropout=0.1))
    return replace(base, **kw)


def test_interrupted_then_resumed_run_matches_uninterrupted(tiny_cache, tmp_path):
    full = config(tiny_cache, tmp_path / "full")
    train(full, progress=False)

    def interrupt(step, loss):
        if step == 4:
            raise KeyboardInterrupt

    part = config(tiny_cache, tmp_path / "part")
    with pytest.raises(KeyboardInterrupt):
        train(part, progress=False, callback=interrupt)
    assert torch.load(tmp_path / "part" / "checkpoint.pt", weights_only=False)["step"] == 4
    train(part, progress=False)
    a = torch.load(tmp_path / "full" / "checkpoint.pt", weights_only=False)
    b = torch.load(tmp_path / "part" / "checkpoint.pt", weights_only=False)
    assert a["step"] == b["step"] == 6
    for key in a["model"]:
        assert torch.equal(a["model"][key], b["model"][key]), key


def test_run_folder_artefacts_and_export(tiny_cache, tmp_path):
    run = tmp_path / "run"
    metrics = train(config(tiny_cache, run), progress=False)
    assert {"mpjpe_mm", "pa_mpjpe_mm", "geodesic_rad"} <= set(metrics)
    saved = json.loads((run / "config.json").read_text())
    assert saved["network"]["width"] == 32 and saved["steps"] == 6
    rows = (run / "metrics.csv").read_text().strip().splitlines()
    assert rows[0].startswith("step,loss,mpjpe_mm") and len(rows) == 3
    assert (run / "loss_curve.png").stat().st_size > 0
    assert not [p for p in run.iterdir() if ".tmp" in p.name]
    exported = export_model(run / "checkpoint.pt", tmp_path / "model.pt")
    model, meta = load_model(exported)
    assert meta["network"]["width"] == 32 and not model.training


def test_torchrun_two_processes_on_cpu(tiny_cache, tmp_path):
    run = tmp_path / "ddp"
    cfg = config(tiny_cache, run, steps=3, ckpt_every=3, val_every=3)
    (tmp_path / "cfg.json").write_text(json.dumps(cfg.to_dict()))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--standalone",
           "-m", "smplik.cli", "train", "--data", str(tiny_cache), "--out", str(run), "--config",
           str(tmp_path / "cfg.json"), "--steps", "3", "--batch-size", "16", "--width", "32",
           "--encoder-blocks", "2", "--decoder-blocks", "1", "--layers-per-block", "1", "--val-every", "3",
           "--ckpt-every", "3"]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    assert state["step"] == 3


def test_init_from_starts_from_given_weights(tiny_cache, tmp_path):
    first = config(tiny_cache, tmp_path / "a", steps=3)
    train(first, progress=False)
    # a 1-step run with lr 0 keeps exactly the weights it started from
    third = config(tiny_cache, tmp_path / "c", steps=1, lr=0.0, init_from=str(tmp_path / "a" / "checkpoint.pt"))
    train(third, progress=False)
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["model"]
    c = torch.load(tmp_path / "c" / "checkpoint.pt", weights_only=False)["model"]
    assert all(torch.equal(a[k], c[k]) for k in a)
    bad = config(tiny_cache, tmp_path / "d", init_from=str(tmp_path / "a" / "checkpoint.pt"),
                 network=replace(TINY, width=48))
    with pytest.raises(ValueError, match="network sizes"):
        train(bad, progress=False)


def test_shipped_recipe_configs_parse():
    """The fine-tuning configs of the shipped model's recipe (README) load as TrainConfig overrides."""
    import json
    from pathlib import Path

    from smplik.train import TrainConfig

    root = Path(__file__).resolve().parents[1] / "configs"
    cfgs = {n: TrainConfig.from_dict({"data": "", "out": "", **json.loads((root / f"shipped_{n}.json").read_text())})
            for n in ("ft1", "ft2")}
    assert (cfgs["ft1"].loss.w_rot_local, cfgs["ft2"].loss.w_rot_local) == (2.0, 4.0)
    for cfg in cfgs.values():
        assert cfg.loss.w_pos_rnd == 1000.0 and cfg.effectors.eta == 4.0 and cfg.effectors.max_effectors == 16
