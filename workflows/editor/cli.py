"""``smplik edit``: the interactive pose editor in the browser (needs the ``edit`` extra: viser)."""

from __future__ import annotations

import ipaddress
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console

from shape_inversion.options import NO_CHARACTER_CLI, CharacterCLI, with_character_options
from smplik.cli.errors import fail

if TYPE_CHECKING:
    from workflows.editor.app import EditorApp
    from workflows.editor.timeline import AnimationTimeline

app = typer.Typer(help="Interactive pose editor.")
console = Console(stderr=True, soft_wrap=True)  # status lines are never cut mid-number


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and 'localhost'."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@app.command("edit")
@with_character_options
def edit_cmd(
    scene: Annotated[Path | None, typer.Argument(help="Scene JSON to edit (a new file: start from a T-pose body "
                                                      "and create it on Save; none: ./scene.json), or an "
                                                      "animation.json of scene animate (a timeline).")] = None,
    host: Annotated[str, typer.Option("--host", help="Address to listen on (0.0.0.0: the whole network).")]
    = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="Port (0: any free port).")] = 8080,
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Model file (default: the shipped model).")]
    = None,
    character: Annotated[Path | None, typer.Option("--character", help="Add a custom character (BVH, glTF, JSON "
                                                                       "skeleton) fitted by SMPL-SI.")] = None,
    character_cli: CharacterCLI = NO_CHARACTER_CLI,
    output_dir: Annotated[list[Path] | None, typer.Option(
        "--output-dir", help="A folder Save and Export may also write in (repeatable; default: only the scene's "
                             "folder).")] = None,
) -> None:
    """Edit a scene in the browser: drag effectors, shape sliders, recovery, undo/redo, Save, Export. An animation
    (scene animate) opens with a timeline: play, scrub, keyframes, drag, blend window, Apply."""
    import dataclasses

    import numpy as np

    from workflows.cli_shared import _solver
    from workflows.scene import SceneCharacter, SkeletonSource, load_scene

    try:
        from workflows.editor.app import EditorApp
    except ModuleNotFoundError as exc:
        if exc.name != "viser":
            raise
        fail("smplik edit needs viser: pip install -e '.[edit]' in the smplik checkout "
             "(or pip install viser websockets).")
    from workflows.editor.state import EditorError, EditorState, fresh_scene

    path = scene if scene is not None else Path("scene.json")
    if path.suffix.lower() != ".json":
        fail(f"SCENE must be a .json file, got {path}.")
    solver = None
    if path.exists():  # an animation (smplik scene animate): the editor with a timeline
        from workflows.editor.timeline import AnimationTimeline

        solver = _solver(checkpoint)
        try:
            timeline = AnimationTimeline.open_if_animation(path, solver)
        except ValueError as exc:
            fail(exc)
        if timeline is not None:
            if character is not None:
                fail(f"{path} is an animation: --character applies to scenes (give it to smplik scene animate).")
            _serve_timeline(timeline, solver, host, port, (path.resolve().parent, *(output_dir or ())))
            return
    try:
        loaded = load_scene(path) if path.exists() else None
    except ValueError as exc:
        fail(exc)
    if character is not None:
        from workflows.character import load_character

        options = character_cli()
        try:
            custom = load_character(character, options)
        except (ValueError, OSError) as exc:
            fail(exc)
        from shape_inversion.rigs import available_presets

        if options.map is None and custom.rig.name in available_presets():  # a re-read skips detection
            options = dataclasses.replace(options, rig=custom.rig.name)
        added = SceneCharacter(character.stem, custom.gender, np.asarray(custom.betas, np.float64), custom.scale,
                               SkeletonSource.from_options(str(character.resolve()), options))
        loaded = dataclasses.replace(loaded, characters=loaded.characters + (added,)) if loaded is not None \
            else dataclasses.replace(fresh_scene(), characters=(added,))
    if loaded is None:
        console.print(f"{path} does not exist: editing a new T-pose body; Save writes {path}.", highlight=False,
                      soft_wrap=True)
        loaded = fresh_scene()
    solver = solver or _solver(checkpoint)
    _one_thread()
    try:
        state = EditorState(loaded, solver, path=path)
        write_dirs = (path.resolve().parent, *(output_dir or ()))
        editor = EditorApp(state, host=host, port=port, write_dirs=write_dirs)
    except (EditorError, OSError) as exc:
        fail(exc)
    _serve(editor, host)


def _one_thread() -> None:
    import torch
    from threadpoolctl import threadpool_limits

    # One pose per solve: a second torch thread does not help (benchmarks/speed.py), and a 2-thread BLAS
    # slows the skinning several times over when other processes share the cores.
    torch.set_num_threads(1)
    threadpool_limits(1)


def _serve_timeline(timeline: AnimationTimeline, solver: Any, host: str, port: int,
                    write_dirs: tuple[Path, ...]) -> None:
    """``smplik edit ANIMATION.json``: the editor with a timeline (:mod:`workflows.editor.timeline_app`)."""
    from workflows.editor.state import EditorError
    from workflows.editor.timeline_app import AnimationEditorApp

    _one_thread()
    try:
        editor = AnimationEditorApp(timeline, solver, host=host, port=port, write_dirs=write_dirs)
    except (EditorError, OSError) as exc:
        fail(exc)
    _serve(editor, host)


def _serve(editor: EditorApp, host: str) -> None:
    """Print the editor's URL and serve until Ctrl+C."""
    if not is_loopback(host):
        console.print(f"[yellow]warning:[/yellow] listening on {host}: anyone who can reach this machine on port "
                      f"{editor.port} can edit the scene and save files.", highlight=False, soft_wrap=True)
    typer.echo(f"smplik editor: {editor.url}  (open this URL: its token is the only way in; Ctrl+C to stop)")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        editor.stop()
