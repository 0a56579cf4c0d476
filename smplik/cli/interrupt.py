"""Ctrl-C for the ``smplik`` command line: one line, exit status 130, at any moment (module light: no rich)."""

from __future__ import annotations

import sys

INTERRUPTED_EXIT = 130
"""Exit status after Ctrl-C (the shell's 128 + SIGINT)."""
INTERRUPTED_MESSAGE = "interrupted (Ctrl-C): stopped; no file was left half-written."


def unraisable_hook(info: object) -> None:
    """``sys.unraisablehook``: a Ctrl-C that landed in a finalizer or a callback (where Python prints
    "Exception ignored in ..." and carries on, e.g. during an import) is raised again in the main thread, so it
    stops the command like any other Ctrl-C; other unraisable errors are reported as usual."""
    exc_type = getattr(info, "exc_type", None)
    if isinstance(exc_type, type) and issubclass(exc_type, KeyboardInterrupt):
        import _thread

        _thread.interrupt_main()
        return
    sys._unraisable_hookhook__(info)  # type: ignore[arg-type]


_reported: list[bool] = []


def reported() -> bool:
    """Whether :func:`interrupted` printed its line in this run."""
    return bool(_reported)


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
