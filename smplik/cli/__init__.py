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
    if "torch" in sys.modules:
        leave(code)
    raise SystemExit(code)


def leave(code: object) -> None:
    """Exit with ``code`` as ``SystemExit`` would, without tearing the interpreter's modules down: after torch was
    imported that teardown costs 0.4-0.6 CPU s of every command (``benchmarks/animation_real_speed.py``). What an
    exit must still do is done first: thread pools are shut down and other non-daemon threads joined
    (``threading._shutdown``, as the interpreter's exit), the ``atexit`` functions run
    (``weakref.finalize`` and temporary folders included), the standard streams are flushed. Every file a command
    writes is closed (atomic writes) before this point."""
    import atexit
    import os
    import threading

    shutdown, run = getattr(threading, "_shutdown", None), getattr(atexit, "_run_exitfuncs", None)
    if shutdown is None or run is None:  # another interpreter: the ordinary exit
        raise SystemExit(code)
    shutdown()  # what the interpreter's exit does first: thread-pool exits, then non-daemon threads joined
    run()
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # SystemExit("message"): printed, status 1
        print(code, file=sys.stderr)
        status = 1
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(status & 0xFF)
