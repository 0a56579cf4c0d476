"""One-line errors for a user's mistakes: the ``smplik`` top level and every command report through here.

A *user error* is one of the project's own error classes (a ``ValueError`` subclass defined in
``smplik``, ``workflows`` or ``shape_inversion``, e.g. ``ModelFileError``, ``SceneError``,
``SkeletonError``, ``EstimateFormatError``, ``EffectorError``; plus ``RenderError``), an OS error on a
user's path (``PermissionError``, ``IsADirectoryError``, ``FileExistsError``, ``NotADirectoryError``,
``FileNotFoundError``, a full disk, ...), a corrupt zip (``zipfile.BadZipFile``), invalid or too deeply
nested JSON (``json.JSONDecodeError``, ``RecursionError``) or an unreadable image
(``PIL.UnidentifiedImageError``). It becomes ONE line on stderr, ``error: <message>``, and exit status
1. Anything else is a bug and keeps its traceback. User text is escaped before rich prints it, so a
``[/red]`` in a file name is printed as is.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import zipfile
from collections.abc import Iterator
from typing import NoReturn

import typer
from rich.console import Console
from rich.markup import escape

PROJECT_PACKAGES = ("smplik", "workflows", "shape_inversion")
OS_ERRORS = (PermissionError, IsADirectoryError, FileExistsError, NotADirectoryError, FileNotFoundError)
_OS_ERRNOS = {errno.ENOSPC, errno.EROFS, errno.ENAMETOOLONG, errno.ELOOP, errno.EACCES, errno.EDQUOT,
              errno.EFBIG, errno.EINVAL, errno.ENOTEMPTY, errno.EXDEV}

console = Console(stderr=True, soft_wrap=True, highlight=False)
_CLICK_EXCEPTION = next(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException")  # typer's click


def is_user_error(exc: BaseException) -> bool:
    """Whether ``exc`` is a user's mistake (module docstring) rather than a bug."""
    if isinstance(exc, ValueError) and type(exc).__module__.split(".")[0] in PROJECT_PACKAGES:
        return True
    if type(exc).__name__ in ("RenderError", "UnidentifiedImageError", "DecompressionBombError"):
        return True
    if isinstance(exc, (*OS_ERRORS, zipfile.BadZipFile, json.JSONDecodeError, RecursionError, UnicodeDecodeError)):
        return True
    return isinstance(exc, OSError) and exc.errno in _OS_ERRNOS


def error_message(exc: BaseException) -> str:
    """The one-line message of a user error, naming the file where the exception knows it."""
    if isinstance(exc, OSError) and type(exc).__module__.split(".")[0] not in PROJECT_PACKAGES:
        where = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
        reason = exc.strerror or str(exc)
        text = f"{where}: {reason}" if where else reason
        if isinstance(exc, NotADirectoryError):
            text += " (a part of the path is a file, not a folder)"
        elif isinstance(exc, IsADirectoryError):
            text += " (give a file path, not a folder)"
    elif isinstance(exc, RecursionError):
        text = "input nested too deeply (RecursionError)"
    elif isinstance(exc, json.JSONDecodeError):
        text = f"invalid JSON ({exc})"
    elif type(exc).__name__ == "UnidentifiedImageError":
        text = f"not a readable image ({exc})"
    elif isinstance(exc, zipfile.BadZipFile):
        text = f"not a readable zip/.npz file ({exc})"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())  # one line


def print_error(message: str) -> None:
    """Print ``error: message`` as one stderr line (``message`` is user text: escaped)."""
    console.print(f"[red]error:[/red] {escape(' '.join(str(message).split()))}", markup=True)


def fail(problem: BaseException | str) -> NoReturn:
    """Print the one-line error and exit with status 1."""
    print_error(error_message(problem) if isinstance(problem, BaseException) else problem)
    raise typer.Exit(1)


def say(message: str) -> None:
    """Print an informational stderr line; ``message`` may hold user text (printed without markup)."""
    console.print(str(message), markup=False)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Inside a command: a user error (or a ``ValueError`` from the library's validation) becomes the one
    line and exit 1 (:func:`fail`); Ctrl-C becomes one ``error: interrupted`` line and exit 130; anything else
    propagates with its traceback."""
    try:
        yield
    except typer.BadParameter as exc:  # raised by a command body: one line too
        fail(exc.format_message())
    except KeyboardInterrupt:  # Ctrl-C: one line, the shell's status for SIGINT; writes are atomic
        from smplik.cli.interrupt import interrupted

        raise typer.Exit(interrupted()) from None
    except (typer.Exit, typer.Abort, SystemExit, _CLICK_EXCEPTION):
        raise
    except Exception as exc:
        if isinstance(exc, ValueError) or is_user_error(exc):
            fail(_with_inputs(error_message(exc)) if _is_foreign(exc) else exc)
        raise


def _is_foreign(exc: BaseException) -> bool:
    """A ``ValueError`` raised by a library (numpy's "SVD did not converge" or "Maximum allowed size exceeded",
    scipy's "Found zero norm quaternions", the OS's "embedded null byte", Python's 4300-digit integer limit):
    its message names no file."""
    return isinstance(exc, ValueError) and not isinstance(exc, OSError) \
        and type(exc).__module__.split(".")[0] not in PROJECT_PACKAGES


def _with_inputs(message: str) -> str:
    """``message`` prefixed with the running command's input files (its path arguments and options that name
    existing files, outputs excluded) when it names none of them, so a library's error says which input it was
    reading."""
    from smplik.cli.outputs import OUTPUT_PARAMS, current_params

    inputs = []
    for name, value in current_params().items():
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if name not in OUTPUT_PARAMS and isinstance(v, os.PathLike) and _is_file(v):
                inputs.append(str(v))
    if not inputs or any(i in message for i in inputs):
        return message
    return f"{', '.join(inputs)}: {message}"


def _is_file(path: os.PathLike) -> bool:
    try:
        return os.path.isfile(path)
    except (OSError, ValueError):
        return False


def run_guarded(app: typer.Typer, args: list[str] | None = None) -> None:
    """Run the command tree (on ``args``, default ``sys.argv[1:]``); a user error becomes one line and
    exit 1, anything else keeps its traceback."""
    try:
        app(args=args)
    except BaseException as exc:
        if isinstance(exc, Exception) and is_user_error(exc):
            print_error(error_message(exc))
            raise SystemExit(1) from None
        raise
