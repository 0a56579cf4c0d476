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
