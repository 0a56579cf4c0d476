"""Issue 36, round 3 of the security work: every case of ``benchmarks/fuzz_round3.py`` (the fuzz campaign's
round-3 section) through the real command tree, in-process: exit status 1, exactly one ``error:`` line, no
traceback, its ``keep`` input byte-identical and nothing written into its working folder. Plus the pieces
underneath: config validation for every field, the pose-cache value checks, strict option parsers, and
the output guard."""

from __future__ import annotations

import importlib
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from smplik.cli.main import app
from smplik.solver import packaged_model_path

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def fuzz_campaign(tmp_path_factory):
    if not packaged_model_path().is_file():
        pytest.skip("no packaged model in this checkout")
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        module = importlib.import_module("fuzz_round3")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return module, module.round3_cases(tmp_path_factory.mktemp("fuzz_campaign"))


def run(args: list[str]):  # noqa: ANN201 - click.testing.Result
    return CliRunner().invoke(app, args)


def one_error_line(result) -> str | None:  # noqa: ANN001 - click.testing.Result
    """The problem with ``result`` (None: exit 1, one ``error:`` line, no escaping exception)."""
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        return f"{type(result.exception).__name__}: {result.exception}"
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    if result.exit_code != 1 or len(lines) != 1 or not lines[0].startswith("error: "):
        return f"exit {result.exit_code}, stderr {lines[-3:]}"
    return None


def test_every_fuzz_case_is_one_error_line_and_keeps_its_inputs(fuzz_campaign, monkeypatch):
    _, cases = fuzz_campaign
    assert {c.reader for c in cases} == {"r3_config", "r3_pose_cache", "r3_estimator", "r3_gltf", "r3_outputs",
                                         "r3_options"}
    failures = []
    for case in cases:
        kept = case.keep.read_bytes() if case.keep is not None else None
        if case.cwd is not None:
            monkeypatch.chdir(case.cwd)
        result = run(case.args)
        monkeypatch.chdir(ROOT)
        problem = one_error_line(result)
        if case.keep is not None and case.keep.read_bytes() != kept:
            problem = f"{case.keep.name} was overwritten"
        if case.cwd is not None and any(case.cwd.iterdir()):
            problem = f"wrote into the working folder: {sorted(p.name for p in case.cwd.iterdir())}"
        if problem:
            failures.append(f"{case.reader} {case.note}: {problem}")
    assert not failures, "\n".join(failures)


def test_the_valid_material_of_the_cases_is_accepted(fuzz_campaign, tmp_path):
    """The cases fail because of their one mutation: the valid cache loads, the valid BVH inverts."""
    from smplik.data.dataset import load_cache

    module, cases = fuzz_campaign
    np.savez(tmp_path / "cache.npz", **module.valid_pose_cache())
    assert len(load_cache(tmp_path / "cache.npz")) == 4
    hero = next(c.keep for c in cases if c.note == "invert-shape --out hero.bvh")
    result = run(["invert-shape", str(hero), "--out", str(tmp_path / "s.json")])
    assert result.exit_code == 0 and (tmp_path / "s.json").is_file(), result.stderr


def test_invert_shape_refuses_to_write_over_its_character(tmp_path):
    from workflows.examples_gen import write_mixamo_character

    bvh = write_mixamo_character(tmp_path / "X.bvh")
    before = bvh.read_bytes()
    result = run(["invert-shape", str(bvh), "--out", str(bvh)])
    assert one_error_line(result) is None
    assert "refusing to overwrite an input" in result.stderr and bvh.read_bytes() == before


def test_in_place_commands_may_still_write_back_to_their_file():
    from smplik.cli.outputs import IN_PLACE, OutputPathError, check_outputs

    assert IN_PLACE == {"scene solve": "scene", "scene edit-keyframe": "animation"}
    check_outputs("scene solve", {"scene": Path(__file__), "out": Path(__file__)})
    with pytest.raises(OutputPathError, match="is the input file"):
        check_outputs("scene render", {"scene": Path(__file__), "out": Path(__file__)})


@pytest.mark.parametrize("cls_name, field, value", [
    ("TrainConfig", "steps", -1), ("TrainConfig", "lr", math.nan), ("TrainConfig", "seed", -1),
    ("TrainConfig", "precision", "fp8"), ("NetworkConfig", "width", 0), ("NetworkConfig", "dropout", 2.0),
    ("LossConfig", "w_pos_rnd", -1.0), ("LossConfig", "w_lookat", math.inf),
    ("EffectorSamplingConfig", "max_effectors", 0), ("EffectorSamplingConfig", "sigma_max", math.nan),
    ("EffectorSamplingConfig", "limb_first", 1.5)])
def test_every_config_class_raises_a_config_error_naming_the_field(cls_name, field, value):
    import smplik.configs as configs
    from smplik.cli.errors import is_user_error

    cls = getattr(configs, cls_name)
    required = {"data": "d", "out": "o"} if cls is configs.TrainConfig else {}
    with pytest.raises(configs.ConfigError, match=rf"{cls_name}\.{field} must be") as info:
        cls(**required, **{field: value})
    assert is_user_error(info.value)


def test_effector_counts_must_be_ordered():
    from smplik.configs import ConfigError, EffectorSamplingConfig

    with pytest.raises(ConfigError, match="min_effectors"):
        EffectorSamplingConfig(min_effectors=8, max_effectors=4)


def test_pose_cache_errors_name_the_key(fuzz_campaign, tmp_path):
    from smplik.data.dataset import CacheError, load_cache

    module, _ = fuzz_campaign
    expected = {"version_1d": "'version'", "version_float": "'version'", "subject_names_scalar": "'subject_names'",
                "subject_names_numbers": "'subject_names'", "clip_names_short": "'clip_id'", "pose_1e30": "'pose'",
                "pose_nan": "'pose'", "transl_inf": "'transl'", "frame_negative": "'frame'",
                "clip_fps_zero": "'clip_fps'", "gender_7": "'gender'", "settings_list": "'settings'"}
    assert set(expected) == set(module.CACHE_MUTATIONS)
    for name, mutate in module.CACHE_MUTATIONS.items():
        arrays = module.valid_pose_cache()
        mutate(arrays)
        np.savez(tmp_path / f"{name}.npz", **arrays)
        with pytest.raises(CacheError, match=expected[name]):
            load_cache(tmp_path / f"{name}.npz")


@pytest.mark.parametrize("text, betas", [(None, [0.0] * 10), ("1", [1.0] + [0.0] * 9),
                                         ("1, -2.5e-1", [1.0, -0.25] + [0.0] * 8),
                                         ("0.5 .5 5.", [0.5, 0.5, 5.0] + [0.0] * 7)])
def test_betas_accepts_plain_numbers(text, betas):
    from smplik.cli.options import parse_betas

    assert parse_betas(text) == betas


@pytest.mark.parametrize("text", ["", " ", ",,", "1,,2", "1_0", "nan", "inf", "0x1", "1e999", "٣",
                                  "1,2,3,4,5,6,7,8,9,0,1"])
def test_betas_refuses_anything_else(text):
    from smplik.cli.options import parse_betas

    with pytest.raises(typer.BadParameter):
        parse_betas(text)


@pytest.mark.parametrize("text, yaw, mirror", [("none", 1, False), ("mirror", 1, True), ("yaw4", 4, False),
                                               ("mirror+yaw4", 4, True), ("YAW2 + mirror", 2, True)])
def test_ensemble_accepts_each_part_once(text, yaw, mirror):
    from smplik.ensemble import EnsembleConfig

    assert EnsembleConfig.parse(text) == EnsembleConfig(yaw=yaw, mirror=mirror)


@pytest.mark.parametrize("text", ["", "+", "mirror+", "mirror+mirror", "none+mirror", "yaw2+yaw4", "yaw", "yaw²",
                                  "mirror+yaw2+none"])
def test_ensemble_refuses_empty_repeated_or_unknown_parts(text):
    from smplik.ensemble import EnsembleConfig

    with pytest.raises(ValueError, match=re.escape(f"Unknown ensemble {text!r}")):
        EnsembleConfig.parse(text)


def test_fps_bounds():
    from smplik.cli.options import FPS_RANGE, check_fps

    assert FPS_RANGE == (1.0, 1000.0)
    assert check_fps(None) is None and check_fps(1.0) == 1.0 and check_fps(1000.0) == 1000.0
    for bad in (1e-300, 0.0, -30.0, math.nan, math.inf, 1000.5):
        with pytest.raises(typer.BadParameter):
            check_fps(bad)
