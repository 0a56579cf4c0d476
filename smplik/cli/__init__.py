"""The ``smplik`` command line: :mod:`smplik.cli.main` builds the tree from the command groups
(``body``, ``data``, ``train``/``export-model``, ``solve``, ``benchmark``, ``invert-shape``, ``scene``,
``demo``); shared option types live in :mod:`smplik.cli.options`."""

from __future__ import annotations


def main() -> None:
    """Console-script entry point (imports the command tree lazily)."""
    from smplik.cli.main import main as _main

    _main()
