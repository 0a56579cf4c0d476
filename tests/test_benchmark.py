"""Benchmark files (reproducible bit for bit), metrics, baselines and the `smplik benchmark` CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from smplik.benchmark import (
    FIXED_SETS,
    LIMB_ZONES,
    ZONES,
    NearestNeighborMethod,
    OptimizationIK,
    PosePrior,
    Prediction,
    RestPoseMethod,
    evaluate_prediction,
    load_benchmark,
    make_benchmark,
    results_markdown,
    run_benchmark,
    sample_subjects,
    set_names,
)
from smplik.conventions import JOINT_INDEX, JOINT_NAMES
from smplik.refine import RefineConfig

K = 6  # samples per set: small and fast


@pytest.fixture(scope="module")
def files(tmp_path_factory, tiny_cache):
    out = tmp_path_factory.mktemp("bench") / "a"
    make_benchmark(tiny_cache, out, split="test", seed=3, samples_per_count=K)
    return out


@pytest.fixture(scope="module")
def bench(files):
    return load_benchmark(files)


def oracle(bset):
    return Prediction(bset.R_local, bset.transl)


def test_zones_cover_every_joint_once():
    joints = [j for zone in ZONES.values() for j in zone]
    assert sorted(joints) == sorted(JOINT_NAMES)


def test_files_are_reproducible_bit_for_bit(tmp_path, tiny_cache, files):
    again = tmp_path / "b"
    make_benchmark(tiny_cache, again, split="test", seed=3, samples_per_count=K)
    names = sorted(p.name for p in files.iterdir())
    assert names == sorted(p.name for p in again.iterdir())
    assert names == sorted([f"{n}.npz" for n in set_names()] + ["manifest.json"])
    for name in names:
        if name.endswith(".npz"):
            with np.load(files / name) as a, np.load(again / name) as b:
                assert a.files == b.files
                for key in a.files:
                    np.testing.assert_array_equal(a[key], b[key])
        assert (files / name).read_bytes() == (again / name).read_bytes(), name
    other = tmp_path / "c"
    make_benchmark(tiny_cache, other, split="test", seed=4, samples_per_count=K)
    assert (other / "random_08.npz").read_bytes() != (files / "random_08.npz").read_bytes()


def test_manifest_and_layout(files, bench):
    manifest = json.loads((files / "manifest.json").read_text())
    assert manifest["format"] == "smplik-benchmark" and manifest["version"] == 1 and manifest["seed"] == 3
    assert [s.name for s in bench.sets] == set_names()
    for bset in bench.sets:
        eff = bset.effectors
        assert len(bset) == K and eff.joint.shape == (K, bset.num_effectors)
        assert (eff.tolerance == 0).all()
        if bset.kind == "fixed":
            assert [JOINT_NAMES[j] for j in eff.joint[0]] == list(FIXED_SETS[bset.name])
            assert (eff.type == 0).all()
            continue
        for s in range(K):
            pairs = list(zip(eff.joint[s].tolist(), eff.type[s].tolist(), strict=True))
            assert len(set(pairs)) == len(pairs), "(joint, type) pairs must be distinct"
            for (j, t), zone in zip(pairs[:4], LIMB_ZONES, strict=True):
                assert t == 0 and JOINT_NAMES[j] in ZONES[zone]


def test_modified_file_is_detected(tmp_path, tiny_cache):
    out = tmp_path / "m"
    make_benchmark(tiny_cache, out, samples_per_count=2)
    with np.load(out / "fixed_5pt.npz") as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["joints"] = arrays["joints"] + 1
    np.savez(out / "fixed_5pt.npz", **arrays)
    with pytest.raises(ValueError, match="SHA-256"):
        load_benchmark(out)


def test_oracle_is_zero_and_rest_is_not(bench, bodies):
    for bset in bench.sets:
        m = evaluate_prediction(bset, oracle(bset), bodies)
        assert m.mpjpe_mm < 1e-3 and m.pa_mpjpe_mm < 1e-3 and m.geodesic_rad < 2e-3
        assert m.position_residual_mm < 1e-3
        assert m.rotation_residual_deg is None or m.rotation_residual_deg < 0.1
        assert m.lookat_error_deg is None or m.lookat_error_deg < 0.1
        rest = evaluate_prediction(bset, RestPoseMethod(bodies)(bset), bodies)
        assert rest.mpjpe_mm > 10 and rest.geodesic_rad > 0.01


def test_baselines_beat_the_rest_pose(bench, bodies, tiny_cache):
    from smplik.data.dataset import load_cache

    train = load_cache(tiny_cache).subset("train").pose
    methods = {"rest": RestPoseMethod(bodies), "optim": OptimizationIK(bodies, PosePrior.fit(train), iterations=60),
               "nn": NearestNeighborMethod.from_dataset(train, bodies, max_samples=200)}
    sub = type(bench)(bench.manifest, tuple(s.head(4) for s in bench.sets[::4]), bench.folder)
    res = run_benchmark(sub, methods, bodies)
    means = {k: v["random_mean"] for k, v in res["methods"].items()}
    assert means["optim"]["position_residual_mm"] < 0.5 * means["rest"]["position_residual_mm"]
    assert means["optim"]["mpjpe_mm"] < means["rest"]["mpjpe_mm"]
    assert means["nn"]["mpjpe_mm"] < means["rest"]["mpjpe_mm"]
    table = results_markdown(res)
    assert "| optim |" in table and "fixed_6pt" in table


def test_nn_returns_exact_train_pose(bodies, bench):
    """A query made from a train pose on the neutral body, beta = 0, finds that very pose."""
    from smplik.kinematics import forward_kinematics

    bset = bench.sets[-1].head(3)
    pose = torch.randn(50, 24, 3, generator=torch.Generator().manual_seed(0)) * 0.4
    nn = NearestNeighborMethod.from_dataset(pose, bodies)
    J_rest = bodies.rest_joints(torch.zeros(3, 10), torch.zeros(3, dtype=torch.long))
    _, p = forward_kinematics(nn.R_local[[7, 21, 33]], J_rest, torch.tensor([1.0, 0.2, -3.0]))
    data = bset.effectors.data.clone()
    data[..., :3] = p[torch.arange(3)[:, None], bset.effectors.joint]
    eff = type(bset.effectors)(bset.effectors.joint, bset.effectors.type, data, bset.effectors.tolerance,
                               bset.effectors.mask)
    query = type(bset)(bset.name, bset.kind, bset.num_effectors, bset.R_local, bset.transl, torch.zeros(3, 10),
                       torch.zeros(3, dtype=torch.long), bset.joints, eff)
    pred = nn(query)
    torch.testing.assert_close(pred.R_local, nn.R_local[[7, 21, 33]])
    torch.testing.assert_close(pred.transl, torch.tensor([1.0, 0.2, -3.0]).expand(3, 3), atol=1e-5, rtol=0)


def test_fixed_set_effectors_are_the_named_joints_ground_truth(bench):
    """The fixed sets put exact position effectors on their named joints, at the ground-truth joint positions."""
    for bset in bench.sets:
        if bset.kind != "fixed":
            continue
        eff = bset.effectors
        names = [[JOINT_NAMES[j] for j in row] for row in eff.joint.tolist()]
        assert all(row == list(FIXED_SETS[bset.name]) for row in names), bset.name
        joints = torch.tensor([JOINT_INDEX[n] for n in FIXED_SETS[bset.name]])
        torch.testing.assert_close(eff.data[..., :3], bset.joints[:, joints], atol=1e-6, rtol=0)
        assert (eff.data[..., 3:] == 0).all()


# ----------------------------------------------------------------------------- per subject


@pytest.fixture(scope="module")
def subject_bench(tmp_path_factory, two_subject_cache):
    out = tmp_path_factory.mktemp("bench-subjects")
    make_benchmark(two_subject_cache, out, split="test", seed=0, samples_per_count=12)
    return load_benchmark(out)


def test_sample_subjects_come_from_the_cache_clip_names(subject_bench, two_subject_cache, tiny_cache):
    from smplik.data.dataset import load_cache

    dataset = load_cache(two_subject_cache)
    labels = sample_subjects(subject_bench, dataset)
    assert list(labels) == set_names()
    test = dataset.subset("test")
    for bset in subject_bench.sets:
        clips = [test.clip_names[test.clip_id[f]] for f in bset.frame.tolist()]
        assert list(labels[bset.name]) == [c.split("_")[0] for c in clips]  # 13_01.npz -> 13, 86_05.npz -> 86
    assert set().union(*labels.values()) == {"13", "86"}
    assert sample_subjects(subject_bench, test) == labels  # the split itself works too
    with pytest.raises(ValueError, match="frames"):
        sample_subjects(subject_bench, load_cache(tiny_cache))


def test_per_subject_results_do_not_let_one_subject_hide_another(subject_bench, two_subject_cache, bodies):
    """A method exact on subject 13 and at the rest pose on subject 86: the per-subject report shows both."""
    from smplik.data.dataset import load_cache

    labels = sample_subjects(subject_bench, load_cache(two_subject_cache))
    rest = RestPoseMethod(bodies)

    def half_oracle(bset):
        good = torch.tensor([s == "13" for s in labels[bset.name]])
        guess = rest(bset)
        return Prediction(torch.where(good[:, None, None, None], bset.R_local, guess.R_local),
                          torch.where(good[:, None], bset.transl, guess.transl))

    res = run_benchmark(subject_bench, {"half": half_oracle, "rest": rest}, bodies, subjects=labels)
    randoms = [s for s in subject_bench.sets if s.kind == "random"]
    counts = {k: sum(list(labels[s.name]).count(k) for s in randoms) for k in ("13", "86")}
    assert res["subjects"] == counts and counts["13"] != counts["86"]
    half = res["methods"]["half"]
    assert half["subjects"]["13"]["mpjpe_mm"] < 1e-3 and half["subjects"]["13"]["samples"] == counts["13"]
    assert half["subjects"]["86"]["mpjpe_mm"] == pytest.approx(res["methods"]["rest"]["subjects"]["86"]["mpjpe_mm"])
    assert half["subjects"]["86"]["mpjpe_mm"] > 10
    for key in ("mpjpe_mm", "geodesic_rad", "position_residual_mm"):
        expected = (half["subjects"]["13"][key] + half["subjects"]["86"][key]) / 2  # unweighted over subjects
        assert half["subject_mean"][key] == pytest.approx(expected)
    pooled = (counts["86"] * half["subjects"]["86"]["mpjpe_mm"]) / sum(counts.values())
    assert half["subject_mean"]["mpjpe_mm"] != pytest.approx(pooled)  # not a mean over samples
    table = results_markdown(res)
    assert "mean over subjects" in table and "| 13 |" in table and "| 86 |" in table


def test_ik_benchmark_script_reports_subjects(tmp_path, two_subject_cache):
    """benchmarks/ik_benchmark.py (reduced run) writes the per-subject results and table."""
    import runpy

    script = runpy.run_path(str(Path(__file__).resolve().parents[1] / "benchmarks" / "ik_benchmark.py"))
    code = script["main"](["--data", str(two_subject_cache), "--files", str(tmp_path / "files"), "--threads", "1",
                           "--samples-per-count", "4", "--methods", "rest,optim", "--optim-iterations", "2",
                           "--results", str(tmp_path / "results"), "--name", "reduced"])
    assert code == 0
    data = json.loads((tmp_path / "results" / "reduced.json").read_text())
    assert set(data["subjects"]) == {"13", "86"}
    assert set(data["methods"]["optim"]["subjects"]) == {"13", "86"}
    assert "mean over subjects" in (tmp_path / "results" / "reduced.md").read_text()
    assert script["main"](["--data", str(tmp_path / "absent.npz")]) == 1


@pytest.fixture(scope="module")
def cli():
    from smplik.cli import benchmark as benchmark_cli

    root = typer.Typer()
    root.add_typer(benchmark_cli.app, name="benchmark")
    return root


def test_cli_make_and_run(tmp_path, cli, tiny_cache, tiny_model):
    out = tmp_path / "files"
    res = CliRunner().invoke(cli, ["benchmark", "make", "--data", str(tiny_cache), "--out", str(out),
                                   "--samples-per-count", "3", "--seed", "1"])
    assert res.exit_code == 0, res.output
    model = tiny_model
    results = tmp_path / "results.json"
    res = CliRunner().invoke(cli, ["benchmark", "run", "--files", str(out), "--checkpoint", str(model),
                                   "--methods", "smplik,smplik_net,optim,nn,rest", "--optim-iterations", "3",
                                   "--out", str(results)])
    assert res.exit_code == 0, res.output
    data = json.loads(results.read_text())
    assert set(data["methods"]) == {"smplik", "smplik_net", "optim", "nn", "rest"}
    assert data["settings"]["refine"] == RefineConfig().to_dict()
    refined, raw = (data["methods"][m]["random_mean"]["position_residual_mm"] for m in ("smplik", "smplik_net"))
    assert refined < 0.5 * raw, (refined, raw)
    for method in data["methods"].values():
        assert set(method["sets"]) == set(set_names())
        assert method["random_mean"]["time_ms_per_pose"] > 0
    assert "| smplik |" in res.output
    assert set(data["subjects"]) == {"clip5"} and "subject_mean" in data["methods"]["optim"]  # the test clip's subject
    res = CliRunner().invoke(cli, ["benchmark", "run", "--files", str(out), "--methods", "magic",
                                   "--out", str(results)])
    assert res.exit_code != 0
    res = CliRunner().invoke(cli, ["benchmark", "run", "--files", str(out), "--methods", "optim",
                                   "--data", str(tmp_path / "absent.npz"), "--out", str(results)])
    assert res.exit_code == 1 and "absent.npz" in res.output and "Traceback" not in res.output


def test_optimization_runs_after_inference_mode_fk(bench, bodies):
    """FK's cached index tensors built under inference_mode must not break the autograd baseline."""
    from smplik import kinematics
    from smplik.kinematics import forward_kinematics

    kinematics._levels.cache_clear()
    with torch.inference_mode():
        forward_kinematics(torch.eye(3).expand(1, 24, 3, 3), torch.zeros(1, 24, 3))
    prior = PosePrior(torch.tensor([1.0, 0, 0, 0, 1.0, 0]).repeat(24, 1), torch.full((24, 6), 0.3))
    pred = OptimizationIK(bodies, prior, iterations=2)(bench.sets[0].head(2))
    assert pred.R_local.shape == (2, 24, 3, 3)


MANIFEST_MUTATIONS = [  # (what the external campaign found: KeyError 'sha256'/'name', PosixPath / bool, ...)
    ("sha256 missing", lambda m: m["sets"][0].pop("sha256")),
    ("name missing", lambda m: m["sets"][0].pop("name")),
    ("file a bool", lambda m: m["sets"][0].__setitem__("file", True)),
    ("file a list (unhashable)", lambda m: m["sets"][0].__setitem__("file", [1])),
    ("file outside the folder", lambda m: m["sets"][0].__setitem__("file", "../x.npz")),
    ("sets a number (not subscriptable)", lambda m: m.__setitem__("sets", 3)),
    ("a set a string", lambda m: m["sets"].__setitem__(0, "x")),
    ("source missing", lambda m: m.pop("source")),
    ("source data a number", lambda m: m["source"].__setitem__("data", 1)),
    ("seed a float", lambda m: m.__setitem__("seed", 1.5)),
    ("manifest a list", lambda m: m.clear() or m.__setitem__("format", ["smplik-benchmark"])),
]
ARRAY_MUTATIONS = [
    ("eff_joint", lambda a: a + 99), ("eff_joint", lambda a: a.astype(np.float32)), ("eff_type", lambda a: -a - 1),
    ("joints", lambda a: a[:, :5]), ("R_local", lambda a: a * np.nan), ("frame", lambda a: a[:-1]),
    ("betas", lambda a: np.zeros((len(a), 3))), ("gender", lambda a: a + 5),
]


@pytest.mark.parametrize("what,mutate", MANIFEST_MUTATIONS, ids=[m[0] for m in MANIFEST_MUTATIONS])
def test_a_malformed_manifest_is_one_clean_error(tmp_path, files, what, mutate):
    import shutil

    out = tmp_path / "f"
    shutil.copytree(files, out)
    manifest = json.loads((out / "manifest.json").read_text())
    mutate(manifest)
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError) as info:
        load_benchmark(out)
    assert "manifest.json" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("key,mutate", ARRAY_MUTATIONS, ids=[f"{k}{i}" for i, (k, _) in enumerate(ARRAY_MUTATIONS)])
def test_a_malformed_set_file_is_one_clean_error(tmp_path, files, key, mutate):
    import shutil

    out = tmp_path / "f"
    shutil.copytree(files, out)
    with np.load(out / "fixed_5pt.npz") as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays[key] = mutate(arrays[key])
    np.savez(out / "fixed_5pt.npz", **arrays)
    with pytest.raises(ValueError, match=f"fixed_5pt.npz: array '{key}'"):
        load_benchmark(out, verify=False)


def test_cli_run_on_a_mutated_manifest_prints_one_error_line(tmp_path, files):
    import shutil
    import subprocess
    import sys

    out = tmp_path / "f"
    shutil.copytree(files, out)
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["sets"][0]["file"] = False
    (out / "manifest.json").write_text(json.dumps(manifest))
    proc = subprocess.run([sys.executable, "-m", "smplik.cli", "benchmark", "run", "--files", str(out), "--methods",
                           "rest", "--out", str(tmp_path / "r.json")], capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "COLUMNS": "60"})
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and "sets[0].file" in lines[0], proc.stderr
