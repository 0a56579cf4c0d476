"""The command line as a user meets it: help that shows flags as flags and ARGUMENTS in capitals, help that
imports no torch, and one ``error:`` line with exit status 1 for a bad invocation of every command group."""

from __future__ import annotations

import subprocess
import sys

import pytest
from typer.testing import CliRunner

from smplik.cli.main import COMMANDS, app, load_command


def invoke(*args: str, env: dict | None = None):
    return CliRunner().invoke(app, list(args), env=env)


def all_help_paths() -> list[list[str]]:
    paths = [[]]
    for name in COMMANDS:
        subs = sorted(getattr(load_command(name), "commands", {}))
        paths += [[name, sub] for sub in subs] if subs else [[name]]
    return paths


@pytest.mark.parametrize("path", all_help_paths(), ids=lambda p: " ".join(p) or "smplik")
def test_help_shows_flags_capital_arguments_and_whole_option_names(path):
    res = invoke(*path, "--help")
    assert res.exit_code == 0, res.output
    text = res.output
    assert text.startswith("Usage: smplik" + "".join(f" {p}" for p in path))
    for bad in ("<bool>", "<path>", "<int", "<str>", "<list", "…", "--install-completion"):
        assert bad not in text, (bad, text)
    assert "{" not in text.splitlines()[0]  # arguments are not shown as if they were choices
    assert "(default" not in text.replace("\n", " ").replace("  ", " "), text  # one style: [default: X]
    command = load_command(path[0]) if path else None
    if command is not None and len(path) == 2:
        command = command.commands[path[1]]
    for param in getattr(command, "params", []):
        if param.param_type_name == "argument":
            assert param.metavar.rstrip(".") == param.name.upper()
            assert param.metavar in text.splitlines()[0]
        elif getattr(param, "is_flag", False):
            names = [o for o in param.opts if o.startswith("--")]
            line = next(line for line in text.splitlines() if line.strip().startswith(names[0]))
            assert not any(w.isupper() and len(w) > 1 for w in line.split()[:3]), line  # no value placeholder
        elif not param.hidden:
            assert param.opts[0] in text  # no option name cut short


def test_listing_matches_the_commands():
    res = invoke("--help")
    listed = [line.split()[0] for line in res.output.split("Commands:")[1].splitlines() if line.startswith("  ")
              and not line.startswith("   ")]
    assert listed == list(COMMANDS)
    for name in COMMANDS:
        assert load_command(name).name == name


@pytest.mark.parametrize("args", [["--help"], ["scene", "export", "--help"], ["solve", "--help"], ["train", "--help"]])
def test_help_imports_no_torch_nor_numpy(args):
    code = ("import sys; from smplik.cli.main import app\n"
            "try:\n    app(args=sys.argv[1:], prog_name='smplik')\nexcept SystemExit:\n    pass\n"
            "print('torch' in sys.modules or 'numpy' in sys.modules, file=sys.stderr)")
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and res.stderr.strip().splitlines()[-1] == "False", res.stderr[-2000:]


BAD_INVOCATIONS = {
    "top level": (["nope"], "No such command 'nope'"),
    "demo": (["demo"], "Missing option '--out'"),
    "solve": (["solve", "missing.json", "--out", "pose.json"], "missing.json"),
    "solve usage": (["solve"], "Missing argument 'EFFECTORS'"),
    "scene": (["scene", "export"], "Missing argument 'SCENE'"),
    "scene command": (["scene", "frobnicate"], "No such command 'frobnicate'"),
    "edit": (["edit", "--port", "99999"], "--port"),
    "invert-shape": (["invert-shape"], "Missing argument 'CHARACTER'"),
    "body": (["body", "info", "--gender", "x"], "--gender"),
    "data preview without data": (["data", "preview"], "Missing argument 'CLIP'"),
    "data preview unknown clip": (["data", "preview", "07_01", "--out", "x.png"], "07_01"),
    "train": (["train", "--steps", "many"], "--steps"),
    "export-model": (["export-model", "missing.pt"], "nothing to write"),
    "average-models": (["average-models", "a.pt", "b.pt", "--out", "soup.pt"], "a.pt"),
    "benchmark": (["benchmark", "make", "--out", "files"], "Missing option '--data'"),
}


@pytest.mark.parametrize("case", list(BAD_INVOCATIONS))
def test_bad_invocation_is_one_error_line_and_exit_1(case, tmp_path, monkeypatch):
    args, names = BAD_INVOCATIONS[case]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cmu").mkdir()
    res = invoke(*args, env={"SMPLIK_CMU_DIR": str(tmp_path / "cmu"), "COLUMNS": "80"})
    assert res.exit_code == 1, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and names in lines[0], res.stderr
    assert "Traceback" not in res.output


def test_console_script_error_line_and_exit_status():
    res = subprocess.run([sys.executable, "-m", "smplik.cli", "data", "preview"], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 1 and res.stdout == ""
    assert res.stderr.strip().splitlines() == [
        "error: Missing argument 'CLIP'. (see 'smplik data preview --help')"]
