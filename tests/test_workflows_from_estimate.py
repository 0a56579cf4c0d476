"""``smplik scene from-estimate`` on producer-layout fixtures: frame rule, --ground, previews, one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from estimator_fixtures import CAMERA_WRITERS, framing, people, write_romp
from helpers import can_render

from workflows.scene import load_scene


@pytest.fixture()
def cli(monkeypatch, best_solver):
    from typer.testing import CliRunner

    from workflows.cli import scene_app

    monkeypatch.setattr("workflows.cli_shared._solver", lambda checkpoint: best_solver)
    return lambda *args: CliRunner().invoke(scene_app, ["from-estimate", *map(str, args)])


def test_video_frame_gives_one_character_per_track_on_the_ground(tmp_path, cli):
    aa, transl, betas = people(seed=1, **framing("romp"))
    w = write_romp(tmp_path, aa, transl, betas, video=True)
    result = cli(w.path, "--out", tmp_path / "out", "--frame", 1, "--ground", "--no-previews", "--max-effectors", 3)
    assert result.exit_code == 0, result.output
    scene = load_scene(tmp_path / "out" / "scene.json")
    assert [c.name for c in scene.characters] == ["person_5", "person_6"]
    assert scene.ground is not None and scene.ground.camera_height_m > 0.5
    raw = json.loads((tmp_path / "out" / "scene.json").read_text())
    assert raw["ground"]["camera_height_m"] == pytest.approx(scene.ground.camera_height_m)
    from workflows.scene import character_joints

    lowest = min(character_joints(c)[:, 1].min() for c in scene.characters)
    assert -0.05 < lowest < 0.2  # feet joints just above the floor (the mesh sole is at y = 0)


def test_errors_are_one_line_with_a_non_zero_exit(tmp_path, cli):
    other = tmp_path / "other.npz"
    np.savez(other, foo=np.zeros(3))
    result = cli(other, "--out", tmp_path / "o1", "--no-previews")
    assert result.exit_code == 1
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "known formats" in lines[0] and "Traceback" not in result.output
    aa, transl, betas = people(seed=2, n=3)
    many = write_romp(tmp_path, aa, transl, betas).path
    result = cli(many, "--out", tmp_path / "o2", "--no-previews", "--max-people", 2)
    assert result.exit_code == 1 and "--max-people 3" in result.output.replace("\n", "")
    bracket = tmp_path / "[bold]x.npz"
    bracket.write_bytes(b"not a zip")
    result = cli(bracket, "--out", tmp_path / "o3", "--no-previews")
    assert result.exit_code == 1 and "[bold]x.npz" in result.output.replace("\n", "")


@pytest.mark.parametrize("fmt", ["phalp", "gvhmr"])
def test_preview_shows_ghost_labels_and_overlay(tmp_path, cli, fmt):
    if not can_render():
        pytest.skip("no OpenGL backend for offscreen rendering: install EGL (apt-get install libegl1) or OSMesa")
    from workflows.examples_gen import write_background
    from workflows.scene.previews import load_image

    n = 1 if fmt == "gvhmr" else 2
    aa, transl, betas = people(seed=3, n=n, **framing(fmt, 300))
    w = CAMERA_WRITERS[fmt](tmp_path, aa, transl, betas)
    photo = write_background(tmp_path / "photo.png")
    result = cli(w.path, "--out", tmp_path / "out", "--image", photo, "--max-effectors", 4)
    assert result.exit_code == 0, result.output
    img = load_image(tmp_path / "out" / "scene.png")
    bg = load_image(photo)
    overlay = img[:, :640].astype(int)
    assert np.abs(overlay - bg.astype(int)).max() > 50  # bodies drawn over the photo
    dark = (overlay.max(-1) < 60) & (bg.astype(int).max(-1) > 100)
    assert dark.sum() > 30  # the ghost wireframe (dark bones) is there
    legend = img[:40, :200]
    assert (legend.min(-1) < 80).sum() > 50  # legend text printed on the image


@pytest.mark.parametrize(("writer", "extra"), [("gvhmr_flat", ["--format", "amass"]), ("gvhmr", ["--space", "world"])])
def test_image_without_a_camera_says_so_in_one_line_or_uses_focal(tmp_path, cli, writer, extra):
    """An AMASS-style file (even one holding K_fullimg) or GVHMR in world space yields no camera: --image is
    recorded, nothing is drawn over it, and one line says so; --focal gives the overlay a camera."""
    aa, transl, betas = people(seed=2, n=1, **framing("gvhmr", 240))
    w = CAMERA_WRITERS[writer](tmp_path, aa, transl, betas)
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"not read with --no-previews")
    result = cli(w.path, "--out", tmp_path / "a", "--image", photo, "--no-previews", "--max-effectors", 2, *extra)
    assert result.exit_code == 0, result.output
    notes = [line for line in result.output.splitlines() if "holds no camera" in line]
    assert len(notes) == 1 and "--focal" in notes[0], result.output
    assert load_scene(tmp_path / "a" / "scene.json").camera is None
    result = cli(w.path, "--out", tmp_path / "b", "--image", photo, "--no-previews", "--max-effectors", 2,
                 "--focal", 812.5, *extra)
    assert result.exit_code == 0 and "holds no camera" not in result.output, result.output
    cam = load_scene(tmp_path / "b" / "scene.json").camera
    assert cam.focal_px == 812.5 and cam.focal_rule == "given" and cam.image_size is None


def test_gvhmr_scene_records_the_intrinsics_and_image_size(tmp_path, cli):
    aa, transl, betas = people(seed=2, n=1, **framing("gvhmr", 240))
    w = CAMERA_WRITERS["gvhmr"](tmp_path, aa, transl, betas)
    assert cli(w.path, "--out", tmp_path / "o", "--no-previews", "--max-effectors", 2).exit_code == 0
    cam = json.loads((tmp_path / "o" / "scene.json").read_text())["camera"]
    assert cam["focal_rule"] == "intrinsics" and cam["image_size"] == [640, 480]


def test_character_matched_by_names_not_a_preset_goes_through_from_estimate(tmp_path, cli):
    """Regression (#23): a rig no preset fits (``rig auto``) made ``--character`` raise TypeError (Path(None))."""
    from workflows.examples_gen import write_mixamo_character

    src = write_mixamo_character(tmp_path / "mixamo.bvh", prefix="").read_text()
    for old, new in (("Left", "l"), ("Right", "r"), ("Hips", "hip")):  # DAZ-like names: lUpLeg, rForeArm, hip
        src = src.replace(old, new)
    (tmp_path / "daz_like.bvh").write_text(src)
    aa, transl, betas = people(seed=3, n=1, **framing("romp"))
    w = write_romp(tmp_path, aa, transl, betas)
    result = cli(w.path, "--out", tmp_path / "out", "--character", tmp_path / "daz_like.bvh", "--no-previews",
                 "--max-effectors", 2)
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    scene = load_scene(tmp_path / "out" / "scene.json")
    skeleton = scene.characters[0].skeleton
    assert skeleton is not None and skeleton.map is None and skeleton.rig is None  # re-read re-detects the map
    raw = json.loads((tmp_path / "out" / "scene.json").read_text())
    joint_map = raw["characters"][0]["skeleton"]["joint_map"]
    assert joint_map["left_hip"] == "lUpLeg" and joint_map["pelvis"] == "hip" and len(joint_map) == 24
    assert (tmp_path / "out" / "person_0.bvh").is_file() or list((tmp_path / "out").glob("*.bvh"))
