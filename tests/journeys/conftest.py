"""Journeys: the commands the README, the docs and the demo's printout tell a user to run, one after the other,
each on the files the previous one wrote, checked for what the user would look at.

Every command runs as the user runs it: a separate process of the ``smplik`` command line
(``python -m smplik.cli``, the console script's ``main``), 80 columns wide like a terminal, its output
captured. The demo, slow-ish, runs once per session (:func:`demo`).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HANG_S = 1200
"""Guard against a hung command only (never a speed check): far above any run on a loaded 2-core machine."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every journey is in the slow tier (``-m "not slow"`` leaves them out): each runs several processes."""
    here = Path(__file__).resolve().parent
    for item in items:
        if here in Path(item.path).resolve().parents:
            item.add_marker(pytest.mark.slow)


@dataclass(frozen=True)
class Run:
    """A finished ``smplik`` command: exit status and what it printed."""

    args: tuple[str, ...]
    returncode: int
    stdout: str
    stderr: str

    @property
    def output(self) -> str:
        """Everything the user saw (stderr carries smplik's status lines, stdout the results)."""
        return self.stdout + self.stderr

    def describe(self) -> str:
        return (f"smplik {' '.join(self.args)} -> exit {self.returncode}\n--- stdout\n{self.stdout}\n"
                f"--- stderr\n{self.stderr}")


def user_env(**extra: str) -> dict[str, str]:
    """The environment of a user's terminal: 80 columns, this checkout importable, headless rendering."""
    env = dict(os.environ)
    env.update(COLUMNS="80", PYOPENGL_PLATFORM=env.get("PYOPENGL_PLATFORM", "egl"))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    env.pop("FORCE_COLOR", None)
    env.update(extra)
    return env


def smplik_command(*args: str | Path) -> list[str]:
    """The argv of ``smplik ARGS`` (the console script's entry point, run by this interpreter)."""
    return [sys.executable, "-m", "smplik.cli", *(str(a) for a in args)]


@pytest.fixture(scope="session")
def smplik() -> Callable[..., Run]:
    """``smplik(*args, cwd=None, ok=True)`` runs ``smplik ARGS`` in its own process; with ``ok`` it fails the
    test, showing the output, unless the command exits 0."""

    def run(*args: str | Path, cwd: Path | None = None, ok: bool = True) -> Run:
        proc = subprocess.run(smplik_command(*args), cwd=cwd, env=user_env(), capture_output=True, text=True,
                              timeout=HANG_S, check=False)
        result = Run(tuple(str(a) for a in args), proc.returncode, proc.stdout, proc.stderr)
        if ok and proc.returncode != 0:
            pytest.fail(result.describe())
        return result

    return run


@pytest.fixture(scope="session")
def smplik_process() -> Callable[..., subprocess.Popen]:
    """``smplik_process(*args, cwd=...)`` starts ``smplik ARGS`` as a user does (a server such as ``smplik
    edit``) and returns the running process, its stdout and stderr as text pipes; the test stops it."""

    def start(*args: str | Path, cwd: Path) -> subprocess.Popen:
        return subprocess.Popen(smplik_command(*args), cwd=cwd, env=user_env(), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)

    return start


@dataclass(frozen=True)
class Demo:
    """``smplik demo --out demo_out`` once: the folder it ran in (``cwd``), its output folder and its printout."""

    cwd: Path
    out: Path
    printout: str

    def printed_command(self, command: str) -> list[str]:
        """The arguments of a ```smplik COMMAND ...``` the printout tells the user to run."""
        match = re.search(rf"`smplik {re.escape(command)} ([^`]+)`", self.printout)
        assert match, f"the demo's printout names no `smplik {command} ...`:\n{self.printout}"
        return match.group(1).split()


@pytest.fixture(scope="session")
def demo(smplik, tmp_path_factory) -> Demo:
    """The demo, as the README's first command runs it (``smplik demo --out demo_out``), in a fresh folder."""
    shipped = REPO / "smplik" / "checkpoints" / "smplik_cmu.pt"
    if not shipped.is_file():
        pytest.skip(f"the shipped model {shipped} is absent (a checkout without its model file)")
    cwd = tmp_path_factory.mktemp("user")
    run = smplik("demo", "--out", "demo_out", cwd=cwd)
    return Demo(cwd, cwd / "demo_out", run.output)
