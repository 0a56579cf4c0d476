"""The ``smplik`` command tree, built from each component's command group.

Commands are loaded lazily: ``smplik --help`` lists :data:`COMMANDS` without importing any of them, and
``smplik scene export --help`` imports only ``workflows.cli`` (whose top level imports no torch), so help
answers fast. To add a command, add one row to :data:`COMMANDS`.

Help is click's plain layout (flags as flags, ``ARGUMENTS`` in capitals, option names never cut), and
every user error, usage errors included, is one ``error: ...`` line on stderr with exit status 1
(:class:`SmplikGroup`).
"""

from __future__ import annotations

import importlib
import os
import re
import sys
from typing import Any

import typer
from typer.core import TyperArgument, TyperGroup

from smplik.cli.errors import error_message, is_user_error, print_error
from smplik.cli.outputs import guard_outputs

_CLICK = {c.__name__: c for c in typer.BadParameter.__mro__}  # typer's (vendored) click exception classes
ClickException, UsageError, Abort = _CLICK["ClickException"], _CLICK["UsageError"], typer.Abort
NoArgsIsHelpError = next(c for c in UsageError.__subclasses__() if c.__name__ == "NoArgsIsHelpError")

COMMANDS: dict[str, tuple[str, str]] = {
    # name: ("module:attribute" (a typer command function or a typer.Typer group), one-line help)
    "demo": ("workflows.cli:demo_cmd", "The whole chain on built-in material: estimator file -> scenes, BVH."),
    "solve": ("smplik.cli.solve:solve_command", "Solve an SMPL pose for the effectors in a JSON file."),
    "scene": ("workflows.cli:scene_app", "Editable scenes: from estimator outputs, re-solve, render, export."),
    "edit": ("workflows.editor.cli:edit_cmd", "Edit a scene in the browser (needs the edit extra: viser)."),
    "invert-shape": ("shape_inversion.cli:invert_shape", "SMPL-SI: custom skeleton -> SMPL shape (beta) and scale."),
    "body": ("smplik.cli.body:body_app", "Body models: export, inspect and render."),
    "data": ("shape_inversion.data_cli:app", "Motion data: build pose caches from BVH/AMASS, preview retargeting."),
    "train": ("smplik.cli.train:train_command", "Train SMPL-IK on a pose cache (resumable; torchrun for DDP)."),
    "export-model": ("smplik.cli.models:export_command", "Compact inference model and/or ONNX graph of a checkpoint."),
    "average-models": ("smplik.cli.models:average_command", "Average models fine-tuned from one start (model soup)."),
    "benchmark": ("workflows.benchmark_cli:app",
                  "Randomized-effector IK benchmark: make files, run methods, calibrate."),
    "track": ("workflows.tracking.cli:track_cmd", "Full body from VR trackers (head, wrists, pelvis) -> animation."),
    "batch": ("workflows.batch.cli:app", "One job over many inputs (folder, glob, manifest): local pool or Ray."),
}
"""Every top-level command, in the order ``smplik --help`` lists them."""

_TYPE_NAMES = {"int": "INTEGER", "float": "FLOAT", "str": "TEXT", "bool": "BOOLEAN"}
_DEFAULT_IN_HELP = re.compile(r"\s*\(default:?\s+((?:[^()]|\([^()]*\))*)\)")


class _PlainArgument(TyperArgument):
    """An argument shown as click shows it: ``NAME`` (required) or ``[NAME]`` in the usage line, no type."""

    def _usage_display_name(self) -> str:
        return self.display_name_raw if self.required else f"[{self.display_name_raw}]"

    def display_type_rich(self, ctx: Any) -> None:
        return None


def _one_default_style(param: Any) -> None:
    """Write every default as ``[default: X]`` after the help: a "(default: X)" in the help text moves
    there, and a flag that is off by default shows none."""
    if getattr(param, "is_flag", False) and not param.default:
        param.show_default = False
    match = _DEFAULT_IN_HELP.search(param.help or "")
    if match:
        param.help = (param.help[:match.start()] + param.help[match.end():]).rstrip()
        param.help = f"{param.help}  [default: {match.group(1).strip()}]"
        param.show_default = False


def _plain_help(command: Any) -> Any:
    """Give ``command`` (and its subcommands) click's plain help layout and capitalised metavars."""
    command.rich_markup_mode = None
    command.params = [p for p in command.params if p.name not in ("install_completion", "show_completion")]
    for param in command.params:
        _one_default_style(param)
        if type(param) is TyperArgument:
            param.__class__ = _PlainArgument
        if param.metavar is not None or getattr(param, "is_flag", False):
            continue
        if param.param_type_name == "argument":
            param.metavar = param.name.upper() + ("..." if param.nargs != 1 else "")
            continue
        desc = param.type_descriptor
        if desc.is_choice:
            param.metavar = "[" + "|".join(str(getattr(c, "value", c)) for c in desc.choices) + "]"
        elif desc.is_path:
            param.metavar = "FILE" if desc.path_type == "file" else "PATH"
        else:
            param.metavar = _TYPE_NAMES.get(param.bare_type(), param.bare_type().upper())
        if param.nargs != 1 or getattr(param, "multiple", False):
            param.metavar += "..."
    for sub in getattr(command, "commands", {}).values():
        _plain_help(sub)
    return command


def load_command(name: str) -> Any:
    """Import the command ``name`` of :data:`COMMANDS` and return it as a click command."""
    module, attribute = COMMANDS[name][0].split(":")
    obj = getattr(importlib.import_module(module), attribute)
    if not isinstance(obj, typer.Typer):
        single = typer.Typer(add_completion=False)
        single.command(name)(obj)
        obj = single
    command = typer.main.get_command(obj)
    command.name = name
    return guard_outputs(_plain_help(command))


class SmplikGroup(TyperGroup):
    """The top-level group: lazy commands, plain help, and one ``error:`` line with exit 1 for every user
    error (click usage errors, the project's own errors, OS errors on user paths)."""

    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def make_context(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().make_context(*args, **kwargs)
        except KeyboardInterrupt:  # before typer turns it into a silent exit 130 (click: Abort, an empty line)
            raise _Interrupted from None

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:  # the same while a command's module is imported or its arguments parsed
            raise _Interrupted from None

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        return load_command(cmd_name) if cmd_name in COMMANDS else None

    def format_commands(self, ctx: Any, formatter: Any) -> None:
        with formatter.section("Commands"):
            formatter.write_dl([(name, short) for name, (_, short) in COMMANDS.items()])

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:
        code = run_command_tree(super().main, args=args, prog_name="smplik", complete_var=complete_var,
                                **extra)
        if standalone_mode:
            sys.exit(code)
        return code


class _Interrupted(Exception):
    """Ctrl-C outside a command's own handling (while its module is imported, its arguments parsed)."""


def run_command_tree(main: Any, **kwargs: Any) -> int:
    """Run a click ``main`` in non-standalone mode; return the exit status. A user error (including a click
    usage error) prints one ``error:`` line and gives 1; Ctrl-C one line and 130; a bug keeps its traceback."""
    from smplik.cli.interrupt import interrupted

    try:
        result = main(standalone_mode=False, **kwargs)
    except (_Interrupted, KeyboardInterrupt):
        return interrupted()
    except NoArgsIsHelpError as exc:  # a group named without a command: its help
        print(exc.ctx.get_help())
        return 0
    except UsageError as exc:
        hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
        print_error(exc.format_message().rstrip(".") + "." + hint)
        return 1
    except ClickException as exc:
        print_error(exc.format_message())
        return 1
    except Abort as exc:
        if isinstance(exc.__context__, KeyboardInterrupt):
            return interrupted()
        print_error("aborted")
        return 1
    except Exception as exc:
        if is_user_error(exc):
            print_error(error_message(exc))
            return 1
        raise
    return result if isinstance(result, int) else 0


app = typer.Typer(cls=SmplikGroup, help="Morphology-aware learned IK on the SMPL body model.", no_args_is_help=True,
                  pretty_exceptions_enable=False, rich_markup_mode=None, add_completion=False)


def _print_version(value: bool) -> None:
    """``smplik --version``: the installed distribution's version (importlib.metadata), then exit."""
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            text = version("smplik")
        except PackageNotFoundError:  # run from a checkout that was never installed
            text = "unknown (not installed: pip install -e .)"
        print(f"smplik {text}")
        raise typer.Exit(0)


@app.callback()
def _root(
    show_version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                      help="Print the version and exit."),
) -> None:
    """Morphology-aware learned IK on the SMPL body model."""


def main() -> None:
    """Console-script entry point."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless rendering by default
    app(prog_name="smplik")
