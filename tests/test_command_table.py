"""The command table at the top layer (``workflows.commands``): the tracker's trainer is a command of it
(``smplik track-train``, the options of :class:`smplik.tracking.config.TrackingTrainConfig`), and the batch's jobs
load the same commands as the table."""

from __future__ import annotations

import subprocess
import sys

import pytest
from typer.testing import CliRunner

from smplik.cli.main import app

NO_HEAVY_IMPORT = ("import sys; from smplik.cli.main import app\n"
                   "try:\n    app(args=sys.argv[1:], prog_name='smplik')\nexcept SystemExit:\n    pass\n"
                   "print('torch' in sys.modules or 'numpy' in sys.modules, file=sys.stderr)")


def test_track_train_help_lists_the_trainer_options_and_imports_no_torch():
    res = subprocess.run([sys.executable, "-c", NO_HEAVY_IMPORT, "track-train", "--help"], capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0 and res.stderr.strip().splitlines()[-1] == "False", res.stderr[-2000:]
    assert res.stdout.startswith("Usage: smplik track-train [OPTIONS] CACHE OUT")
    for option in ("--minutes", "--kind", "--trackers", "--threads", "--device", "--workers", "--batch", "--lr",
                   "--seed", "--init", "--rotation-weight"):
        assert option in res.stdout, option
    assert "[cvae|mlp]" in res.stdout and "[4|3]" in res.stdout


BAD = {
    "no arguments": ([], "Missing argument 'CACHE'"),
    "minutes": (["c.npz", "o.pt", "--minutes", "0"], "--minutes"),
    "kind": (["c.npz", "o.pt", "--kind", "gan"], "--kind"),
    "trackers": (["c.npz", "o.pt", "--trackers", "5"], "--trackers"),
    "workers": (["c.npz", "o.pt", "--workers", "-1"], "--workers"),
    "batch": (["c.npz", "o.pt", "--batch", "0"], "--batch"),
    "out suffix": (["c.npz", "o.onnx"], "must end in .pt"),
    "missing cache": (["c.npz", "o.pt"], "c.npz: no such pose cache"),
    "unknown option": (["c.npz", "o.pt", "--epochs", "3"], "--epochs"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_track_train_refuses_bad_options_in_one_line(case, tmp_path, monkeypatch):
    args, names = BAD[case]
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(app, ["track-train", *args])
    assert res.exit_code == 1, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and names in lines[0], res.stderr
    assert not (tmp_path / "o.pt").exists()


def test_track_train_option_check_imports_no_torch(tmp_path):
    res = subprocess.run([sys.executable, "-c", NO_HEAVY_IMPORT, "track-train", "c.npz", "o.pt", "--minutes", "-1"],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert lines[-1] == "False" and lines[0].startswith("error: ") and "--minutes" in lines[0], res.stderr[-2000:]


def test_batch_jobs_load_the_commands_of_the_table():
    from workflows.batch.jobs import JOBS
    from workflows.batch.plan import job_command
    from workflows.commands import load_command

    for job in JOBS.values():
        command = load_command(job.command[0])
        for word in job.command[1:]:
            command = command.commands[word]
        if getattr(command, "commands", None):
            command = next(iter(command.commands.values()))
        loaded = job_command(job)
        assert (loaded.name, loaded.help, [p.name for p in loaded.params]) == \
            (command.name, command.help, [p.name for p in command.params]), job.name


def test_track_train_runs_the_trainer_and_reports_its_refusal_in_one_line(tiny_cache, tmp_path):
    """The command reaches :func:`smplik.tracking.train.train`: a 30 fps cache is refused by the trainer (the network
    reads 60 Hz) with one line naming the cache, and no model file is written."""
    res = CliRunner().invoke(app, ["track-train", str(tiny_cache), str(tmp_path / "o.pt"), "--minutes", "0.01"])
    assert res.exit_code == 1, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and str(tiny_cache) in lines[0] and "30 fps" in lines[0] and "60" in lines[0], res.stderr
    assert not (tmp_path / "o.pt").exists()


def test_track_train_trains_with_the_options_given(tmp_path):
    """A few seconds of training on a 60 Hz toy cache: the model file and its figures are written, and the options
    reach the trainer's config (network kind, tracker set, batch, rotation weight)."""
    import json

    import numpy as np

    from smplik.data.dataset import build_cache, find_sources

    rng, clips = np.random.default_rng(0), tmp_path / "clips"
    clips.mkdir()
    for c in range(4):  # AMASS-layout clips at 60 Hz: smooth random motion, upright in AMASS's z-up world
        t = np.linspace(0, 2 * np.pi, 140)[:, None]
        poses = rng.normal(0, 0.25, 72) + rng.normal(0, 0.3, 72) * np.sin(t + rng.uniform(0, 6, 72))
        poses[:, :3] = [np.pi / 2, 0, 0]
        np.savez(clips / f"clip{c}.npz", poses=poses, trans=np.zeros((140, 3)), betas=rng.normal(0, 1, 10),
                 gender="neutral", mocap_framerate=60.0)
    split = {"train": {"files": ["clip0.npz", "clip1.npz"]}, "validation": {"files": ["clip2.npz"]},
             "test": {"files": ["clip3.npz"]}}
    (clips / "split.json").write_text(json.dumps(split))
    cache = tmp_path / "c60.npz"
    build_cache(find_sources(clips, "amass"), fps=60, split=clips / "split.json", out=cache)
    res = CliRunner().invoke(app, ["track-train", str(cache), str(tmp_path / "m.pt"), "--minutes", "0.005",
                                   "--kind", "mlp", "--trackers", "3", "--batch", "2", "--rotation-weight", "0.3"])
    assert res.exit_code == 0, res.output
    assert "best validation MPJPE" in res.stdout and (tmp_path / "m.pt").stat().st_size > 0
    info = json.loads((tmp_path / "m.json").read_text())
    assert info["net"]["kind"] == "mlp" and info["net"]["trackers"] == ["head", "left_wrist", "right_wrist"]
    assert info["train"]["batch"] == 2 and info["train"]["rotation_weight"] == 0.3 and info["steps"] >= 1
