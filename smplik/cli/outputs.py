"""Outputs that cannot destroy inputs: one guard for every ``smplik`` command that writes.

:func:`guard_outputs` is applied to every command of the tree when it is loaded (``smplik.cli.tree.click_command``):

* an output option (:data:`OUTPUT_PARAMS`: ``--out``, ``--render``, ``--preview``, ``--onnx``, ...) given as an
  empty or blank string is a usage error (``Path('')`` would be the current folder: a command would write there
  without being asked);
* before the command runs, an output that resolves to the same file as any input of the command (another
  path parameter naming an existing file, through symlinks and hard links: :func:`os.path.samefile`) is
  refused with one ``error:`` line, so ``smplik invert-shape X.bvh --out X.bvh`` leaves ``X.bvh`` as it was.
  Commands that edit a file in place by design (:data:`IN_PLACE`) may write back to that one input.

The files a command writes *inside* an output folder, and the inputs it discovers while working (a scene's
skeletons), are compared by the command itself with :mod:`smplik.output_files` (``check_writes``,
``staged_folder``), which also makes its multi-file outputs all-new or all-old.
"""

from __future__ import annotations

import contextvars
import os
from pathlib import Path
from typing import Any

import typer

from smplik.output_files import OutputPathError  # one error class for both checks

OUTPUT_PARAMS = frozenset({"out", "render", "render_png", "preview", "onnx", "markdown", "results"})
"""Parameter names (click's, i.e. the function arguments) of the options that name a file or folder to write."""

IN_PLACE = {"scene solve": "scene", "scene edit-keyframe": "animation"}
"""Commands whose output defaults to overwriting one input (``--out`` omitted): that input may be the output."""

__all__ = ["IN_PLACE", "OUTPUT_PARAMS", "OutputPathError", "check_outputs", "current_params", "guard_outputs"]


_PARAMS: contextvars.ContextVar[dict[str, Any] | None] = contextvars.ContextVar("smplik_command_params",
                                                                               default=None)


def current_params() -> dict[str, Any]:
    """The parsed parameters of the command running now (empty outside one): error messages name its inputs."""
    return _PARAMS.get() or {}


def _refuse_empty(param: Any) -> None:
    """Make ``param`` (a typer option) refuse an empty or blank value before it becomes ``Path('.')``."""
    process_value = param.process_value

    def checked(ctx: Any, value: Any) -> Any:
        if isinstance(value, str) and not value.strip():
            raise typer.BadParameter("must not be empty (give the file or folder to write)", ctx=ctx, param=param)
        return process_value(ctx, value)

    param.process_value = checked


def _paths(value: Any) -> list[Path]:
    """The paths held by a parameter value (a path, a string, or a list/tuple of them)."""
    items = value if isinstance(value, (list, tuple)) else [value]
    return [Path(v) for v in items if isinstance(v, (str, Path)) and str(v)]


def _exists(path: Path, *, file: bool = False) -> bool:
    """``path.exists()`` (``is_file()`` with ``file``), False for a name the OS cannot look up (too long, NUL)."""
    try:
        return path.is_file() if file else path.exists()
    except (OSError, ValueError):
        return False


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def check_outputs(command_path: str, params: dict[str, Any]) -> None:
    """Raise :class:`OutputPathError` when an output parameter resolves to an existing input file.

    ``command_path`` is the command's name without the program (``"scene export"``); ``params`` click's
    parsed parameters (name -> value)."""
    outputs = [(name, p) for name in OUTPUT_PARAMS & params.keys() for p in _paths(params[name])]
    outputs = [(name, p) for name, p in outputs if _exists(p)]
    if not outputs:
        return
    allowed = IN_PLACE.get(command_path)
    inputs = [(name, p) for name, value in params.items() if name not in OUTPUT_PARAMS and name != allowed
              for p in _paths(value)]
    for out_name, out in outputs:
        for in_name, inp in inputs:
            if _exists(inp, file=True) and _same_file(out, inp):
                option = "--" + ("render" if out_name == "render_png" else out_name).replace("_", "-")
                raise OutputPathError(f"{option} {out} is the input file {inp} ({in_name.replace('_', '-')}): "
                                      "refusing to overwrite an input; give another output path.")


def guard_outputs(command: Any) -> Any:
    """Apply both checks (module docstring) to ``command`` and its subcommands (click commands)."""
    for param in getattr(command, "params", []):
        if param.name in OUTPUT_PARAMS and param.param_type_name == "option" and "process_value" not in vars(param):
            _refuse_empty(param)
    subcommands = getattr(command, "commands", None)
    if subcommands:
        for sub in subcommands.values():
            guard_outputs(sub)
    elif getattr(command, "callback", None) is not None and "invoke" not in command.__dict__:
        invoke = command.invoke

        def guarded_invoke(ctx: Any) -> Any:
            path = ctx.command_path.split(" ", 1)[1] if " " in ctx.command_path else ctx.command_path
            check_outputs(path, ctx.params)
            token = _PARAMS.set(dict(ctx.params))
            try:
                return invoke(ctx)
            finally:
                _PARAMS.reset(token)

        command.invoke = guarded_invoke
    return command
