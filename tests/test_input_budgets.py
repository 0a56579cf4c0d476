"""Issue 45, round 4 of the security work (the budget half): every case of ``benchmarks/fuzz_round4_budgets.py``
(trackers JSON TQ/TF, SteamVR SV1-SV4, tracking checkpoints MH/MF/MS/MZ, IK views, animation AF/KF/PE, AMASS
``mocap_framerate``) through the real command tree, in-process: exit 1, exactly one ``error:`` line holding the
case's key or limit variable, its input byte-identical (or exit 0 for a valid input the old readers broke on).
Then the pieces underneath, with the memory bounds checked structurally: a refusal comes before the allocation
it guards (``tracemalloc`` peaks of a few MB where the work would take gigabytes), not by timing."""

from __future__ import annotations

import importlib
import json
import re
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from smplik.cli.main import app
from smplik.limits import (
    MAX_FPS,
    MIN_FPS,
    OUTPUT_FRAMES,
    TRACK_FRAMES,
    LimitError,
    check_rate,
    check_resampled_frames,
)
from smplik.solver import packaged_model_path

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def budget_campaign(tmp_path_factory):
    if not packaged_model_path().is_file():
        pytest.skip("no packaged model in this checkout")
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        module = importlib.import_module("fuzz_round4_budgets")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return module, module.round4_budget_cases(tmp_path_factory.mktemp("budget_campaign"))


def run(args: list[str]):  # noqa: ANN201 - click.testing.Result
    return CliRunner().invoke(app, args)


def problem(result, needle: str) -> str | None:  # noqa: ANN001 - click.testing.Result
    """What is wrong with ``result`` (None: exit 1, one ``error:`` line holding ``needle``, no exception)."""
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        return f"{type(result.exception).__name__}: {result.exception}"
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    if result.exit_code != 1 or len(lines) != 1 or not lines[0].startswith("error: "):
        return f"exit {result.exit_code}, stderr {lines[-3:]}"
    text = re.sub(r"\s+", " ", lines[0])
    if needle not in text:
        return f"{needle!r} not in {text!r}"
    return None


@pytest.mark.slow
def test_every_budget_case_is_one_error_line_and_keeps_its_input(budget_campaign):
    module, cases = budget_campaign
    assert {c.reader for c, _ in cases} == {"r4_trackers", "r4_steamvr", "r4_tracking_model", "r4_ik_model",
                                            "r4_animation"}
    failures = []
    for case, needle in cases:
        kept = case.keep.read_bytes() if case.keep is not None else None
        result = run(case.args)
        if needle == module.ACCEPT:
            bad = None if result.exit_code == 0 else f"exit {result.exit_code}: {result.stderr.strip()[-300:]}"
        else:
            bad = problem(result, needle)
        if case.keep is not None and case.keep.read_bytes() != kept:
            bad = f"{case.keep} changed"
        if bad:
            failures.append(f"{case.reader} / {case.note}: {bad}")
    assert not failures, "\n".join(failures)


def test_a_huge_or_tiny_quaternion_is_the_identity_and_a_zero_one_is_named(budget_campaign, tmp_path):
    from smplik.tracking.io import TrackerFileError, signals_from_dict

    module, _ = budget_campaign
    for scale in (1e300, 1e-300, 5e-324):
        sig = signals_from_dict(module.tracker_doc(head_rotation=[[scale, 0, 0, 0]] * 60), "t.json")
        np.testing.assert_allclose(sig.rotations[:, 0], np.tile([1.0, 0, 0, 0], (60, 1)))
    q = [[1e300, 1e300, 0, 0]] * 60  # norm overflows unless normalised by the largest component first
    sig = signals_from_dict(module.tracker_doc(head_rotation=q), "t.json")
    np.testing.assert_allclose(sig.rotations[0, 0], [2**-0.5, 2**-0.5, 0, 0])
    with pytest.raises(TrackerFileError, match=r"t.json: trackers.head.rotation\[3\]: is a zero quaternion"):
        signals_from_dict(module.tracker_doc(head_rotation=[[1, 0, 0, 0]] * 3 + [[0, 0, 0, 0]] * 57), "t.json")


def test_rates_are_bounded_everywhere_by_one_range():
    from smplik.cli.options import FPS_RANGE

    assert FPS_RANGE == (MIN_FPS, MAX_FPS) == (1.0, 1000.0)
    for good in (1, 1.0, 60, 1000, np.float32(30.0), np.int64(120)):
        assert check_rate(good, "x") == float(good)
    for bad in (0, 0.999, 1000.5, 5e-324, 1e308, float("nan"), float("inf"), -60, True, "60", None, [60]):
        with pytest.raises(LimitError, match=r"^x: must be a frame rate"):
            check_rate(bad, "x")


def test_resampled_frames_are_counted_before_any_array(monkeypatch):
    assert check_resampled_frames(1.0, 60.0, "s") == 61
    assert check_resampled_frames(0.0, 60.0, "s") == 1
    for duration, rate in ((1e7, 60.0), (1e300, 1000.0), (float("inf"), 60.0), (-1.0, 60.0)):
        with pytest.raises(LimitError, match="^s"):
            check_resampled_frames(duration, rate, "s")
    monkeypatch.setenv(OUTPUT_FRAMES.env, "100")
    with pytest.raises(LimitError, match="SMPLIK_MAX_OUTPUT_FRAMES"):
        check_resampled_frames(2.0, 60.0, "s")


def _peak_mb(fn) -> float:  # noqa: ANN001
    tracemalloc.start()
    try:
        fn()
    except (LimitError, ValueError):
        pass
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def test_resampling_a_recording_is_refused_before_it_is_made(budget_campaign):
    """60 rows at 1 frame/s stretched to 3.5 M frames (the TF hang) and 10^6 rows at 1000 frames/s (the tracker's
    cap, counted on input and output frames): refused with a few MB traced, never the arrays themselves."""
    from smplik.tracking.io import TrackerSignals
    from smplik.tracking.runtime import resample_signals

    def signals(T: int, fps: float) -> TrackerSignals:
        return TrackerSignals(fps, ("head",), np.zeros((T, 1, 3)), np.tile([1.0, 0, 0, 0], (T, 1, 1)),
                              np.ones(1, bool), "rec.json")

    long = signals(60_000, 1.0)  # 16.7 h at 1 frame/s: 3.6 M frames at 60 (1.2 GB of positions and rotations)
    with pytest.raises(LimitError, match="rec.json.*SMPLIK_MAX_OUTPUT_FRAMES"):
        resample_signals(long, 60.0)
    assert _peak_mb(lambda: resample_signals(long, 60.0)) < 5
    fast = signals(TRACK_FRAMES.value + 1, 60.0)
    with pytest.raises(LimitError, match="rec.json.*SMPLIK_MAX_TRACK_FRAMES"):
        resample_signals(fast, 60.0)
    P, Q, nearest = resample_signals(signals(3, 30.0), 60.0)  # 2 frames' span at 60: 5 frames
    assert P.shape == (5, 1, 3) and Q.shape == (5, 1, 4) and nearest.tolist() == [0, 2, 4]


def test_a_steamvr_span_is_refused_before_the_resampling(budget_campaign, tmp_path):
    from smplik.tracking.io import TrackerFileError, read_steamvr_jsonl

    module, _ = budget_campaign
    path = tmp_path / "log.jsonl"
    path.write_text(module.steamvr_lines(last=1e9))  # 6e10 frames at 60 frames/s: 2.8 TB of positions
    with pytest.raises(TrackerFileError, match="SMPLIK_MAX_OUTPUT_FRAMES"):
        read_steamvr_jsonl(path)
    assert _peak_mb(lambda: read_steamvr_jsonl(path)) < 5
    path.write_text(module.steamvr_lines())
    sig = read_steamvr_jsonl(path)
    assert sig.names == ("head", "left_wrist", "right_wrist") and sig.num_frames == 60


def test_strings_are_not_numbers_in_tracker_files(budget_campaign):
    from smplik.tracking.io import TrackerFileError, signals_from_dict
    from smplik.validation import only_numbers

    module, _ = budget_campaign
    assert only_numbers([[1, 2.5, np.float32(3)]]) and only_numbers(np.zeros((2, 3)))
    assert not only_numbers([[1, "2", 3]]) and not only_numbers([[1, True, 3]]) and not only_numbers([[1, None, 3]])
    assert not only_numbers(np.asarray(["1"])) and not only_numbers([[1, {}, 3]])
    for row in (["0", 1.6, 0], [0, 1.6, "0e0"], [0, None, 0], [0, False, 0]):
        with pytest.raises(TrackerFileError, match="trackers.head.position: must be numbers"):
            signals_from_dict(module.tracker_doc(head_position=[row] * 60), "t.json")


def test_the_one_model_file_reader_is_the_only_torch_load():
    """torch.load appears in one library file (smplik/model_io.py, the reader); every .pt goes through it."""
    found = []
    for folder in ("smplik", "workflows", "shape_inversion"):
        for path in (ROOT / folder).rglob("*.py"):
            code = "\n".join(line.split("#")[0] for line in path.read_text().splitlines())
            if re.search(r"\btorch\.load\(", code.replace("``torch.load(", "")):
                found.append(str(path.relative_to(ROOT)))
    assert found == ["smplik/model_io.py"], found


def test_tracking_model_values_are_typed_and_bounded():
    from smplik.tracking.config import TRACKING_NET_RANGES, TrackingNetConfig

    base = TrackingNetConfig().to_dict()
    assert TrackingNetConfig.from_dict(base) == TrackingNetConfig()
    for key, (lo, hi) in TRACKING_NET_RANGES.items():
        for bad in (lo - 1, hi + 1, float(lo), True, str(lo)):
            with pytest.raises(ValueError, match=f"^net.{key}: expected a whole number"):
                TrackingNetConfig.from_dict({**base, key: bad})
    for key, bad in (("fps", 0), ("fps", "60"), ("kind", "gru"), ("trackers", ["head", "head"]),
                     ("trackers", ["nose"]), ("trackers", "head"), ("extra", 1)):
        with pytest.raises(ValueError, match=f"^net.{key}"):
            TrackingNetConfig.from_dict({**base, key: bad})


def test_the_largest_tracking_network_the_ranges_allow_is_small():
    """The ranges bound what a model file can make the tracker build: at their top, under 100 MB of weights."""
    from smplik.tracking.config import TRACKING_NET_RANGES, TrackingNetConfig
    from smplik.tracking.network import build_network

    top = {k: hi for k, (_, hi) in TRACKING_NET_RANGES.items()}
    for kind in ("cvae", "mlp"):
        net = build_network(TrackingNetConfig.from_dict({**TrackingNetConfig().to_dict(), **top, "kind": kind}))
        size = sum(p.numel() * p.element_size() for p in net.parameters())
        assert size < 100e6, (kind, size)


def test_a_model_file_bomb_is_refused_from_the_zip_directory(budget_campaign, tmp_path):
    """The deflated-storage tracking model (MZ) never reaches torch.load: refused with a few MB traced."""
    from smplik.tracking.model_io import read_tracking_file

    _, cases = budget_campaign
    bomb = next(c for c, _ in cases if c.note.startswith("MZ")).keep
    assert bomb.stat().st_size < 3 << 20  # the shipped model's 2.2 MB and one deflated 80 MB member
    with pytest.raises(LimitError, match="is compressed and inflates to 83886080 bytes"):
        read_tracking_file(bomb)
    assert _peak_mb(lambda: read_tracking_file(bomb)) < 5


def test_keyframe_effectors_are_counted_before_they_are_parsed(budget_campaign, monkeypatch):
    """200,000 effectors in a keyframe: refused before a single one is parsed (the MemoryError at 1.5 GB)."""
    import workflows.animation.files as files
    from workflows.animation.files import AnimationFileError, animation_from_dict

    module, _ = budget_campaign
    parsed = []
    real = files.parse_effector_dict
    monkeypatch.setattr(files, "parse_effector_dict", lambda *a, **k: parsed.append(1) or real(*a, **k))
    doc = module.animation_doc(keyframes=[{"frame": 5, "effectors": [module.EFFECTOR] * 200_000}])
    with pytest.raises(AnimationFileError, match="200000 effectors; at most 64"):
        animation_from_dict(doc, "a.json")
    assert parsed == []
    ok = animation_from_dict(module.animation_doc(keyframes=[{"frame": 5, "effectors": [module.EFFECTOR] * 64}]))
    assert len(ok.tracks[0].keyframes[0].effectors) == 64


def test_a_sparse_preview_plays_at_least_one_frame_a_second():
    from workflows.animation.preview import MAX_PREVIEW_EVERY, shown_frames

    class Track:
        first_frame, num_frames = 0, 100_000

    class Anim:
        tracks, fps = (Track(),), 1.0

    frames, step = shown_frames(Anim(), MAX_PREVIEW_EVERY, 1000)
    assert len(frames) <= 1000 and step % MAX_PREVIEW_EVERY == 0
    for bad in (0, MAX_PREVIEW_EVERY + 1, 100_000, True):
        with pytest.raises(ValueError, match="--preview-every must be a whole number in 1..1000"):
            shown_frames(Anim(), bad, 1000)


def test_every_budget_limit_is_on_the_security_page():
    page = (ROOT / "docs" / "security.md").read_text()
    for needle in (OUTPUT_FRAMES.env, TRACK_FRAMES.env, "smplik.limits.MIN_FPS", "MAX_PREVIEW_EVERY",
                   "TRACKING_NET_RANGES", "MAX_ABS_TIMESTAMP_S", "MAX_EFFECTORS", "read_torch_file"):
        assert needle in page, needle
    data = json.loads((ROOT / "benchmarks" / "results" / "fuzz_round4_budgets.json").read_text())
    assert data["totals"]["runs"] > 0


def test_a_json_integer_of_5001_digits_is_named_by_its_file(tmp_path):
    from smplik.tracking.io import TrackerFileError
    from smplik.tracking.recordings import read_trackers

    path = tmp_path / "t.json"
    path.write_text('{"format": "smplik-trackers", "version": 1, "fps": 1' + "0" * 5000 + ', "trackers": {}}')
    with pytest.raises(TrackerFileError, match=r"t.json: invalid JSON \(Exceeds the limit \(4300 digits\)"):
        read_trackers(path)
