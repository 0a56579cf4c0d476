"""Ctrl-C for the ``smplik`` command line: one line, exit status 130, at any moment (module light: no rich)."""

from __future__ import annotations

import sys

INTERRUPTED_EXIT = 130
"""Exit status after Ctrl-C (the shell's 128 + SIGINT)."""
INTERRUPTED_MESSAGE = "interrupted (Ctrl-C): stopped; no file was left half-written."


REINTERRUPT_DELAY_S = 0.05
"""How long after a swallowed Ctrl-C it is raised again in the main thread (once the finalizer has returned)."""


def _interrupt_main_later() -> None:
    import _thread
    import time

    time.sleep(REINTERRUPT_DELAY_S)
    _thread.interrupt_main()


def unraisable_hook(info: object) -> None:
    """``sys.unraisablehook``: a Ctrl-C that landed in a finalizer or a callback (where Python prints
    "Exception ignored in ..." and carries on, e.g. during an import) is raised again in the main thread, so it
    stops the command like any other Ctrl-C; other unraisable errors are reported as usual.

    The new interrupt comes from a helper thread a moment later: raised at once it would land in this hook (and be
    swallowed in turn); one that lands in another finalizer comes back here and is sent again."""
    exc_type = getattr(info, "exc_type", None)
    if isinstance(exc_type, type) and issubclass(exc_type, KeyboardInterrupt):
        import threading

        threading.Thread(target=_interrupt_main_later, name="smplik-reinterrupt", daemon=True).start()
        return
    sys.__unraisablehook__(info)  # type: ignore[arg-type]


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
