"""How a character file is read: one options dataclass and one set of CLI options for every command.

:class:`CharacterOptions` is used by ``smplik invert-shape``, ``smplik scene from-estimate
--character`` (stored in ``scene.json`` so ``scene solve`` / ``scene export`` re-read the
character identically) and any other command taking a character. Commands declare the options
once, through :func:`with_character_options`: the command takes one parameter ``character_cli``
(a :data:`CharacterCLI`) that becomes the nine options ``--rig`` ... ``--root`` in its place, and builds
the dataclass where it wants the options checked::

    @with_character_options
    def cmd(character: Path, character_cli: CharacterCLI = NO_CHARACTER_CLI, ...):
        options = character_cli()  # typer.BadParameter naming the option when invalid
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from smplik.limits import DEFAULT_MAX_JOINTS
from smplik.units import UNIT_NAMES, parse_units

RestSource = Literal["auto", "frame0", "offsets"]
BindSource = Literal["inverse_bind", "nodes"]
PositionMode = Literal["auto", "replace", "add"]


class CharacterOptionsError(ValueError):
    """A character option has an invalid value; the message names the option."""


@dataclass(frozen=True)
class CharacterOptions:
    """How to read and map a character file (every field has the CLI option of the same name)."""

    rig: str | None = None
    """Joint-name preset (``mixamo``, ``cmu``, ...); None: detected from the names (and topology)."""
    map: str | None = None
    """A JSON map file ``{smpl_joint: rig_joint}`` instead of a preset."""
    units: str = "auto"
    """``auto`` (from the stature), a unit name (m, dm, cm, mm, in, ft, cmu) or metres per unit."""
    up: str = "auto"
    """``auto`` or the file's up axis (``y``, ``z``, ``-z``, ...)."""
    rest: RestSource = "auto"
    """BVH rest pose: frame 0 through forward kinematics, the zero-rotation OFFSETs, or ``auto`` (frame 0 when
    it is a rest pose, else the OFFSETs; see :func:`shape_inversion.skeleton_io.read_character`)."""
    bind: BindSource = "inverse_bind"
    """glTF bind pose: the inverse bind matrices, or the joint nodes' default transforms."""
    positions: PositionMode = "auto"
    """BVH non-root position channels: replace the OFFSET (BVH convention), add to it (MakeHuman), or auto."""
    max_joints: int = DEFAULT_MAX_JOINTS
    """Refuse files with more joints than this."""
    root: str | None = None
    """With several root joints: the name of the one whose hierarchy is the character (None: chosen)."""

    def __post_init__(self) -> None:
        def bad(option: str, value: Any, expected: str) -> CharacterOptionsError:
            return CharacterOptionsError(f"character option {option}: {str(value)[:60]!r} is invalid; "
                                         f"expected {expected}")

        for name in ("rig", "map", "root"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, str):
                raise bad(name, value, "a string or null")
        if self.rig is not None and self.map is not None:
            raise CharacterOptionsError("character options rig and map: give either a rig preset or a map file, "
                                        "not both")
        if not isinstance(self.units, str):
            raise bad("units", self.units, "a string")
        if self.units.lower() != "auto":
            try:
                parse_units(self.units, CharacterOptionsError)
            except CharacterOptionsError as exc:
                raise CharacterOptionsError(f"character option units: {exc}") from None
        if not isinstance(self.up, str) or self.up.strip().lower().lstrip("+-") not in ("auto", "x", "y", "z") \
                or self.up.strip().lower() in ("-auto", "+auto"):
            raise bad("up", self.up, "auto, x, y, z, optionally signed (-z)")
        for name, allowed in (("rest", ("auto", "frame0", "offsets")), ("bind", ("inverse_bind", "nodes")),
                              ("positions", ("auto", "replace", "add"))):
            if getattr(self, name) not in allowed:
                raise bad(name, getattr(self, name), " or ".join(allowed))
        if isinstance(self.max_joints, bool) or not isinstance(self.max_joints, int) or self.max_joints < 1:
            raise bad("max_joints", self.max_joints, "a positive integer")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CharacterOptions:
        """Options from a dict of field values (unknown keys refused, naming them)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise CharacterOptionsError(f"unknown character option(s) {unknown}; allowed: {sorted(names)}")
        return cls(**data)


RigOption = Annotated[str | None, typer.Option("--rig", help="Joint-name preset of the character (default: detected "
                                               "from its joint names and topology).")]
MapOption = Annotated[Path | None, typer.Option("--map", help="JSON map {smpl_joint: rig_joint} for the character.",
                                                dir_okay=False)]
UnitsOption = Annotated[str, typer.Option("--units", help=f"Character units: auto, {', '.join(UNIT_NAMES)}, or "
                                          "metres per unit.")]
UpOption = Annotated[str, typer.Option("--up", help="Character up axis: auto, or x, y, z, -z, ...")]
RestOption = Annotated[str, typer.Option("--rest", help="BVH rest pose: auto (frame 0 when it is a rest pose, "
                                         "else the OFFSETs), frame0 or offsets.")]
BindOption = Annotated[str, typer.Option("--bind", help="glTF bind pose: inverse_bind or nodes.")]
PositionsOption = Annotated[str, typer.Option("--positions", help="BVH non-root position channels: auto, replace "
                                              "(BVH convention, Mixamo/Rokoko) or add (MakeHuman).")]
MaxJointsOption = Annotated[int, typer.Option("--max-joints", help="Refuse character files with more joints.")]
RootOption = Annotated[str | None, typer.Option("--root", help="Character with several root joints: the root "
                                                "joint whose hierarchy to use (default: the one holding the body).")]


def character_options_from_cli(rig: str | None = None, map_file: Path | None = None, units: str = "auto",
                               up: str = "auto", rest: str = "auto", bind: str = "inverse_bind",
                               positions: str = "auto", max_joints: int = DEFAULT_MAX_JOINTS,
                               root: str | None = None) -> CharacterOptions:
    """:class:`CharacterOptions` from the CLI options above; raises :class:`typer.BadParameter` naming the option."""
    try:
        return CharacterOptions(rig=rig, map=None if map_file is None else str(map_file), units=units, up=up,
                                rest=rest, bind=bind, positions=positions, max_joints=max_joints,  # type: ignore[arg-type]
                                root=root)
    except CharacterOptionsError as exc:
        raise typer.BadParameter(str(exc)) from None


CharacterCLI = Callable[[], CharacterOptions]
"""What a command decorated by :func:`with_character_options` receives: call it for the :class:`CharacterOptions`
of the options given (raises :class:`typer.BadParameter` naming the option when one is invalid)."""
NO_CHARACTER_CLI: CharacterCLI = CharacterOptions
"""The placeholder default of a ``character_cli`` parameter (the decorator always passes the given values)."""

_CLI_OPTIONS: tuple[tuple[str, Any], ...] = (
    ("rig", RigOption), ("map_file", MapOption), ("units", UnitsOption), ("up", UpOption), ("rest", RestOption),
    ("bind", BindOption), ("positions", PositionsOption), ("max_joints", MaxJointsOption), ("root", RootOption))


def with_character_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """The character options, declared once for every command that reads a character.

    ``command``'s parameter ``character_cli`` is replaced, at its place in the signature typer reads, by the
    options ``--rig``, ``--map``, ``--units``, ``--up``, ``--rest``, ``--bind``, ``--positions``,
    ``--max-joints`` and ``--root`` (defaults those of :class:`CharacterOptions`); the command receives their
    values as one :data:`CharacterCLI`, which builds the options when called.
    """
    signature = inspect.signature(command, eval_str=True)
    defaults = inspect.signature(character_options_from_cli).parameters
    params: list[inspect.Parameter] = []
    for param in signature.parameters.values():
        if param.name == "character_cli":
            params += [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=defaults[name].default,
                                         annotation=annotation) for name, annotation in _CLI_OPTIONS]
        else:
            params.append(param.replace(kind=inspect.Parameter.KEYWORD_ONLY))
    if len(params) == len(signature.parameters):
        raise TypeError(f"{command.__name__} has no parameter character_cli")
    names = [name for name, _ in _CLI_OPTIONS]

    @functools.wraps(command)
    def wrapper(**kwargs: Any) -> Any:
        values = {name: kwargs.pop(name) for name in names}
        return command(**kwargs, character_cli=functools.partial(character_options_from_cli, **values))

    wrapper.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
    wrapper.__annotations__ = {p.name: p.annotation for p in params} | {"return": signature.return_annotation}
    return wrapper
