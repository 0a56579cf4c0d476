"""`.ci/run` cannot be fooled by what the CI machine has installed: it runs the README's test command inside a
virtual environment it has just created (``python -m venv`` in a temporary folder), activated first."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

CI = Path(__file__).resolve().parents[1] / ".ci" / "run"
TEST_COMMAND = 'pip install torch==2.13.0 -e ".[dev]" && python -m pytest -q'


def test_ci_runs_the_test_command_in_a_fresh_virtual_environment():
    lines = [line.strip() for line in CI.read_text().splitlines()]
    made = next(i for i, line in enumerate(lines) if "-m venv" in line and '"$venv"' in line)
    temporary = next(i for i, line in enumerate(lines) if line.startswith("venv=") and "mktemp -d" in line)
    activated = next(i for i, line in enumerate(lines) if line == '. "$venv/bin/activate"')
    command = lines.index(TEST_COMMAND)
    assert temporary < made < activated < command
    assert not any("--system-site-packages" in line for line in lines)


@pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")
def test_ci_script_is_valid_bash():
    res = subprocess.run(["bash", "-n", str(CI)], capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
