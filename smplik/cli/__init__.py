"""The ``smplik`` command line: :mod:`smplik.cli.main` builds the tree from the command groups
(``body``, ``data``, ``train``/``export-model``, ``solve``, ``benchmark``, ``invert-shape``, ``scene``,
``demo``); shared option types live in :mod:`smplik.cli.options`."""

from __future__ import annotations

import sys

from smplik.cli.interrupt import INTERRUPTED_EXIT, interrupted, reported, unraisable_hook


def main() -> None:
    """Console-script entry point (imports the command tree lazily). Ctrl-C at any moment, imports included,
    prints one ``error:`` line and exits with status 130."""
    sys.unraisablehook = unraisable_hook
    try:
        from smplik.cli.main import main as _main

        _main()
        code: object = 0
    except KeyboardInterrupt:
        code = interrupted()
    except SystemExit as exc:
        code = exc.code
    if code == INTERRUPTED_EXIT and reported():
        # CPython marks a Ctrl-C that hit code run by exec() (a dataclass being built during an import) as
        # unhandled even once caught, and then kills itself with SIGINT at exit: leave with 130 directly (every
        # file was already closed or removed by the commands' context managers).
        import os

        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError, AttributeError):
                pass
        os._exit(INTERRUPTED_EXIT)
    raise SystemExit(code)
