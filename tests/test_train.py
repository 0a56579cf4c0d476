"""Training loop: exact resume after interruption (also a real SIGINT), metrics.csv, config precedence,
caches without validation frames, artefacts, and 2-process torchrun on CPU."""

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from smplik.model_io import export_model, load_model
from smplik.network import NetworkConfig
from smplik.train import TrainConfig, TrainingInterrupted, train

TINY = NetworkConfig(width=32, encoder_blocks=2, decoder_blocks=1, layers_per_block=1)


def config(cache, out, **kw):
    base = TrainConfig(data=str(cache), out=str(out), steps=6, batch_size=16, val_every=3, ckpt_every=3,
                       val_size=32, network=replace(TINY, dropout=0.1))
    return replace(base, **kw)


def load(path):
    return torch.load(path, weights_only=True)


def metric_rows(run):
    """metrics.csv without the timing column (samples/s differs between runs by nature)."""
    lines = (run / "metrics.csv").read_text().strip().splitlines()
    return [line.rsplit(",", 1)[0] for line in lines]


def assert_same_weights(a, b):
    assert a["step"] == b["step"]
    for key in a["model"]:
        assert torch.equal(a["model"][key], b["model"][key]), key


def test_interrupted_then_resumed_run_matches_uninterrupted(tiny_cache, tmp_path):
    draws = {}

    def record(name):
        def callback(step, loss):  # numpy and python RNG draws are part of the resumed state too
            draws.setdefault(name, []).append((np.random.random(), random.random()))
        return callback

    np.random.seed(5)
    random.seed(5)
    full = config(tiny_cache, tmp_path / "full")
    train(full, progress=False, callback=record("full"))

    def interrupt(step, loss):
        record("part")(step, loss)
        if step == 4:
            raise KeyboardInterrupt

    np.random.seed(5)
    random.seed(5)
    part = config(tiny_cache, tmp_path / "part")
    with pytest.raises(TrainingInterrupted, match="checkpoint saved at step 4"):
        train(part, progress=False, callback=interrupt)
    assert load(tmp_path / "part" / "checkpoint.pt")["step"] == 4
    np.random.seed(999)  # whatever happened in between, the checkpoint restores the states
    random.seed(999)
    train(part, progress=False, callback=record("part"))
    assert_same_weights(load(tmp_path / "full" / "checkpoint.pt"), load(tmp_path / "part" / "checkpoint.pt"))
    assert draws["part"] == draws["full"]
    assert metric_rows(tmp_path / "part") == metric_rows(tmp_path / "full")  # loss average resumes too


def test_checkpoint_is_plain_data(tiny_cache, tmp_path):
    """The safe loader reads the checkpoint; RNG states are tensors and numbers, not numpy objects."""
    run = tmp_path / "run"
    train(config(tiny_cache, run, steps=3), progress=False)
    state = load(run / "checkpoint.pt")
    assert state["format"] == "smplik-checkpoint" and state["version"] == 2 and state["step"] == 3
    assert isinstance(state["rng"]["numpy"]["key"], torch.Tensor) and state["rng"]["numpy"]["key"].shape == (624,)
    assert isinstance(state["rng"]["python"]["state"], torch.Tensor)
    assert state["config"]["network"]["width"] == 32 and isinstance(state["loss_ema"], float)


def test_metrics_csv_is_cut_back_to_the_checkpoint_on_resume(tiny_cache, tmp_path):
    """A kill after logging steps 4 and 6 but before their checkpoint: the resume logs them once, as
    the uninterrupted run does (old code appended them a second time)."""
    ref = tmp_path / "ref"
    train(config(tiny_cache, ref, val_every=2), progress=False)
    run = tmp_path / "run"
    saved = {}

    def keep_step3(step, loss):
        if step == 3:
            saved["ckpt"] = (run / "checkpoint.pt").read_bytes()

    train(config(tiny_cache, run, val_every=2), progress=False, callback=keep_step3)
    (run / "checkpoint.pt").write_bytes(saved["ckpt"])  # as if killed before the step-6 checkpoint
    with open(run / "metrics.csv", "a") as fh:
        fh.write("7,0.12")  # and mid-way through a row
    assert len(metric_rows(run)) == 5
    train(config(tiny_cache, run, val_every=2), progress=False)
    assert metric_rows(run) == metric_rows(ref)
    assert [int(r.split(",")[0]) for r in metric_rows(run)[1:]] == [2, 4, 6]


@pytest.fixture()
def one_thread():
    """torch on one thread for the test (bit-exact comparisons with a ``--threads 1`` process), restored after."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _sigint_inside_loss(at_call: int, times: int = 1):
    """A ``protores_loss`` that raises a real SIGINT ``times`` times inside loss call ``at_call`` (mid-step:
    batch and effectors drawn, no update yet), then computes the loss as usual."""
    import smplik.train as train_module

    real_loss = train_module.protores_loss
    calls = {"n": 0}

    def loss(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == at_call:
            for _ in range(times):
                signal.raise_signal(signal.SIGINT)
        return real_loss(*args, **kwargs)

    return loss


@pytest.mark.parametrize("at_step", [1, 3, 5])
def test_sigint_inside_a_step_finishes_it_saves_and_resumes_bit_exactly(tiny_cache, tmp_path, monkeypatch, at_step):
    """A real SIGINT arriving in the middle of step k (raised from inside the loop, so the moment is
    chosen, not timed): step k finishes, its checkpoint is written, and the resumed run equals an
    uninterrupted one bit for bit."""
    import smplik.train as train_module

    full = config(tiny_cache, tmp_path / "full")
    train(full, progress=False)
    real_loss = train_module.protores_loss
    monkeypatch.setattr(train_module, "protores_loss", _sigint_inside_loss(at_step))
    part = config(tiny_cache, tmp_path / "part")
    with pytest.raises(TrainingInterrupted, match=f"checkpoint saved at step {at_step}$") as info:
        train(part, progress=False)
    assert not info.value.dropped and load(tmp_path / "part" / "checkpoint.pt")["step"] == at_step
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is restored
    monkeypatch.setattr(train_module, "protores_loss", real_loss)
    train(part, progress=False)
    assert_same_weights(load(tmp_path / "full" / "checkpoint.pt"), load(tmp_path / "part" / "checkpoint.pt"))
    assert metric_rows(tmp_path / "part") == metric_rows(tmp_path / "full")
    assert not [p.name for p in (tmp_path / "part").iterdir() if ".tmp" in p.name]


def test_second_sigint_inside_a_step_drops_it_and_resumes_bit_exactly(tiny_cache, tmp_path, monkeypatch):
    """Two real SIGINTs inside step 5: the second stops at once, the half-done step is dropped, the
    checkpoint of step 3 is the resume point, and the resumed run equals an uninterrupted one."""
    import smplik.train as train_module

    full = config(tiny_cache, tmp_path / "full")
    train(full, progress=False)
    real_loss = train_module.protores_loss
    monkeypatch.setattr(train_module, "protores_loss", _sigint_inside_loss(5, times=2))
    part = config(tiny_cache, tmp_path / "part")
    with pytest.raises(TrainingInterrupted, match="step was dropped and the checkpoint at step 3") as info:
        train(part, progress=False)
    assert info.value.dropped and load(tmp_path / "part" / "checkpoint.pt")["step"] == 3
    monkeypatch.setattr(train_module, "protores_loss", real_loss)
    train(part, progress=False)
    assert_same_weights(load(tmp_path / "full" / "checkpoint.pt"), load(tmp_path / "part" / "checkpoint.pt"))
    assert metric_rows(tmp_path / "part") == metric_rows(tmp_path / "full")


_CLI_WITH_SIGINT_AT = """
import signal, sys
import smplik.train as train_module
real_loss, calls = train_module.protores_loss, [0]
def loss(*args, **kwargs):  # a real SIGINT inside loss call {at_call} (mid-step), as _sigint_inside_loss
    calls[0] += 1
    if calls[0] == {at_call}:
        signal.raise_signal(signal.SIGINT)
    return real_loss(*args, **kwargs)
train_module.protores_loss = loss
sys.argv = ["smplik", *sys.argv[1:]]
from smplik.cli.main import main
main()
"""


@pytest.mark.slow
def test_cli_train_sigint_mid_step_exits_130_naming_the_saved_step(tiny_cache, tmp_path, one_thread):
    """`smplik train` in its own process, a real SIGINT inside step 4 (chosen, not timed): exit status
    130, the last stderr line says where it saved, and the resumed run equals an uninterrupted one."""
    ref_cfg = config(tiny_cache, tmp_path / "ref")
    train(ref_cfg, progress=False)
    cfg = replace(ref_cfg, out=str(tmp_path / "run"))
    (tmp_path / "cfg.json").write_text(json.dumps(cfg.to_dict()))
    code = _CLI_WITH_SIGINT_AT.format(at_call=4)
    res = subprocess.run([sys.executable, "-c", code, "train", "--config", str(tmp_path / "cfg.json"), "--threads",
                          "1"], capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
                         timeout=600)  # a hang guard only: the run takes seconds
    assert res.returncode == 130, res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[-1] == "checkpoint saved at step 4"
    assert load(tmp_path / "run" / "checkpoint.pt")["step"] == 4
    train(cfg, progress=False)
    assert_same_weights(load(tmp_path / "ref" / "checkpoint.pt"), load(tmp_path / "run" / "checkpoint.pt"))
    assert metric_rows(tmp_path / "run") == metric_rows(tmp_path / "ref")


def _stop_at(step_to_stop: int):
    def callback(step, loss):
        if step == step_to_stop:
            raise KeyboardInterrupt  # between steps: saves the checkpoint of this step
    return callback


@pytest.mark.slow
def test_real_sigint_from_outside_at_a_random_moment_resumes_bit_exactly(tiny_cache, tmp_path, one_thread):
    """A real SIGINT sent by another process at a random moment of a training run that is far too long
    to finish first: the process exits 130 naming the saved step s; resuming it to step s + 3 gives, bit
    for bit, what an uninterrupted run gives at step s + 3. A try whose signal did not interrupt the
    run (it cannot finish, but if it ever did) is retried, at most three times."""
    net = NetworkConfig(width=16, encoder_blocks=1, decoder_blocks=1, layers_per_block=1, dropout=0.1)
    long_cfg = config(tiny_cache, tmp_path / "ref", steps=1_000_000, batch_size=8, val_size=16, val_every=25,
                      ckpt_every=25, network=net)
    rng = random.Random(1234)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    saved = None
    for attempt in range(3):
        run = tmp_path / f"run{attempt}"
        cfg = replace(long_cfg, out=str(run))
        (tmp_path / f"cfg{attempt}.json").write_text(json.dumps(cfg.to_dict()))
        proc = subprocess.Popen([sys.executable, "-m", "smplik.cli", "train", "--config",
                                 str(tmp_path / f"cfg{attempt}.json"), "--threads", "1"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        try:
            while not (run / "metrics.csv").exists() and proc.poll() is None:
                time.sleep(0.01)  # polling, not timing: the loop starts once the run folder is set up
            time.sleep(rng.uniform(0.0, 0.3))  # the random moment
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=600)  # a hang guard only
        finally:
            proc.kill()
        if proc.returncode == 130:
            last = err.strip().splitlines()[-1]
            assert last.startswith("checkpoint saved at step "), err[-1000:]
            saved = int(last.removeprefix("checkpoint saved at step "))
            assert load(run / "checkpoint.pt")["step"] == saved
            assert not [p.name for p in run.iterdir() if ".tmp" in p.name]
            break
        assert proc.returncode == 0, err[-2000:]
    assert saved is not None, "no SIGINT interrupted the run in three tries"
    with pytest.raises(TrainingInterrupted, match=f"step {saved + 3}$"):
        train(cfg, progress=False, callback=_stop_at(saved + 3))
    with pytest.raises(TrainingInterrupted, match=f"step {saved + 3}$"):
        train(long_cfg, progress=False, callback=_stop_at(saved + 3))
    assert_same_weights(load(tmp_path / "ref" / "checkpoint.pt"), load(run / "checkpoint.pt"))
    assert metric_rows(run) == metric_rows(tmp_path / "ref")


def test_no_validation_frames_trains_with_a_notice_or_held_out_clips(tiny_cache, tmp_path):
    from smplik.data.dataset import build_cache, find_sources, load_cache

    cache = tmp_path / "all_train.npz"  # the tiny cache's clips, built without a split: all in train
    build_cache(find_sources(tiny_cache.parent / "clips", "amass"), fps=30, split=None, out=cache)
    assert len(load_cache(cache).subset("validation")) == 0
    with pytest.warns(UserWarning, match="no validation frames: validation is skipped"):
        metrics = train(config(cache, tmp_path / "skip", steps=3), progress=False)
    assert metrics == {} and load(tmp_path / "skip" / "checkpoint.pt")["step"] == 3
    held = train(config(cache, tmp_path / "held", steps=3, val_fraction=0.3), progress=False)
    assert held["mpjpe_mm"] > 0
    with pytest.raises(ValueError, match="has 40 validation frames; val_fraction"):
        train(config(tiny_cache, tmp_path / "bad", val_fraction=0.3), progress=False)


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


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_torchrun_two_processes_on_cpu(tiny_cache, tmp_path):
    run = tmp_path / "ddp"
    cfg = config(tiny_cache, run, steps=3, ckpt_every=3, val_every=3)
    (tmp_path / "cfg.json").write_text(json.dumps(cfg.to_dict()))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--standalone",
           "-m", "smplik.cli", "train", "--config", str(tmp_path / "cfg.json")]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)  # hang guard
    assert res.returncode == 0, res.stderr[:3000] + " ... " + res.stderr[-1500:]
    state = load(run / "checkpoint.pt")
    assert state["step"] == 3 and state["config"]["network"]["width"] == 32


def test_init_from_starts_from_given_weights(tiny_cache, tmp_path):
    first = config(tiny_cache, tmp_path / "a", steps=3)
    train(first, progress=False)
    # a 1-step run with lr 0 keeps exactly the weights it started from
    third = config(tiny_cache, tmp_path / "c", steps=1, lr=0.0, init_from=str(tmp_path / "a" / "checkpoint.pt"))
    train(third, progress=False)
    a = load(tmp_path / "a" / "checkpoint.pt")["model"]
    c = load(tmp_path / "c" / "checkpoint.pt")["model"]
    assert all(torch.equal(a[k], c[k]) for k in a)
    bad = config(tiny_cache, tmp_path / "d", init_from=str(tmp_path / "a" / "checkpoint.pt"),
                 network=replace(TINY, width=48))
    with pytest.raises(ValueError, match="network sizes"):
        train(bad, progress=False)
    with pytest.raises(ValueError, match="the run was trained with network sizes"):
        train(replace(first, network=replace(TINY, width=48)), progress=False)  # resuming run "a"


def test_bf16_precision_trains_float32_weights_and_bad_precision_is_an_error(tiny_cache, tmp_path):
    train(config(tiny_cache, tmp_path / "bf", steps=3, precision="bf16"), progress=False)
    state = load(tmp_path / "bf" / "checkpoint.pt")
    assert all(v.dtype == torch.float32 for v in state["model"].values() if v.is_floating_point())
    rows = (tmp_path / "bf" / "metrics.csv").read_text().splitlines()
    assert np.isfinite(float(rows[-1].split(",")[1]))
    fp = config(tiny_cache, tmp_path / "fp", steps=3)
    train(fp, progress=False)
    assert not torch.equal(state["model"]["encoder.0.mlp.0.weight"],
                           load(tmp_path / "fp" / "checkpoint.pt")["model"]["encoder.0.mlp.0.weight"])
    with pytest.raises(ValueError, match="precision must be one of fp32, bf16, got 'fp16'"):
        train(config(tiny_cache, tmp_path / "x", precision="fp16"), progress=False)


def test_distillation_pulls_towards_the_teacher_and_resumes_exactly(tiny_cache, tmp_path):
    """With weight 0 the teacher changes nothing (bit for bit); with weight > 0 the run differs, and an
    interrupted distillation run resumes to the uninterrupted one's weights."""
    train(config(tiny_cache, tmp_path / "teacher", steps=3), progress=False)
    teacher = str(tmp_path / "teacher" / "checkpoint.pt")
    start = {"init_from": teacher, "distill_from": teacher, "distill_ensemble": "mirror+yaw2"}
    plain = config(tiny_cache, tmp_path / "plain", init_from=teacher)
    zero = config(tiny_cache, tmp_path / "zero", **start, distill_weight=0.0)
    full = config(tiny_cache, tmp_path / "full", **start, distill_weight=5.0)
    for cfg in (plain, zero, full):
        train(cfg, progress=False)
    assert_same_weights(load(tmp_path / "plain" / "checkpoint.pt"), load(tmp_path / "zero" / "checkpoint.pt"))
    distilled = load(tmp_path / "full" / "checkpoint.pt")
    assert not torch.equal(distilled["model"]["ikd.blocks.0.forward_out.weight"],
                           load(tmp_path / "plain" / "checkpoint.pt")["model"]["ikd.blocks.0.forward_out.weight"])

    def interrupt(step, loss):
        if step == 4:
            raise KeyboardInterrupt

    part = config(tiny_cache, tmp_path / "part", **start, distill_weight=5.0)
    with pytest.raises(TrainingInterrupted, match="checkpoint saved at step 4"):
        train(part, progress=False, callback=interrupt)
    train(part, progress=False)
    assert_same_weights(distilled, load(tmp_path / "part" / "checkpoint.pt"))
    refined = config(tiny_cache, tmp_path / "refined", **start, distill_weight=5.0, distill_refine=True)
    train(refined, progress=False)  # the teacher solver's pose as the target: another run again
    assert not torch.equal(load(tmp_path / "refined" / "checkpoint.pt")["model"]["ikd.blocks.0.forward_out.weight"],
                           distilled["model"]["ikd.blocks.0.forward_out.weight"])
    with pytest.raises(ValueError, match="Unknown ensemble 'yaw-2'"):
        train(config(tiny_cache, tmp_path / "bad", distill_from=teacher, distill_ensemble="yaw-2"), progress=False)


# ----------------------------------------------------------------------------- config file and flags


@pytest.fixture()
def captured(monkeypatch):
    """Run ``smplik train`` but capture the merged TrainConfig instead of training."""
    from smplik.cli.main import app

    seen = {}

    def fake_train(cfg, **kwargs):
        seen["cfg"] = cfg
        return {}

    monkeypatch.setattr("smplik.train.train", fake_train)

    def run(*args):
        res = CliRunner().invoke(app, ["train", *args])
        assert res.exit_code == 0, res.output
        return seen.pop("cfg")

    return run


ISSUE_CONFIG = {"steps": 777, "lr": 5e-4, "seed": 3, "val_every": 50,
                "network": {"width": 256, "effector_slots": True}, "loss": {"w_rot_local": 4.0}}


def test_config_file_alone_is_honoured(captured, tmp_path):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(ISSUE_CONFIG))
    cfg = captured("--config", str(path), "--data", "c.npz", "--out", "run")
    assert (cfg.steps, cfg.lr, cfg.seed, cfg.val_every) == (777, 5e-4, 3, 50)
    assert (cfg.network.width, cfg.network.effector_slots, cfg.loss.w_rot_local) == (256, True, 4.0)
    assert cfg.batch_size == TrainConfig.batch_size and cfg.network.encoder_blocks == NetworkConfig.encoder_blocks


def test_config_file_plus_one_flag(captured, tmp_path):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps({**ISSUE_CONFIG, "data": "from_file.npz", "out": "run_from_file"}))
    cfg = captured("--config", str(path), "--lr", "1e-4")
    assert cfg.lr == 1e-4
    assert (cfg.steps, cfg.seed, cfg.network.width, cfg.network.effector_slots) == (777, 3, 256, True)
    assert (cfg.data, cfg.out) == ("from_file.npz", "run_from_file")
    cfg = captured("--config", str(path), "--no-effector-slots", "--width", "64")
    assert (cfg.network.width, cfg.network.effector_slots, cfg.steps) == (64, False, 777)


def test_flags_alone(captured):
    cfg = captured("--data", "c.npz", "--out", "run", "--steps", "12", "--width", "48", "--seed", "7",
                   "--no-augment", "--val-fraction", "0.2")
    assert (cfg.steps, cfg.network.width, cfg.seed, cfg.augment, cfg.val_fraction) == (12, 48, 7, False, 0.2)
    assert cfg.lr == TrainConfig.lr and cfg.network.decoder_blocks == NetworkConfig.decoder_blocks
    assert captured("--data", "c.npz", "--out", "run", "--paper-sizes").network == NetworkConfig.paper()
    cfg = captured("--data", "c.npz", "--out", "run", "--precision", "bf16", "--distill-from", "t.pt",
                   "--distill-weight", "0.5", "--distill-ensemble", "mirror", "--distill-refine")
    assert (cfg.precision, cfg.distill_from, cfg.distill_weight, cfg.distill_ensemble, cfg.distill_refine) == (
        "bf16", "t.pt", 0.5, "mirror", True)
    cfg = captured("--data", "c.npz", "--out", "run", "--part-swap", "0.25", "--limb-first", "0.5")
    assert (cfg.part_swap, cfg.effectors.limb_first, cfg.effectors.eta) == (0.25, 0.5, TrainConfig(
        data="", out="").effectors.eta)


def test_bad_config_files_are_one_line_errors(tmp_path):
    from smplik.cli.main import app

    for text, message in [('{"width": 256}', "unknown key 'width'"), ('{"network": {"widht": 1}}', "network.widht"),
                          ('{"steps": "777"}', "key 'steps' must be int"), ("{nope", "invalid JSON")]:
        path = tmp_path / "cfg.json"
        path.write_text(text)
        res = CliRunner().invoke(app, ["train", "--config", str(path), "--data", "c.npz", "--out", "r"])
        assert res.exit_code == 1 and message in res.output and "cfg.json" in res.output, res.output
        assert len(res.output.strip().splitlines()) == 1 and res.exception is None or isinstance(res.exception,
                                                                                                 SystemExit)
    res = CliRunner().invoke(app, ["train", "--out", "r"])
    assert res.exit_code == 1 and "--data is required" in res.output


def test_shipped_recipe_configs_parse():
    """The fine-tuning configs of the shipped model's recipe (README) load as TrainConfig overrides."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "configs"
    cfgs = {n: TrainConfig.from_file(root / f"shipped_{n}.json", data="", out="") for n in ("ft1", "ft2")}
    distill = TrainConfig.from_file(root / "shipped_ft3_distill.json", data="", out="")
    assert (distill.precision, distill.distill_ensemble, distill.distill_weight) == ("bf16", "mirror+yaw4", 1.0)
    assert not distill.distill_refine
    refined = TrainConfig.from_file(root / "shipped_ft4_distill_refine.json", data="", out="")
    assert refined.distill_refine and refined.precision == "bf16" and refined.steps == 12000
    limbs = {n: TrainConfig.from_file(root / f"shipped_{n}.json", data="", out="")
             for n in ("ft6a_limbs", "ft6b_limbs_swap", "ft7_distill_limbs")}
    assert [c.effectors.limb_first for c in limbs.values()] == [0.5, 0.5, 0.5]
    assert [c.part_swap for c in limbs.values()] == [0.0, 0.25, 0.25]
    assert limbs["ft7_distill_limbs"].distill_refine and limbs["ft7_distill_limbs"].steps == 14000
    assert (cfgs["ft1"].loss.w_rot_local, cfgs["ft2"].loss.w_rot_local) == (2.0, 4.0)
    for cfg in cfgs.values():
        assert cfg.loss.w_pos_rnd == 1000.0 and cfg.effectors.eta == 4.0 and cfg.effectors.max_effectors == 16


def test_sampling_options_train_and_keep_validation_comparable(tiny_cache, tmp_path):
    """limb_first and part_swap change what the run trains on, but not its validation effectors: with a
    learning rate of 0 the logged validation metrics equal the paper-sampling run's, and the options
    land in config.json."""
    plain = config(tiny_cache, tmp_path / "plain", lr=0.0, steps=3, val_every=3, network=TINY)
    options = replace(plain, out=str(tmp_path / "options"), part_swap=0.5,
                      effectors=replace(plain.effectors, limb_first=1.0))
    assert train(plain, progress=False) == train(options, progress=False)
    saved = json.loads((tmp_path / "options" / "config.json").read_text())
    assert saved["part_swap"] == 0.5 and saved["effectors"]["limb_first"] == 1.0
    losses = [float(metric_rows(tmp_path / run)[-1].split(",")[1]) for run in ("plain", "options")]
    assert losses[0] != losses[1]  # the training batches did differ
