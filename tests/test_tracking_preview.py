"""``smplik track --preview`` (the animation preview of ``scene animate``), :meth:`Tracker.step`'s frame-rate check
on timestamped streams, and the streaming snippet of ``docs/tracking.md`` run as written (issue 43, item 5)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from smplik.cli.main import app
from smplik.tracking.runtime import RATE_MIN_INTERVALS, Tracker

DOCS = Path(__file__).resolve().parents[1] / "docs" / "tracking.md"
STANDING = np.array([[0.0, 1.62, 0.0], [0.2, 0.88, 0.05], [-0.2, 0.88, 0.05], [0.0, 0.95, 0.0]])
UPRIGHT = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))


@pytest.fixture(scope="module")
def tracker():
    return Tracker.load()


def recording(path: Path, frames: int = 24) -> Path:
    """A smplik-trackers file of a person standing and swaying (60 frames/s, head, wrists, pelvis)."""
    t = np.arange(frames) / 60.0
    sway = 0.05 * np.sin(2 * np.pi * t)[:, None]
    pos = np.repeat(STANDING[None], frames, 0)
    pos[:, :, 0] += sway
    names = ("head", "left_wrist", "right_wrist", "pelvis")
    doc = {"format": "smplik-trackers", "version": 1, "fps": 60,
           "trackers": {n: {"position": pos[:, k].tolist(), "rotation": np.repeat(UPRIGHT[k:k + 1], frames, 0).tolist()}
                        for k, n in enumerate(names)}}
    path.write_text(json.dumps(doc))
    return path


def test_track_preview_writes_the_animation_preview(tmp_path):
    from PIL import Image

    src = recording(tmp_path / "session.json")
    gif = tmp_path / "out" / "preview.gif"
    res = CliRunner().invoke(app, ["track", str(src), "--out", str(tmp_path / "out"), "--preview", str(gif),
                                   "--export", ""])
    assert res.exit_code == 0, res.output
    assert f"wrote {gif}" in res.output and "frames" in res.output
    with Image.open(gif) as img:
        assert img.n_frames == 6  # a GIF shows at most 15 frames per second of the clip: every 4th of 24 frames
        assert img.size == (480, 360)
    assert (tmp_path / "out" / "animation.json").exists()


@pytest.mark.parametrize("args, said", [
    (["--preview", "p.png"], "a preview is a .gif or .mp4 file"),
    (["--preview", "p.gif", "--live"], "--preview is for a recording"),
])
def test_track_refuses_a_bad_preview_before_any_work(tmp_path, args, said):
    src = recording(tmp_path / "session.json")
    out = tmp_path / "out"
    cmd = ["track", *([] if "--live" in args else [str(src), "--out", str(out)]), *args]
    res = CliRunner().invoke(app, cmd)
    assert res.exit_code == 1, res.output
    assert said in res.output and len(res.output.strip().splitlines()) == 1
    assert not out.exists()


def test_step_refuses_a_stream_at_another_rate(tracker):
    tracker.reset()
    tracker.step(STANDING, UPRIGHT, time_s=0.0)
    with pytest.raises(ValueError, match=r"runs at 30\.0 frames/s .* this model runs at 60") as err:
        tracker.step(STANDING, UPRIGHT, time_s=1 / 30)
    assert "\n" not in str(err.value)
    assert tracker.frame_in == 1  # the refused frame was not used
    tracker.reset()
    rate = 72.0  # close to 60: refused once enough intervals say so
    with pytest.raises(ValueError, match="runs at 72.0 frames/s"):
        for k in range(RATE_MIN_INTERVALS + 2):
            tracker.step(STANDING, UPRIGHT, time_s=k / rate)
    assert tracker.frame_in == RATE_MIN_INTERVALS


def test_step_accepts_the_models_rate_with_real_jitter_and_refuses_time_going_back(tracker):
    rng = np.random.default_rng(0)
    tracker.reset()
    times = np.arange(120) / 60.0 + rng.uniform(-0.003, 0.003, 120)  # a headset log's +-3 ms sampling jitter
    for t in times:
        tracker.step(STANDING, UPRIGHT, time_s=t)
    assert tracker.frame_in == 120
    with pytest.raises(ValueError, match="timestamps must increase"):
        tracker.step(STANDING, UPRIGHT, time_s=times[-1])
    with pytest.raises(ValueError, match="finite"):
        tracker.step(STANDING, UPRIGHT, time_s=float("nan"))
    tracker.reset()  # a new recording starts its own clock
    tracker.step(STANDING, UPRIGHT, time_s=0.0)
    tracker.step(STANDING, UPRIGHT)  # without timestamps nothing is checked
    assert tracker.frame_in == 2


def streaming_snippet() -> str:
    text = DOCS.read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    found = [b for b in blocks if "tracker.step(" in b]
    assert len(found) == 1, "docs/tracking.md has one streaming snippet"
    return found[0]


def test_the_docs_streaming_snippet_runs_as_written():
    namespace: dict = {}
    exec(compile(streaming_snippet(), str(DOCS), "exec"), namespace)  # noqa: S102 (the docs' own code)
    poses, stream = namespace["poses"], namespace["stream"]
    assert len(poses) == len(stream)  # one pose per frame, the look-ahead flushed
    last = poses[-1]
    assert last.R_local.shape == (24, 3, 3) and np.isfinite(last.transl).all()
    pelvis = namespace["tracker"].J_rest64[0] + last.transl
    assert abs(pelvis[1] - 0.95) < 0.1  # the body stands with its pelvis at the pelvis tracker's height
