"""The ``smplik`` command line: :mod:`smplik.cli.main` builds the tree from the command groups
(``body``, ``data``, ``train``/``export-model``, ``solve``, ``benchmark``, ``invert-shape``, ``scene``,
``demo``); shared option types live in :mod:`smplik.cli.options`."""

from __future__ import annotations

import sys

INTERRUPTED_EXIT = 130
"""Exit status after Ctrl-C (the shell's 128 + SIGINT)."""
INTERRUPTED_MESSAGE = "interrupted (Ctrl-C): stopped; no file was left half-written."


def _unraisable(info: object) -> None:
    """``sys.unraisablehook``: a Ctrl-C that landed in a finalizer or a callback (where Python prints
    "Exception ignored in ..." and carries on, e.g. during an import) is raised again in the main thread, so it
    stops the command like any other Ctrl-C; other unraisable errors are reported as usual."""
    exc_type = getattr(info, "exc_type", None)
    if isinstance(exc_type, type) and issubclass(exc_type, KeyboardInterrupt):
        import _thread

        _thread.interrupt_main()
        return
    sys.__unraisablehook__(info)  # type: ignore[arg-type]


_reported: list[bool] = []


def interrupted() -> int:
    """Print the one Ctrl-C line (plainly: rich may be the module being imported; once per run, whichever layer
    sees the interrupt first) and return the exit status."""
    if not _reported:
        _reported.append(True)
        try:
            sys.stderr.write(f"error: {INTERRUPTED_MESSAGE}\n")
            sys.stderr.flush()
        except (OSError, ValueError):
            pass
    return INTERRUPTED_EXIT


def main() -> None:
    """Console-script entry point (imports the command tree lazily). Ctrl-C at any moment, imports included,
    prints one ``error:`` line and exits with status 130."""
    sys.unraisablehook = _unraisable
    try:
        from smplik.cli.main import main as _main

        _main()
        code: object = 0
    except KeyboardInterrupt:
        code = interrupted()
    except SystemExit as exc:
        code = exc.code
    if code == INTERRUPTED_EXIT and _reported:
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
