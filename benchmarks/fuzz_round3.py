"""The fuzz campaign's round-3 cases (issue 36): inputs that gave a traceback, were accepted silently or
destroyed data. Every case must end as ``clean_error`` (exit 1, one ``error:`` line) and leave its ``keep``
file byte-identical.

:func:`round3_cases` writes its own small material (a BVH and a GLB character, a ROMP estimate, a scene, a
pose cache, WHAM output) and returns the cases; ``benchmarks/fuzz_campaign.py`` runs them in subprocesses with
the crafted cases, ``tests/test_input_errors_one_line.py`` runs them in-process in CI (a few seconds).

Groups (the ``reader`` of each case): ``r3_config`` (training options and config values out of range),
``r3_pose_cache`` (cache values: a non-scalar version, subject names not a list of strings, poses 1e30 or NaN),
``r3_estimator`` (WHAM ``frame_ids`` inf or 1e300), ``r3_gltf`` (a GLB whose JSON holds ``Infinity``, a
bufferView without ``buffer``, in ``invert-shape`` and in ``scene export``), ``r3_outputs`` (an output that
is an input, through the same path, a symlink or a hard link; empty output paths) and ``r3_options``
(``--betas``, ``--ensemble``, ``--fps``, ``--image``).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np
from fuzz_campaign import Case, _write_glb

EMPTY_OUTPUT = ""


def _glb_json_edit(data: bytes, edit: Any) -> bytes:
    """A GLB whose JSON chunk is ``edit(doc)``-ed (written with Python's json: ``Infinity`` as is)."""
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + n])
    edit(doc)
    chunk = json.dumps(doc).encode()
    chunk += b" " * (-len(chunk) % 4)
    rest = data[20 + n:]
    return (struct.pack("<4sII", b"glTF", 2, 20 + len(chunk) + len(rest)) + struct.pack("<I4s", len(chunk), b"JSON")
            + chunk + rest)


def valid_pose_cache() -> dict[str, np.ndarray]:
    """The arrays of a 4-frame pose cache in the layout of :func:`smplik.data.dataset.build_cache`."""
    rng = np.random.default_rng(0)
    N = 4
    return {"version": np.asarray(1, dtype=np.int64), "settings": np.asarray(json.dumps({"fps": 30.0})),
            "pose": rng.normal(0, 0.2, (N, 24, 3)).astype(np.float32), "transl": np.zeros((N, 3), np.float32),
            "betas": np.zeros((N, 10), np.float32), "has_betas": np.zeros(N, bool),
            "gender": np.full(N, -1, np.int8), "clip_id": np.zeros(N, np.int32), "subject_id": np.zeros(N, np.int32),
            "frame": np.arange(N, dtype=np.int32), "split": np.zeros(N, np.int8),
            "clip_names": np.asarray(["s01_01"]), "clip_fps": np.asarray([30.0], np.float32),
            "subject_names": np.asarray(["s01"])}


CACHE_MUTATIONS: dict[str, Any] = {
    "version_1d": lambda a: a.__setitem__("version", np.asarray([1], dtype=np.int64)),
    "version_float": lambda a: a.__setitem__("version", np.asarray(1.0)),
    "subject_names_scalar": lambda a: a.__setitem__("subject_names", np.asarray("s01")),
    "subject_names_numbers": lambda a: a.__setitem__("subject_names", np.asarray([1.0])),
    "clip_names_short": lambda a: a.__setitem__("clip_id", np.full(4, 3, np.int32)),
    "pose_1e30": lambda a: a["pose"].__setitem__((1, 3, 0), 1e30),
    "pose_nan": lambda a: a["pose"].__setitem__((2, 0, 1), np.nan),
    "transl_inf": lambda a: a["transl"].__setitem__((0, 1), np.inf),
    "frame_negative": lambda a: a["frame"].__setitem__(0, -1),
    "clip_fps_zero": lambda a: a.__setitem__("clip_fps", np.asarray([0.0], np.float32)),
    "gender_7": lambda a: a["gender"].__setitem__(0, 7),
    "settings_list": lambda a: a.__setitem__("settings", np.asarray("[1, 2]")),
}


def _scene(path: Path) -> dict[str, Any]:
    """A solved one-character scene (the shipped model) written to ``path``; returns its JSON."""
    from smplik.conventions import Gender
    from smplik.effectors import Effector
    from smplik.solver import IKSolver
    from workflows.scene import Scene, SceneCharacter, save_scene

    eff = (Effector.position("left_wrist", [0.4, 1.1, 0.2]), Effector.position("pelvis", [0.0, 0.9, 0.1]))
    pose = IKSolver.load().solve(list(eff), gender="female")
    save_scene(Scene((SceneCharacter("a", Gender.FEMALE, np.zeros(10), 1.0, None, eff, pose),)), path)
    return json.loads(path.read_text())


def round3_cases(work: Path) -> list[Case]:
    """Every case of issue 36's "tracebacks" and "accepted silently or destroys data" lists (module docstring)."""
    import joblib
    import torch

    from smplik.body_model import load_body_model
    from smplik.conventions import JOINT_NAMES, PARENTS
    from workflows.examples_gen import write_mixamo_character, write_romp_example

    work.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []
    counter = iter(range(10**6))

    def folder() -> Path:
        d = work / f"r{next(counter):03d}"
        d.mkdir()
        return d

    bvh = write_mixamo_character(work / "hero.bvh")
    romp = write_romp_example(work / "romp.npz")
    J = load_body_model("neutral").rest_joints(torch.zeros(10)).double().numpy()
    glb = _write_glb(work / "char.glb", list(JOINT_NAMES), list(PARENTS), J).read_bytes()
    effectors = work / "effectors.json"
    effectors.write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [
        {"joint": "left_wrist", "type": "position", "value": [0.4, 1.1, 0.2]}]}))
    scene_doc = _scene(work / "scene.json")
    scene = work / "scene.json"
    cache = work / "cache.npz"
    np.savez(cache, **valid_pose_cache())

    # r3_config: option and config values out of range (a ConfigError at the config, one line)
    for flag, value in (("--steps", "-1"), ("--lr", "nan"), ("--width", "0"), ("--dropout", "2"),
                        ("--batch-size", "0"), ("--seed", "-1"), ("--limb-first", "1.5"), ("--precision", "fp8")):
        d = folder()
        cases.append(Case("r3_config", ["train", "--data", str(cache), "--out", str(d / "run"), flag, value],
                          f"train {flag} {value}"))
    d = folder()
    (d / "cfg.json").write_text(json.dumps({"loss": {"w_lookat": -1.0}, "effectors": {"max_effectors": 0}}))
    cases.append(Case("r3_config", ["train", "--config", str(d / "cfg.json"), "--data", str(cache), "--out",
                                    str(d / "run")], "config loss weight -1"))
    d = folder()
    (d / "bvh").mkdir()
    write_mixamo_character(d / "bvh" / "01_01.bvh")
    cases.append(Case("r3_config", ["data", "build", "--bvh", str(d / "bvh"), "--out", str(d / "c.npz"),
                                    "--split-by-subject", "-1"], "data build --split-by-subject -1"))

    # r3_pose_cache: values, not only keys
    for name, mutate in CACHE_MUTATIONS.items():
        d = folder()
        arrays = valid_pose_cache()
        mutate(arrays)
        np.savez(d / "cache.npz", **arrays)
        cases.append(Case("r3_pose_cache", ["train", "--data", str(d / "cache.npz"), "--out", str(d / "run"),
                                            "--steps", "1"], name))

    # r3_estimator: WHAM frame_ids (joblib.dump of WHAM demo.py's results dict, as tests/estimator_fixtures.py)
    for name, value in (("inf", np.inf), ("1e300", 1e300), ("nan", np.nan)):
        d = folder()
        T = 3
        track = {"pose": np.zeros((T, 72), np.float32), "trans": np.tile([0.0, 0.0, 4.0], (T, 1)).astype(np.float32),
                 "pose_world": np.zeros((T, 72), np.float32), "trans_world": np.zeros((T, 3), np.float32),
                 "betas": np.zeros((T, 10), np.float32), "verts": np.zeros((T, 4, 3), np.float32),
                 "frame_ids": np.array([0.0, 1.0, value])}
        joblib.dump({0: track}, d / "wham_output.pkl")
        cases.append(Case("r3_estimator", ["scene", "animate", str(d / "wham_output.pkl"), "--out", str(d / "anim")],
                          f"wham frame_ids {name}"))

    # r3_gltf: non-finite JSON numbers and bufferView fields, in invert-shape and scene export alike
    bad_glbs = {
        "count_infinity": lambda doc: doc["accessors"][0].__setitem__("count", float("inf")),
        "translation_infinity": lambda doc: doc["nodes"][1].__setitem__("translation", [float("-inf"), 0, 0]),
        "view_without_buffer": lambda doc: doc["bufferViews"].append({"byteLength": 4}),
        "view_buffer_5": lambda doc: doc["bufferViews"][0].__setitem__("buffer", 5),
        "view_length_negative": lambda doc: doc["bufferViews"][0].__setitem__("byteLength", -4),
        "view_past_buffer": lambda doc: doc["bufferViews"][0].__setitem__("byteOffset", 1 << 20),
    }
    for name, edit in bad_glbs.items():
        d = folder()
        (d / "char.glb").write_bytes(_glb_json_edit(glb, edit))
        cases.append(Case("r3_gltf", ["invert-shape", str(d / "char.glb"), "--out", str(d / "s.json")],
                          f"invert-shape {name}", output=d / "s.json"))
        doc = json.loads(json.dumps(scene_doc))
        doc["characters"][0]["skeleton"] = {"path": str(d / "char.glb")}
        (d / "scene.json").write_text(json.dumps(doc))
        cases.append(Case("r3_gltf", ["scene", "export", str(d / "scene.json"), "--out", str(d / "export")],
                          f"scene export {name}"))

    # r3_outputs: an output that resolves to an input; empty output paths (cwd: an empty folder)
    d = folder()
    hero = d / "hero.bvh"
    hero.write_bytes(bvh.read_bytes())
    os.symlink(hero, d / "link.bvh")
    os.link(hero, d / "hard.bvh")
    for out in ("hero.bvh", "link.bvh", "hard.bvh"):
        cases.append(Case("r3_outputs", ["invert-shape", str(hero), "--out", str(d / out)], f"invert-shape --out {out}",
                          keep=hero))
    cases.append(Case("r3_outputs", ["invert-shape", str(hero), "--out", str(d / "s.json"), "--render", str(hero)],
                      "invert-shape --render X", keep=hero))
    e = folder()
    (e / "effectors.json").write_bytes(effectors.read_bytes())
    cases.append(Case("r3_outputs", ["solve", str(e / "effectors.json"), "--out", str(e / "effectors.json")],
                      "solve --out EFFECTORS", keep=e / "effectors.json"))
    s = folder()
    (s / "scene.json").write_bytes(scene.read_bytes())
    cases.append(Case("r3_outputs", ["scene", "render", str(s / "scene.json"), "--out", str(s / "scene.json")],
                      "scene render --out SCENE", keep=s / "scene.json"))
    empty = folder()
    for args in (["scene", "from-estimate", str(romp), "--no-previews"], ["scene", "export", str(scene)],
                 ["train", "--data", str(cache), "--steps", "1"], ["invert-shape", str(bvh)],
                 ["solve", str(effectors)], ["body", "export"], ["scene", "render", str(scene)]):
        for blank in (EMPTY_OUTPUT, " "):
            cases.append(Case("r3_outputs", [*args, "--out", blank], f"{' '.join(args[:2])} --out {blank!r}",
                              cwd=empty))

    # r3_options: strict parsing
    for value in (",,", "", "1_0", "nan", "1,,2", "0x1"):
        cases.append(Case("r3_options", ["solve", str(effectors), "--out", str(folder() / "p.json"), "--betas", value],
                          f"--betas {value!r}"))
    for value in ("", "+", "mirror+mirror", "none+yaw2", "yaw2+yaw4"):
        cases.append(Case("r3_options", ["solve", str(effectors), "--out", str(folder() / "p.json"), "--ensemble",
                                         value], f"--ensemble {value!r}"))
    for value in ("1e-300", "0", "nan", "5000"):
        cases.append(Case("r3_options", ["scene", "animate", str(romp), "--out", str(folder() / "a"), "--fps", value],
                          f"scene animate --fps {value}"))
    cases.append(Case("r3_options", ["data", "build", "--bvh", str(d), "--out", str(folder() / "c.npz"), "--fps",
                                     "1e-300"], "data build --fps 1e-300"))
    img = folder()
    (img / "a_folder").mkdir()
    (img / "empty.png").write_bytes(b"")
    (img / "text.png").write_text("not an image")
    for name, value in (("folder", img / "a_folder"), ("empty", img / "empty.png"), ("not_an_image", img / "text.png"),
                        ("url", "http://example.com/photo.png"), ("dev_zero", "/dev/zero"),
                        ("missing", img / "missing.png")):
        if name != "not_an_image":  # recorded, not read, with --no-previews
            cases.append(Case("r3_options", ["scene", "from-estimate", str(romp), "--out", str(folder() / "o"),
                                             "--no-previews", "--image", str(value)], f"from-estimate --image {name}"))
        if name != "not_an_image":  # a scene without a camera draws no image (a notice says so)
            cases.append(Case("r3_options", ["scene", "render", str(scene), "--out", str(folder() / "r.png"),
                                             "--image", str(value)], f"scene render --image {name}"))
    return cases
