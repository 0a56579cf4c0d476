"""Journey: ``smplik --version``, the first thing asked of a bug report: the installed distribution's version."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import pytest


def test_smplik_version_prints_the_installed_version(smplik):
    try:
        expected = version("smplik")
    except PackageNotFoundError:
        pytest.skip("smplik is not installed in this environment (pip install -e .)")
    run = smplik("--version")
    assert run.stdout == f"smplik {expected}\n" and run.stderr == ""
    assert "--version" in smplik("--help").stdout
