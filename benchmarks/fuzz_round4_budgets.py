"""The fuzz campaign's round-4 *budget* cases (issue 45, first half): budgets on what a command will make, rates
bounded where they are read, wrong JSON types in tracker files and SteamVR logs, and the one model-file reader.

Every case must end as ``clean_error`` (exit 1, one ``error:`` line) whose line holds the case's ``needle`` (the
file's key or the limit's environment variable), under 2 GB, quickly; the exceptions are the ``accept`` cases
(valid inputs the old readers broke on, e.g. a quaternion ``[1e300, 0, 0, 0]``: exit 0).

:func:`round4_budget_cases` writes its own small material (tracker recordings, SteamVR logs, tracking and IK model
files from the shipped ones, an animation file, AMASS clips) and returns ``(case, needle)`` pairs;
``benchmarks/fuzz_campaign.py`` runs them in subprocesses (``--round4-budgets-only`` alone, results in
``benchmarks/results/fuzz_round4_budgets.json``), ``tests/test_input_budgets.py`` in-process.

Groups (``reader``): ``r4_trackers`` (TQ, TF, strings as numbers, the tracker's frame cap), ``r4_steamvr`` (SV1-SV4,
string timestamps), ``r4_tracking_model`` (MH, MF, MS, MZ, stride-0 and unknown keys), ``r4_ik_model`` (a view
as a weight), ``r4_animation`` (AF, KF, PE and AMASS ``mocap_framerate``).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from fuzz_campaign import Case

ACCEPT = "<accept>"
"""The needle of a case that must succeed (exit 0)."""

TRACKER_ROWS = {"head": [0.0, 1.6, 0.0], "left_wrist": [0.3, 1.0, 0.05], "right_wrist": [-0.3, 1.0, 0.05],
                "pelvis": [0.0, 0.95, 0.0]}


def tracker_doc(frames: int = 60, fps: Any = 60, **edits: Any) -> dict[str, Any]:
    """A ``smplik-trackers`` document (:mod:`smplik.tracking.io`): four still trackers, the head with an identity
    rotation; ``edits`` replace a tracker's ``position``/``rotation`` (key ``head_rotation`` etc.)."""
    trackers: dict[str, Any] = {name: {"position": [list(p)] * frames} for name, p in TRACKER_ROWS.items()}
    trackers["head"]["rotation"] = [[1.0, 0.0, 0.0, 0.0]] * frames
    for key, value in edits.items():
        name, field = key.rsplit("_", 1)
        trackers[name][field] = value
    return {"format": "smplik-trackers", "version": 1, "fps": fps, "trackers": trackers}


def steamvr_lines(frames: int = 60, *, last: float | None = None, edit: Any = None) -> str:
    """A SteamVR JSON-lines log in the layout :func:`smplik.tracking.io.read_steamvr_jsonl` reads (the OpenVR
    poller's records: ``timestamp`` and ``devices`` with ``index``, ``class``, ``pose``): an HMD and two
    controllers standing still; ``last`` replaces the final timestamp, ``edit(record)`` changes every record."""
    def pose(x: float, y: float) -> dict[str, Any]:
        return {"valid": True, "position": {"x": x, "y": y, "z": 0.0}, "quaternion": {"x": 0.0, "y": 0.0, "z": 0.0,
                                                                                      "w": 1.0}}

    out = []
    for i in range(frames):
        record = {"timestamp": i / 60 if last is None or i < frames - 1 else last,
                  "devices": [{"index": 0, "class": "HMD", "pose": pose(0.0, 1.65)},
                              {"index": 1, "class": "Controller", "pose": pose(0.3, 1.0)},
                              {"index": 2, "class": "Controller", "pose": pose(-0.3, 1.0)}]}
        if edit is not None:
            edit(record)
        out.append(json.dumps(record))
    return "\n".join(out) + "\n"


def animation_doc(frames: int = 30, fps: Any = 30.0, keyframes: list[Any] | None = None) -> dict[str, Any]:
    """A one-track ``smplik-animation`` document (:mod:`workflows.animation.files`) in the rest pose."""
    track = {"name": "person_0", "track_id": "0", "gender": "neutral", "betas": [0.0] * 10, "scale": 1.0,
             "skeleton": None, "first_frame": 0, "global_orient": [[0.0, 0.0, 0.0]] * frames,
             "body_pose": [[[0.0, 0.0, 0.0]] * 23] * frames, "transl": [[0.0, 0.9, 0.0]] * frames,
             "contacts": None, "repaired": [], "keyframes": keyframes or []}
    return {"format": "smplik-animation", "version": 1, "source": "fuzz", "source_format": "smplik-trackers",
            "fps": fps, "space": "world", "camera": None, "clean": None, "tracks": [track]}


EFFECTOR = {"type": "position", "joint": "left_wrist", "value": [0.3, 1.0, 0.1]}


def _amass(path: Path, rate: Any, frames: int = 30) -> Path:
    """An AMASS SMPL+H clip (``poses`` (T, 156), ``trans``, ``betas`` (16,), ``gender``, ``mocap_framerate``)."""
    np.savez(path, poses=np.zeros((frames, 156)), trans=np.zeros((frames, 3)), betas=np.zeros(16),
             gender=np.asarray("neutral"), mocap_framerate=np.asarray(rate))
    return path


def _deflated_member(src: Path, dst: Path, inflated: int) -> Path:
    """``src`` (a torch.save zip) with its first storage member replaced by ``inflated`` zero bytes, deflated (a
    few hundred KB on disk)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        replaced = False
        for info in zin.infolist():
            if "/data/" in info.filename and not replaced:
                zout.writestr(info.filename, bytes(inflated), compress_type=zipfile.ZIP_DEFLATED, compresslevel=1)
                replaced = True
            else:
                zout.writestr(info, zin.read(info))
    return dst


def round4_budget_cases(work: Path) -> list[tuple[Case, str]]:
    """Every round-4 budget case with the text its one error line must hold (or :data:`ACCEPT`)."""
    import torch

    from smplik.model_io import read_model_file, read_torch_file
    from smplik.solver import packaged_model_path
    from smplik.tracking.model_io import DEFAULT_CHECKPOINT

    work.mkdir(parents=True, exist_ok=True)
    cases: list[tuple[Case, str]] = []
    n = iter(range(10**6))

    def folder() -> Path:
        d = work / f"r4_{next(n):03d}"
        d.mkdir()
        return d

    def track(reader: str, doc: Any, note: str, needle: str, *, suffix: str = ".json", extra: tuple = ()) -> None:
        d = folder()
        path = d / f"t{suffix}"
        path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
        cases.append((Case(reader, ["track", str(path), "--out", str(d / "out"), "--export", "", *extra], note,
                           keep=path), needle))

    # trackers JSON: TQ (normalise, then check), TF (rates and the frames the resampling makes), strings
    track("r4_trackers", tracker_doc(head_rotation=[[1e300, 0, 0, 0]] * 60), "TQ rotation 1e300", ACCEPT)
    track("r4_trackers", tracker_doc(head_rotation=[[1e-300, 0, 0, 0]] * 60), "TQ rotation 1e-300", ACCEPT)
    track("r4_trackers", tracker_doc(head_rotation=[[0, 0, 0, 0]] + [[1, 0, 0, 0]] * 59), "zero quaternion",
          "trackers.head.rotation[0]")
    track("r4_trackers", tracker_doc(fps=0.001), "TF fps 0.001 (60 rows)", "fps: must be a frame rate in [1, 1000]")
    track("r4_trackers", tracker_doc(frames=2, fps=0.001), "TF fps 0.001 (2 rows)", "fps")
    track("r4_trackers", tracker_doc(fps=5e-324), "fps 5e-324", "fps")
    track("r4_trackers", tracker_doc(fps="60"), "fps '60'", "fps: must be a frame rate (a number)")
    track("r4_trackers", tracker_doc(frames=20_000, fps=1), "20,000 rows at 1 frame/s (1.2 M at 60)",
          "SMPLIK_MAX_OUTPUT_FRAMES")
    track("r4_trackers", tracker_doc(frames=40_000), "40,000 frames at 60 frames/s", "SMPLIK_MAX_TRACK_FRAMES")
    track("r4_trackers", json.dumps(tracker_doc()).replace('"fps": 60', '"fps": 1' + "0" * 5000), "fps of 5001 digits",
          "t.json: invalid JSON (Exceeds the limit (4300 digits)")
    track("r4_trackers", tracker_doc(head_position=[["0", "1.6", "0"]] * 60), "position strings",
          "trackers.head.position: must be numbers")
    track("r4_trackers", tracker_doc(pelvis_position=[[0, True, 0]] * 60), "position bool",
          "trackers.pelvis.position: must be numbers")
    track("r4_trackers", tracker_doc(head_rotation=[[1, 0, 0, "0"]] * 60), "rotation string",
          "trackers.head.rotation: must be numbers")

    # SteamVR logs: SV1/SV2 (the span), SV3/SV4 (JSON types), string timestamps
    def set_dev(i: int, key: str, value: Any) -> Any:
        return lambda r: r["devices"][i].__setitem__(key, value)

    sv = [("SV1 last timestamp 1e7", steamvr_lines(last=1e7), "SMPLIK_MAX_OUTPUT_FRAMES"),
          ("SV2 last timestamp 1e15", steamvr_lines(last=1e15), "line 60.timestamp"),
          ("last timestamp 1e300", steamvr_lines(last=1e300), "line 60.timestamp"),
          ("SV3 pose [1, 2]", steamvr_lines(edit=set_dev(0, "pose", [1, 2])), "line 1.devices[0].pose"),
          ("SV3 pose 5", steamvr_lines(edit=set_dev(1, "pose", 5)), "line 1.devices[1].pose"),
          ("SV3 devices {a: 1}", steamvr_lines(edit=lambda r: r.__setitem__("devices", {"a": 1})),
           "line 1.devices"),
          ("SV3 device 'HMD'", steamvr_lines(edit=lambda r: r["devices"].__setitem__(0, "HMD")),
           "line 1.devices[0]"),
          ("SV3 position list", steamvr_lines(
              edit=lambda r: r["devices"][0]["pose"].__setitem__("position", [0, 1, 2])),
           "line 1.devices[0].pose.position"),
          ("SV3 quaternion w string", steamvr_lines(
              edit=lambda r: r["devices"][2]["pose"]["quaternion"].__setitem__("w", "1")),
           "line 1.devices[2].pose.quaternion.w"),
          ("SV3 valid 'yes'", steamvr_lines(edit=lambda r: r["devices"][0]["pose"].__setitem__("valid", "yes")),
           "line 1.devices[0].pose.valid"),
          ("SV4 index Infinity", steamvr_lines(edit=set_dev(0, "index", 0)).replace('"index": 0', '"index": Infinity'),
           "line 1"),
          ("index 1e300", steamvr_lines(edit=set_dev(0, "index", 1e300)), "line 1.devices[0].index"),
          ("class 5", steamvr_lines(edit=set_dev(0, "class", 5)), "line 1.devices[0].class"),
          ("timestamp string", steamvr_lines(edit=lambda r: r.__setitem__("timestamp", str(r["timestamp"]))),
           "line 1.timestamp: must be a number"),
          ("timestamp NaN", steamvr_lines().replace('"timestamp": 0.0', '"timestamp": NaN'), "line 1"),
          ("record a list", "[1, 2]\n" + steamvr_lines(), "line 1")]
    for note, text, needle in sv:
        track("r4_steamvr", text, note, needle, suffix=".jsonl")

    # tracking model files through the one reader: MH, MF, MS, MZ, stride 0
    blob = read_torch_file(DEFAULT_CHECKPOINT, what="tracking model")  # raw: info.net stays a dict
    trackers = tracker_doc()

    def model_case(note: str, needle: str, edit: Any = None, raw: Path | None = None) -> None:
        d = folder()
        path = raw if raw is not None else d / "model.pt"
        if raw is None:
            b = {**blob, "info": {**blob["info"], "net": dict(blob["info"]["net"])}}
            edit(b)
            torch.save(b, path)
        (d / "t.json").write_text(json.dumps(trackers))
        cases.append((Case("r4_tracking_model", ["track", str(d / "t.json"), "--checkpoint", str(path), "--out",
                                                 str(d / "out"), "--export", ""], note, keep=path), needle))

    model_case("MH hidden 16000", "info.net.hidden", lambda b: b["info"]["net"].__setitem__("hidden", 16000))
    model_case("decoder 0", "info.net.decoder", lambda b: b["info"]["net"].__setitem__("decoder", 0))
    model_case("hidden true", "info.net.hidden", lambda b: b["info"]["net"].__setitem__("hidden", True))
    model_case("MF fps 0", "info.net.fps", lambda b: b["info"]["net"].__setitem__("fps", 0))
    model_case("MF fps '60'", "info.net.fps", lambda b: b["info"]["net"].__setitem__("fps", "60"))
    model_case("trackers 'abc'", "info.net.trackers", lambda b: b["info"]["net"].__setitem__("trackers", "abc"))
    model_case("unknown net key", "info.net.depth", lambda b: b["info"]["net"].__setitem__("depth", 3))
    model_case("MS pose_lo 'abc'", "key 'pose_lo'", lambda b: b.__setitem__("pose_lo", "abc"))
    model_case("pose_hi NaN", "key 'pose_hi'", lambda b: b.__setitem__("pose_hi", torch.full((24, 3), float("nan"))))
    model_case("stride-0 pose_lo", "stride", lambda b: b.__setitem__("pose_lo", torch.zeros(1, 1).expand(24, 3)))
    model_case("stride-0 weight", "stride", lambda b: b["state_dict"].__setitem__(
        "x_mean", torch.zeros(1).expand(b["state_dict"]["x_mean"].shape[0])))
    model_case("state_dict a list", "key 'state_dict'", lambda b: b.__setitem__("state_dict", [1, 2]))
    d = folder()
    plain = d / "plain.pt"
    torch.save(blob, plain)
    model_case("MZ deflated 80 MB member", "is compressed and inflates to 83886080 bytes",
               raw=_deflated_member(plain, d / "bomb.pt", 80 << 20))

    # IK model file: a transposed view as a weight (the same reader)
    ik = read_model_file(packaged_model_path())
    name, weight = next((k, v) for k, v in ik["model"].items() if v.ndim == 2 and v.shape[0] != v.shape[1])
    d = folder()
    torch.save({**ik, "model": {**ik["model"], name: weight.t().contiguous().t()}}, d / "model.pt")
    (d / "eff.json").write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [EFFECTOR]}))
    cases.append((Case("r4_ik_model", ["solve", str(d / "eff.json"), "--checkpoint", str(d / "model.pt"), "--out",
                                       str(d / "pose.json")], "weight a transposed view", keep=d / "model.pt"),
                  "stride"))

    # animation files: AF (fps), KF (effectors per keyframe), PE (--preview-every), AMASS mocap_framerate
    effectors_file = work / "effectors.json"
    effectors_file.write_text(json.dumps({"format": "smplik-effectors", "version": 1, "effectors": [EFFECTOR]}))

    def edit_case(doc: dict[str, Any], note: str, needle: str) -> None:
        d = folder()
        path = d / "animation.json"
        path.write_text(json.dumps(doc))
        cases.append((Case("r4_animation", ["scene", "edit-keyframe", str(path), "--frame", "5", "--effectors",
                                            str(effectors_file), "--out", str(d / "edited.json"), "--export", "bvh"],
                           note, keep=path), needle))

    edit_case(animation_doc(fps=5e-324), "AF fps 5e-324", "fps: must be a frame rate in [1, 1000]")
    edit_case(animation_doc(fps=0.5), "fps 0.5", "fps")
    edit_case(animation_doc(fps=1e308), "fps 1e308", "fps")
    edit_case(animation_doc(keyframes=[{"frame": 5, "effectors": [EFFECTOR] * 200_000}]), "KF 200,000 effectors",
              "tracks[0].keyframes[0].effectors: 200000 effectors; at most 64")
    edit_case(animation_doc(keyframes=[{"frame": i % 30, "effectors": [EFFECTOR] * 3000} for i in range(30)]),
              "KF 30 x 3,000 effectors", "at most 64")
    edit_case(animation_doc(keyframes=[{"frame": 5, "effectors": [EFFECTOR] * 65}]), "KF 65 effectors",
              "65 effectors; at most 64")
    d = folder()
    for note, rate, needle in (("AMASS mocap_framerate 0.001", 0.001, "mocap_framerate: must be a frame rate"),
                               ("AMASS mocap_framerate 1e9", 1e9, "mocap_framerate"),
                               ("AMASS mocap_framerate '60'", "60", "mocap_framerate")):
        clip = _amass(d / f"clip_{len(cases)}.npz", rate)
        cases.append((Case("r4_animation", ["scene", "animate", str(clip), "--out", str(d / f"o{len(cases)}")], note,
                           keep=clip), needle))
    clip = _amass(d / "ok_clip.npz", 30.0)
    cases.append((Case("r4_animation", ["scene", "animate", str(clip), "--out", str(d / "o_pe"), "--preview",
                                        str(d / "p.gif"), "--preview-every", "100000"], "PE --preview-every 100000",
                       keep=clip), "--preview-every"))
    return cases


def run_round4_budgets(work: Path, timeout: float, env: dict[str, str], workers: int) -> list[dict[str, Any]]:
    """Run every case in a subprocess (:func:`fuzz_campaign.run_case`: 2 GB address-space cap, ``timeout``);
    each result gets ``expected`` (the needle) and ``as_expected``: a clean error whose line holds the needle
    (or ``accepted`` for an :data:`ACCEPT` case), the input byte-identical."""
    from concurrent.futures import ThreadPoolExecutor

    from fuzz_campaign import run_case

    pairs = round4_budget_cases(work)

    def one(pair: tuple[Case, str]) -> dict[str, Any]:
        case, needle = pair
        res = run_case(case, timeout, env)
        ok = (res["outcome"] == "accepted" if needle == ACCEPT
              else res["outcome"] == "clean_error" and needle in " ".join(res["last_line"].split()))
        return {**res, "expected": needle, "as_expected": ok}

    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(one, pairs))
