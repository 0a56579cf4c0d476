"""Issue 44's smaller animation seams: the GIF preview plays in the clip's own time, options are refused before
anything heavy loads, and the cleaning's properties on small synthetic clips (never worse than its input, planted
feet held)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from workflows.animation.preview import GIF_TICK_MS, gif_durations, save_gif


@pytest.mark.parametrize("fps", [15.0, 30.0 / 2, 24.0, 25.0, 12.5, 29.97 / 2, 7.0])
@pytest.mark.parametrize("n", [1, 7, 269])
def test_gif_delays_add_up_to_the_clips_duration(fps, n):
    delays = gif_durations(n, fps)
    assert len(delays) == n
    assert all(d % GIF_TICK_MS == 0 and d >= GIF_TICK_MS for d in delays)
    assert abs(sum(delays) - n * 1000.0 / fps) <= GIF_TICK_MS / 2 + 1e-9  # the clip plays in its own time
    assert max(delays) - min(delays) <= GIF_TICK_MS  # evenly spread, no stall


def test_a_written_gif_of_66ms_frames_is_not_played_11_percent_fast(tmp_path):
    # the issue: every frame stored as 60 ms for 66.7 ms frames (a 15 frames/s preview of a 30 frames/s clip)
    n, fps = 30, 15.0
    rng = np.random.default_rng(0)
    images = [Image.fromarray(rng.integers(0, 255, (8, 8, 3), dtype=np.uint8)).quantize(colors=16)
              for _ in range(n)]
    path = tmp_path / "p.gif"
    save_gif(images, path, fps)
    with Image.open(path) as gif:
        stored = []
        for k in range(gif.n_frames):
            gif.seek(k)
            stored.append(gif.info["duration"])
    assert len(stored) == n
    assert abs(sum(stored) - 2000.0) <= 5.0  # 30 frames at 15 frames/s: two seconds
    assert set(stored) == {60, 70}


@pytest.mark.parametrize("args, said", [
    (["--frames", "abc"], "--frames must be 'all' or 'A:B'"),
    (["--frames", "5:2"], "--frames 5:2: need 0 <= A < B"),
    (["--export", "fbx"], "unknown export format"),
    (["--smoothing", "wiener"], "smoothing must be"),
    (["--fps", "0"], "--fps"),
    (["--preview", "x.png"], "x.png"),
])
def test_animate_refuses_bad_options_before_loading_the_model(tmp_path, monkeypatch, args, said):
    from typer.testing import CliRunner

    import workflows.cli_shared
    from workflows.cli import scene_app

    loaded = []
    monkeypatch.setattr(workflows.cli_shared, "_solver", lambda checkpoint: loaded.append(checkpoint))
    source = tmp_path / "missing.npz"  # not even read: the options are refused first
    res = CliRunner().invoke(scene_app, ["animate", str(source), "--out", str(tmp_path / "o"), *args])
    assert res.exit_code == 1, res.output
    assert said in res.output
    assert len(res.output.strip().splitlines()) == 1 and "Traceback" not in res.output
    assert loaded == []  # the model never loaded
    assert not (tmp_path / "o").exists()
