"""The README's first command installs smplik without extras (``pip install -e .``); the demo's printout then
says ``smplik edit demo_out/character/scene.json``. Without the ``[edit]`` extra that command must say what to
install, in one line, in the words of the README (a checkout install), not crash."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_edit_without_the_edit_extra_says_what_to_install(tmp_path, demo):
    no_viser = tmp_path / "no_viser"  # a base install: importing viser fails as it does when it is absent
    no_viser.mkdir()
    (no_viser / "viser.py").write_text("raise ModuleNotFoundError(\"No module named 'viser'\", name='viser')\n")
    args = demo.printed_command("edit")
    env = dict(os.environ, COLUMNS="80", PYTHONPATH=os.pathsep.join((str(no_viser), str(REPO))))
    proc = subprocess.run([sys.executable, "-m", "smplik.cli", "edit", *args], cwd=demo.cwd, env=env,
                          capture_output=True, text=True, timeout=1200, check=False)
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stdout + proc.stderr
    assert lines[0].startswith("error: smplik edit needs viser") and "pip install -e '.[edit]'" in lines[0], lines
