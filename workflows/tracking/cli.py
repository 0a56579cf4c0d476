"""``smplik track``: full body from a few VR trackers (logic in :mod:`workflows.tracking.run`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from shape_inversion.options import NO_CHARACTER_CLI, CharacterCLI, with_character_options
from smplik.cli.errors import say, user_errors


@with_character_options
def track_cmd(
    trackers: Annotated[Path | None, typer.Argument(help="Tracker recording: smplik-trackers JSON (docs/formats.md), "
                                                    "a SteamVR JSON-lines log (.jsonl) or a VR CSV recording (.csv, "
                                                    "docs/tracking.md). Not with --live.")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Output folder (animation.json and the exports); "
                                             "required without --live.")] = None,
    samples: Annotated[int, typer.Option("--samples", help="Latent samples run in one batch; above 1: sample "
                                         "selection with a 10-frame look-ahead.")] = 1,
    betas: Annotated[str | None, typer.Option("--betas", help="The user's SMPL shape, 10 comma-separated numbers "
                                              "(default zeros).")] = None,
    gender: Annotated[str, typer.Option("--gender", help="neutral, male or female.")] = "neutral",
    character: Annotated[Path | None, typer.Option("--character", help="Custom skeleton (BVH, glTF, JSON): animate "
                                                   "its SMPL-SI body; trackers in its units.")] = None,
    character_cli: CharacterCLI = NO_CHARACTER_CLI,
    export: Annotated[str, typer.Option("--export", help="Animated files, comma-separated: bvh, glb; '' for "
                                        "none.")] = "bvh",
    seed: Annotated[int, typer.Option("--seed", help="Seed of the latent samples.")] = 0,
    fit_trackers: Annotated[bool, typer.Option("--fit-trackers", help="Set the root, wrists and head from the "
                                               "trackers (two-bone arm IK).")] = False,
    checkpoint: Annotated[Path | None, typer.Option("--checkpoint", help="Tracking model file (default: "
                                                    "the shipped model for the recording's trackers).")] = None,
    foot_locks: Annotated[str, typer.Option("--foot-locks", help="offline (knowing the whole recording), "
                                            "streaming (causal, what --live uses) or off.")] = "offline",
    live: Annotated[bool, typer.Option("--live", help="Live: trackers from --vmc-in (VMC over UDP) or SteamVR "
                                       "JSON lines on stdin, the body to --vmc-out (docs/vmc.md).")] = False,
    vmc_in: Annotated[str | None, typer.Option("--vmc-in", help="Live: receive VMC device messages on PORT "
                                               "(127.0.0.1) or HOST:PORT (0.0.0.0: every interface); "
                                               "without it: SteamVR JSON lines on stdin.")] = None,
    vmc_out: Annotated[str | None, typer.Option("--vmc-out", help="Live: send the VMC bones to HOST:PORT "
                                                "(a receiver's port, e.g. 127.0.0.1:39539).")] = None,
    left_serial: Annotated[str | None, typer.Option("--left-serial", help="Live: serial of the left controller "
                                                    "(default: the one on the headset's left).")] = None,
    right_serial: Annotated[str | None, typer.Option("--right-serial", help="Live: serial of the right "
                                                     "controller.")] = None,
    waist_serial: Annotated[str | None, typer.Option("--waist-serial", help="Live: serial of the waist tracker "
                                                     "(VMC input; without it head and hands only).")] = None,
    height: Annotated[float | None, typer.Option("--height", help="The user's stature in metres (sets the "
                                                 "first shape component; instead of --betas).")] = None,
    fps: Annotated[float | None, typer.Option("--fps", help="Live: the input's frame rate (default: the "
                                              "model's, 60).")] = None,
    record: Annotated[Path | None, typer.Option("--record", help="Live: save the session as a smplik-trackers "
                                                "file (replay: smplik track FILE --foot-locks streaming).")] = None,
    max_frames: Annotated[int | None, typer.Option("--max-frames", help="Live: stop after this many input "
                                                   "frames.")] = None,
    idle_timeout: Annotated[float | None, typer.Option("--idle-timeout", help="Live: stop after this many seconds "
                                                       "without input.")] = None,
    from_motion: Annotated[Path | None, typer.Option("--from-motion", help="Make a trackers file (--out FILE.json) "
                                                     "from a motion file (BVH, FBX, animation.json).")] = None,
    no_calibrate: Annotated[bool, typer.Option("--no-calibrate", help="Keep the recording's floor and the "
                                               "given (or default) body: no floor or stature estimate.")] = False,
    controller: Annotated[str | None, typer.Option("--controller", help="The controllers: vive, touch, index or "
                                                   "none (CSV/JSONL: the wrist point; default: the layout's).")] = None,
    csv_units: Annotated[str | None, typer.Option("--csv-units", help="CSV positions in m, cm or mm (default: "
                                                  "detected).")] = None,
    csv_time_unit: Annotated[str | None, typer.Option("--csv-time-unit", help="CSV times in s, ms, us or ns "
                                                      "(default: detected).")] = None,
    csv_axes: Annotated[str | None, typer.Option("--csv-axes", help="CSV axes: openvr (right-handed) or unity "
                                                 "(left-handed) (default: detected).")] = None,
    preview: Annotated[Path | None, typer.Option("--preview", help="Write an animated preview (.gif or .mp4), "
                                                 "as scene animate does.")] = None,
    preview_every: Annotated[int, typer.Option("--preview-every", min=1, max=1000, help="Preview every N-th "
                                               "frame, 1..1000.")] = 1,
) -> None:
    """Tracker recording (head, wrists, pelvis; or head and wrists) -> OUT/animation.json and BVH/GLB; or live:
    VMC/SteamVR trackers in, VMC bones out (--live)."""
    from workflows.animation.clips import AnimationError

    with user_errors():
        values = None
        if preview is not None:  # refused before any work (and before numpy/torch load)
            from workflows.animation.options import check_preview_path

            if live:
                raise AnimationError("--preview is for a recording, not --live.")
            check_preview_path(preview)
        if betas is not None and height is not None:
            raise AnimationError("give --betas or --height, not both.")
        if betas is not None:
            try:
                values = [float(v) for v in betas.split(",")]
            except ValueError:
                raise AnimationError(f"--betas must be 10 comma-separated numbers, got {betas!r}.") from None
            if len(values) != 10:
                raise AnimationError(f"--betas must be 10 comma-separated numbers, got {len(values)}.")
        if foot_locks not in ("offline", "streaming", "off"):
            raise AnimationError(f"--foot-locks must be offline, streaming or off, got {foot_locks!r}.")
        if live:
            if trackers is not None or out is not None or character is not None or samples != 1:
                bad = ("a TRACKERS file" if trackers is not None else "--out" if out is not None
                       else "--character" if character is not None else "--samples")
                raise AnimationError(f"--live takes no {bad} (live: deterministic, trackers from --vmc-in or stdin).")
            _live(values, height, gender, checkpoint, fit_trackers, vmc_in, vmc_out, left_serial, right_serial,
                  waist_serial, fps, record, max_frames, idle_timeout)
            return
        live_only = [name for name, v in (("--vmc-in", vmc_in), ("--vmc-out", vmc_out), ("--record", record),
                                          ("--left-serial", left_serial), ("--right-serial", right_serial),
                                          ("--waist-serial", waist_serial), ("--fps", fps),
                                          ("--max-frames", max_frames), ("--idle-timeout", idle_timeout))
                     if v is not None]
        if live_only:
            raise AnimationError(f"{live_only[0]} needs --live.")
        if from_motion is not None:
            if trackers is not None or out is None:
                raise AnimationError("--from-motion CLIP takes --out FILE.json (the trackers file) and no TRACKERS.")
            from workflows.tracking.from_motion import write_trackers_from_motion

            if height is not None:
                from smplik.tracking.calibrate import betas_for_stature

                values = list(betas_for_stature(height, gender))
            made = write_trackers_from_motion(from_motion, out, betas=values, gender=gender)
            say(f"wrote {made}")
            return
        if trackers is None or out is None:
            raise AnimationError("give a TRACKERS file and --out (or --live).")
        from workflows.tracking.run import track_file

        options = character_cli()
        outputs = track_file(trackers, out, samples=samples, betas=values, gender=gender, character_path=character,
                             character_options=options, checkpoint=checkpoint, seed=seed,
                             fit_trackers=fit_trackers, foot_locks=foot_locks, height=height,
                             calibrate=not no_calibrate, controller=controller, csv_units=csv_units,
                             csv_time_unit=csv_time_unit, csv_axes=csv_axes,
                             formats=[f.strip().lower() for f in export.split(",") if f.strip()])
        shown = None
        if preview is not None:  # the animation preview of scene animate (workflows.animation.preview)
            from workflows.animation.preview import write_preview

            shown = write_preview(outputs.animation, preview, every=preview_every)
    if outputs.calibration is not None:
        if outputs.calibration.message:
            say(outputs.calibration.message)
        say(outputs.calibration.summary())
    anim = outputs.animation
    say(f"{anim.tracks[0].num_frames} frames at {anim.fps:g} frames/s, anomaly rate {outputs.anomaly_rate:.3f}, "
        f"{outputs.switches} sample switches")
    if shown is not None:
        say(shown.describe())
    for path in (outputs.animation_file, *outputs.exported, *([shown.path] if shown is not None else [])):
        say(f"wrote {path}")


def _live(betas: list[float] | None, height: float | None, gender: str, checkpoint: Path | None, fit_trackers: bool,
          vmc_in: str | None, vmc_out: str | None, left_serial: str | None, right_serial: str | None,
          waist_serial: str | None, fps: float | None, record: Path | None, max_frames: int | None,
          idle_timeout: float | None) -> None:
    """``smplik track --live`` (logic in :mod:`workflows.tracking.live`). Ctrl-C ends it with one line."""
    import signal
    import sys

    import numpy as np

    from smplik.tracking.config import TRACKER_SETS
    from workflows.tracking import live as lv

    if vmc_out is None:
        raise lv.LiveError("--live needs --vmc-out HOST:PORT (where the VMC receiver listens).")
    if left_serial is not None and left_serial == right_serial:
        raise lv.LiveError(f"--left-serial and --right-serial are both {left_serial!r}; give each controller's own.")
    if fps is not None and not 1.0 <= fps <= 1000.0:
        raise lv.LiveError(f"--fps must be in [1, 1000], got {fps}.")
    if max_frames is not None and max_frames < 1:
        raise lv.LiveError(f"--max-frames must be at least 1, got {max_frames}.")
    if idle_timeout is not None and not idle_timeout > 0:
        raise lv.LiveError(f"--idle-timeout must be positive, got {idle_timeout}.")
    config = lv.LiveConfig(vmc_out=lv.parse_endpoint(vmc_out, "--vmc-out"),
                           vmc_in=None if vmc_in is None else lv.parse_endpoint(vmc_in, "--vmc-in", "127.0.0.1"),
                           left_serial=left_serial, right_serial=right_serial, waist_serial=waist_serial, fps=fps,
                           max_frames=max_frames, idle_timeout_s=idle_timeout, record=record)
    if config.vmc_in is not None and config.vmc_in[0] not in ("127.0.0.1", "localhost"):
        say(f"warning: listening on {config.vmc_in[0]}: anyone who reaches port {config.vmc_in[1]} can drive the "
            "avatar (VMC has no authentication)")
    body = np.zeros(10) if betas is None else np.asarray(betas, dtype=np.float64)
    if height is not None:
        body = lv.betas_for_height(height, gender)
    lines = None
    if config.vmc_in is None:
        if waist_serial is not None:
            raise lv.LiveError("--waist-serial is for --vmc-in; on stdin one generic tracker is the waist.")
        first = sys.stdin.readline()
        if not first.strip():
            raise lv.LiveError("stdin: no SteamVR JSON line (give --vmc-in PORT for VMC input).")
        trackers = lv.first_line_trackers(first)
        lines = _chain(first, sys.stdin)
    else:
        trackers = TRACKER_SETS["4"] if waist_serial is not None else TRACKER_SETS["3"]
    tracker = lv.open_tracker(trackers, betas=body, gender=gender, checkpoint=checkpoint, fit_trackers=fit_trackers)
    session = lv.LiveTracker(tracker, fps, record=record is not None)
    stats = lv.LiveStats()
    where = f"{config.vmc_out[0]}:{config.vmc_out[1]}"

    def on_ctrl_c(signum: int, frame: object) -> None:  # a frame in flight is finished (sent and counted) first
        if stats.busy:
            stats.interrupted = True
        else:
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_ctrl_c)
    try:
        if lines is None:
            def ready(addr: tuple[str, int]) -> None:
                say(f"listening on {addr[0]}:{addr[1]} ({', '.join(trackers)}), sending to {where}; Ctrl-C stops")

            lv.run_vmc(session, config, on_ready=ready, stats=stats)
        else:
            lv.run_steamvr(session, config, lines, stats=stats)
        stopped = stats.stopped
    except KeyboardInterrupt:
        stopped = "Ctrl-C"
    finally:
        signal.signal(signal.SIGINT, previous)
    lat = np.asarray(stats.latency_s) * 1e3
    timing = f", latency p50 {np.median(lat):.2f} ms" if lat.size else ""
    ignored = f", {stats.ignored} malformed messages ignored" if stats.ignored else ""
    saved = f", recorded {record}" if record is not None and session.recorded else ""
    say(f"stopped ({stopped}): {stats.frames_in} frames in, {stats.bundles_out} bundles to {where}{timing}"
        f"{ignored}{saved}")


def _chain(first: str, rest: object) -> object:
    yield first
    yield from rest  # type: ignore[misc]
