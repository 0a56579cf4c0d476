"""Model files never run code: every entry point refuses a payload ``.pt`` before it runs, with a
one-line error naming the file; older files convert through ``--legacy``, which is the restricted loader too."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from smplik.model_io import (
    FORMAT_VERSION,
    CheckpointError,
    average_models,
    export_model,
    load_checkpoint,
    load_model,
    read_model_file,
    write_model_file,
)
from smplik.network import NetworkConfig, ProtoResIK
from smplik.solver import IKSolver, packaged_model_path
from smplik.train import TrainConfig, train

TINY = NetworkConfig(width=16, encoder_blocks=1, decoder_blocks=1, layers_per_block=1)


class Payload:
    """Unpickling this creates ``marker``: what a hostile model file would do with ``os.system``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture()
def payload(tmp_path):
    """A model file in every other respect (format, network, weights) carrying a payload."""
    marker = tmp_path / "PAYLOAD_RAN"
    path = tmp_path / "evil.pt"
    torch.save({"format": "smplik-model", "version": 1, "network": TINY.to_dict(), "model": {},
                "metrics": {"x": Payload(marker)}}, path)
    return path, marker


def flat(text: str) -> str:
    return "".join(text.split())


def assert_refused(res, path: Path, marker: Path, *, one_line: bool = True) -> None:
    """Non-zero exit, no traceback, the file named, the payload not run."""
    assert not marker.exists(), "the payload ran"
    assert res.exit_code != 0, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in res.output and flat(str(path)) in flat(res.output), res.output
    if one_line:
        assert len(res.output.strip().splitlines()) == 1, res.output


def cli(*args):
    from smplik.cli.main import app

    return CliRunner().invoke(app, list(args))


def test_the_payload_is_live(payload):
    """Sanity check of the fixture: plain unpickling would run it (here in a throwaway process)."""
    path, marker = payload
    code = "import torch, sys; torch.load(sys.argv[1], weights_only=False)"  # the old loader's call
    subprocess.run([sys.executable, "-c", code, str(path)], check=True, capture_output=True, timeout=600)
    assert marker.exists()


def test_iksolver_load_refuses_payload(payload):
    path, marker = payload
    with pytest.raises(CheckpointError, match="refused.*posix.system.*--legacy") as info:
        IKSolver.load(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    assert not marker.exists()


def test_solve_cli_refuses_payload(payload, tmp_path):
    path, marker = payload
    eff = tmp_path / "eff.json"
    eff.write_text(json.dumps({"effectors": [{"joint": "head", "type": "position", "value": [0, 1.6, 0]}]}))
    assert_refused(cli("solve", str(eff), "--checkpoint", str(path), "--out", str(tmp_path / "p.json")), path,
                   marker, one_line=False)  # smplik solve's error printing is the CLI-hardening change's


def test_solve_cli_process_refuses_payload(payload, tmp_path):
    """The same through a real process: exit 1, no traceback on stderr."""
    path, marker = payload
    eff = tmp_path / "eff.json"
    eff.write_text(json.dumps({"effectors": [{"joint": "head", "type": "position", "value": [0, 1.6, 0]}]}))
    res = subprocess.run([sys.executable, "-m", "smplik.cli", "solve", str(eff), "--checkpoint", str(path), "--out",
                          str(tmp_path / "p.json")], capture_output=True, text=True, timeout=600)
    assert res.returncode == 1 and "Traceback" not in res.stderr and "refused" in res.stderr, res.stderr
    assert not marker.exists() and not (tmp_path / "p.json").exists()


def test_train_init_from_refuses_payload(payload, tiny_cache, tmp_path):
    path, marker = payload
    res = cli("train", "--data", str(tiny_cache), "--out", str(tmp_path / "run"), "--init-from", str(path),
              "--steps", "1", "--width", "16")
    assert_refused(res, path, marker)


def test_resume_refuses_payload_checkpoint(payload, tiny_cache, tmp_path):
    path, marker = payload
    run = tmp_path / "run"
    run.mkdir()
    ckpt = run / "checkpoint.pt"
    ckpt.write_bytes(path.read_bytes())
    res = cli("train", "--data", str(tiny_cache), "--out", str(run), "--steps", "1")
    assert_refused(res, ckpt, marker)
    with pytest.raises(CheckpointError, match="refused"):
        train(TrainConfig(data=str(tiny_cache), out=str(run), steps=1, network=TINY), progress=False)
    assert not marker.exists()


def test_export_model_refuses_payload(payload, tmp_path):
    path, marker = payload
    path = path.rename(tmp_path / "evil[red].pt")  # file names are printed verbatim, not as rich markup
    res = cli("export-model", str(path), "--out", str(tmp_path / "out.pt"))
    assert_refused(res, path, marker)
    assert "--legacy" in res.output and not (tmp_path / "out.pt").exists()
    res = cli("export-model", str(path), "--out", str(tmp_path / "out.pt"), "--legacy")  # the conversion path
    assert_refused(res, path, marker)
    assert not (tmp_path / "out.pt").exists()


def test_scene_commands_refuse_payload(payload, tmp_path):
    from workflows.scene import SCENE_FORMAT, SCENE_VERSION

    path, marker = payload
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"format": SCENE_FORMAT, "version": SCENE_VERSION, "characters": []}))
    assert_refused(cli("scene", "solve", str(scene), "--checkpoint", str(path)), path, marker, one_line=False)
    assert_refused(cli("scene", "from-estimate", str(tmp_path / "est.npz"), "--out", str(tmp_path / "o"),
                       "--checkpoint", str(path)), path, marker, one_line=False)


# ----------------------------------------------------------------------------- old files and conversion


@pytest.fixture()
def old_format_model(tmp_path, bodies):
    """A model file as an older writer might have saved it: numpy metrics and a numpy RNG state."""
    torch.manual_seed(0)
    model = ProtoResIK(TINY, bodies.J_template, bodies.J_dirs)
    path = tmp_path / "old.pt"
    torch.save({"format": "smplik-checkpoint", "version": 1, "step": np.int64(12), "network": TINY.to_dict(),
                "model": model.state_dict(), "metrics": {"mpjpe_mm": np.float64(81.5)},
                "rng": {"numpy": np.random.RandomState(0).get_state()}, "body_fingerprint": bodies.fingerprint}, path)
    return path, model


def test_old_format_file_refused_then_converted_with_legacy(old_format_model, tmp_path):
    path, model = old_format_model
    with pytest.raises(CheckpointError, match=r"refused.*numpy.*smplik export-model .*old\.pt --out NEW\.pt "
                                              r"--legacy"):
        load_model(path)
    new = tmp_path / "new.pt"
    res = cli("export-model", str(path), "--out", str(new), "--legacy", "--full-precision")
    assert res.exit_code == 0, res.output
    converted, meta = load_model(new)
    assert meta["version"] == FORMAT_VERSION and meta["step"] == 12 and meta["metrics"] == {"mpjpe_mm": 81.5}
    for key, value in model.state_dict().items():
        assert torch.equal(converted.state_dict()[key], value), key


def test_writer_refuses_what_the_safe_loader_would(tmp_path):
    with pytest.raises(TypeError, match=r"state\['metrics'\]\['x'\]: a numpy.float64"):
        write_model_file(tmp_path / "m.pt", {"format": "smplik-model", "metrics": {"x": np.float64(1.0)}})
    assert not list(tmp_path.iterdir())


def test_header_checks(tmp_path, bodies):
    model = ProtoResIK(TINY, bodies.J_template, bodies.J_dirs)
    base = {"format": "smplik-model", "version": FORMAT_VERSION, "network": TINY.to_dict(),
            "model": model.state_dict()}
    cases = [({**base, "version": 99}, "version 99"), ({**base, "format": "other"}, "not an smplik model"),
             ({**base, "network": {"width": 16, "depth": 3}}, "not a network config"),
             ({**base, "network": replace(TINY, width=24).to_dict()}, "do not fit"),
             ([1, 2], "not an smplik model")]
    for i, (state, message) in enumerate(cases):
        path = tmp_path / f"m{i}.pt"
        torch.save(state, path)
        with pytest.raises(CheckpointError, match=message):
            load_model(path)
    with pytest.raises(CheckpointError, match="is an smplik-model file; expected smplik-checkpoint"):
        load_checkpoint(write_model_file(tmp_path / "ok.pt", base))
    raw = tmp_path / "raw.pt"
    raw.write_bytes(b"\x80\x04not a zip")
    with pytest.raises(CheckpointError, match="not a torch.save zip file"):
        read_model_file(raw)
    truncated = tmp_path / "trunc.pt"
    truncated.write_bytes((tmp_path / "ok.pt").read_bytes()[:-200])
    with pytest.raises(CheckpointError, match="trunc.pt"):
        read_model_file(truncated)


def test_shipped_model_is_the_safe_format():
    if not packaged_model_path().is_file():
        pytest.skip("this installation ships without a model")
    state = read_model_file(packaged_model_path())
    assert state["format"] == "smplik-model" and state["version"] == FORMAT_VERSION
    dtypes = {v.dtype for k, v in state["model"].items() if not k.startswith(("J_", "identity"))}
    assert dtypes == {torch.float16} and state["model"]["J_template"].dtype == torch.float32


def test_export_round_trip_keeps_weights(tmp_path, bodies):
    model = ProtoResIK(TINY, bodies.J_template, bodies.J_dirs)
    ckpt = write_model_file(tmp_path / "c.pt", {"format": "smplik-checkpoint", "version": FORMAT_VERSION,
                                                "step": 3, "network": TINY.to_dict(), "model": model.state_dict()})
    out = export_model(ckpt, tmp_path / "m.pt")
    again = export_model(out, out)  # re-export in place is the identity
    loaded, _ = load_model(again)
    for key, value in model.state_dict().items():
        expected = value if key.startswith("J_") or not value.is_floating_point() else value.half().float()
        assert torch.equal(loaded.state_dict()[key], expected), key


def test_solver_imports_no_training_code():
    """Module boundaries: loading and solving never import the training loop, its data or its losses
    (old code imported smplik.train from IKSolver.load); effector sampling sits with the pose sampler."""
    import smplik.effectors
    from smplik.data import effector_sampling

    assert not hasattr(smplik.effectors, "sample_effectors") and callable(effector_sampling.sample_effectors)
    code = ("import json, sys; from smplik.solver import IKSolver; IKSolver.load().solve([{'joint': 'head', "
            "'type': 'position', 'value': [0, 1.6, 0]}]); "
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('smplik'))))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    loaded = set(json.loads(res.stdout.strip().splitlines()[-1]))
    assert "smplik.model_io" in loaded
    assert not loaded & {"smplik.train", "smplik.losses", "smplik.data.sampler", "smplik.data.dataset"}, loaded


def test_decompression_bomb_is_refused_before_reading(tmp_path, monkeypatch):
    import zipfile

    monkeypatch.setattr("smplik.model_io._MAX_INFLATED_BYTES", 1 << 16)  # the real cap is 64 MiB
    bomb = tmp_path / "bomb.pt"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("archive/data.pkl", b"\0" * (1 << 20))
    with pytest.raises(CheckpointError, match="bomb.pt: member 'archive/data.pkl' inflates"):
        read_model_file(bomb)


def _tiny_file(tmp_path, bodies, name: str, seed: int, cfg: NetworkConfig = TINY, **extra) -> Path:
    torch.manual_seed(seed)
    model = ProtoResIK(cfg, bodies.J_template, bodies.J_dirs)
    return write_model_file(tmp_path / name, {"format": "smplik-checkpoint", "version": FORMAT_VERSION,
                                              "step": 10 * seed, "network": cfg.to_dict(),
                                              "model": model.state_dict(), "body_fingerprint": "bodies", **extra})


def test_average_models_is_the_mean_of_the_weights(tmp_path, bodies):
    paths = [_tiny_file(tmp_path, bodies, f"m{seed}.pt", seed) for seed in (1, 2, 3)]
    out = average_models(paths, tmp_path / "soup.pt", half=False)
    soup, meta = load_model(out)
    inputs = [load_model(p)[0].state_dict() for p in paths]
    for key, value in soup.state_dict().items():
        expected = torch.stack([s[key].float() for s in inputs]).mean(0)
        assert torch.allclose(value, expected, atol=1e-7), key
    weights = [k for k, v in inputs[0].items() if v.is_floating_point() and not k.startswith(("J_", "identity"))]
    assert weights and all(not torch.equal(inputs[0][k], inputs[1][k]) for k in weights if inputs[0][k].std() > 0)
    assert meta["step"] == 30 and [a["file"] for a in meta["averaged_from"]] == ["m1.pt", "m2.pt", "m3.pt"]
    assert "refine" not in meta
    assert export_model(out, tmp_path / "again.pt") and load_model(tmp_path / "again.pt")[1]["averaged_from"]


def test_average_models_refuses_mismatches(tmp_path, bodies):
    a = _tiny_file(tmp_path, bodies, "a.pt", 1)
    wide = _tiny_file(tmp_path, bodies, "wide.pt", 2, replace(TINY, width=24))
    other_body = _tiny_file(tmp_path, bodies, "body.pt", 3, body_fingerprint="other")
    with pytest.raises(ValueError, match="at least two"):
        average_models([a], tmp_path / "x.pt")
    with pytest.raises(CheckpointError, match="wide.pt: key 'network' differs"):
        average_models([a, wide], tmp_path / "x.pt")
    with pytest.raises(CheckpointError, match="body.pt: key 'body_fingerprint' differs"):
        average_models([a, other_body], tmp_path / "x.pt")
    state = read_model_file(a)
    state["model"]["J_template"] = state["model"]["J_template"] + 0.01
    moved = write_model_file(tmp_path / "moved.pt", state)
    with pytest.raises(CheckpointError, match="moved.pt: buffer 'model.J_template' differs"):
        average_models([a, moved], tmp_path / "x.pt")
    assert not (tmp_path / "x.pt").exists()


def test_average_models_cli(tmp_path, bodies):
    a, b = _tiny_file(tmp_path, bodies, "a.pt", 1), _tiny_file(tmp_path, bodies, "b.pt", 2)
    result = cli("average-models", str(a), str(b), "--out", str(tmp_path / "soup.pt"))
    assert result.exit_code == 0, result.output
    assert read_model_file(tmp_path / "soup.pt")["format"] == "smplik-model"
    wide = _tiny_file(tmp_path, bodies, "wide.pt", 3, replace(TINY, width=24))
    result = cli("average-models", str(a), str(wide), "--out", str(tmp_path / "bad.pt"))
    assert result.exit_code == 1 and "key 'network' differs" in result.output
    assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / "bad.pt").exists()
