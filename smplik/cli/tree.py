"""Typer command functions and groups as click commands with the ``smplik`` tree's help layout.

:func:`click_command` is what every entry of the command table (:mod:`workflows.commands`) goes through when
it is loaded: click's plain help (flags as flags, ``ARGUMENTS`` in capitals, one default style) and the output
guard of :mod:`smplik.cli.outputs`. Importing this module imports no numpy or torch.
"""

from __future__ import annotations

import re
from typing import Any

import typer
from typer.core import TyperArgument

from smplik.cli.outputs import guard_outputs

__all__ = ["click_command"]

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


def click_command(obj: Any, name: str) -> Any:
    """``obj`` (a typer command function or a ``typer.Typer`` group) as the click command ``name`` of the tree."""
    if not isinstance(obj, typer.Typer):
        single = typer.Typer(add_completion=False)
        single.command(name)(obj)
        obj = single
    command = typer.main.get_command(obj)
    command.name = name
    return guard_outputs(_plain_help(command))
