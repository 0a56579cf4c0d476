"""The ``smplik`` command tree, built from each component's command group.

The command table is :data:`workflows.commands.COMMANDS`, at the top layer, where every command's module is a
real import (inside its loader function, so the layering test sees it); this entry point reads it with its one
import of the top layer. Commands are loaded lazily: ``smplik --help`` lists the table without importing any
command, and ``smplik scene export --help`` imports only ``workflows.cli`` (whose top level imports no torch),
so help answers fast. To add a command, add one row to :data:`workflows.commands.COMMANDS`.

Help is click's plain layout (flags as flags, ``ARGUMENTS`` in capitals, option names never cut), and
every user error, usage errors included, is one ``error: ...`` line on stderr with exit status 1
(:class:`SmplikGroup`).
"""

from __future__ import annotations

import os
import sys
from typing import Any

import typer
from typer.core import TyperGroup

from smplik.cli.errors import error_message, is_user_error, print_error
from workflows import commands  # the command table (top layer): the composition root's one upward import

_CLICK = {c.__name__: c for c in typer.BadParameter.__mro__}  # typer's (vendored) click exception classes
ClickException, UsageError, Abort = _CLICK["ClickException"], _CLICK["UsageError"], typer.Abort
NoArgsIsHelpError = next(c for c in UsageError.__subclasses__() if c.__name__ == "NoArgsIsHelpError")

COMMANDS = commands.COMMANDS
"""Every top-level command, in the order ``smplik --help`` lists them (:data:`workflows.commands.COMMANDS`)."""
load_command = commands.load_command


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
