"""A glTF character is read at its own size (glTF is in metres): a 7 cm figurine to a 27 m giant goes through
``invert-shape`` with no options, one line saying so, and no bank-range refusal; a human exported in centimetres
without the 0.01 scale (145 m) is still read in centimetres."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

FIGURE = Path(__file__).resolve().parent / "data" / "rigs" / "RiggedFigure.glb"  # 1.45 m, Khronos, CC-BY 4.0


def _scaled(tmp_path: Path, factor: float) -> Path:
    """RiggedFigure with its root node (``Z_UP``, a ``matrix``) scaled by ``factor``: the whole character is that
    much larger in the file's metres, as a figurine or giant exported at its own size is."""
    import pygltflib

    doc = pygltflib.GLTF2.load_binary(FIGURE)
    m = np.array(doc.nodes[0].matrix, dtype=np.float64).reshape(4, 4)
    m[:3, :3] *= factor
    doc.nodes[0].matrix = m.reshape(-1).tolist()
    out = tmp_path / f"figure_x{factor:g}.glb"
    doc.save_binary(str(out))
    return out


def test_a_gltf_figurine_and_giant_are_read_at_their_own_size(tmp_path):
    from typer.testing import CliRunner

    from shape_inversion.skeleton_io import read_character
    from smplik.cli.main import app

    head_ankle = read_character(FIGURE).head_ankle_height_m
    runner = CliRunner()
    shapes = {}
    for factor in (0.05, 19.0):  # about 0.07 m and 27 m tall
        f = _scaled(tmp_path, factor)
        res = runner.invoke(app, ["invert-shape", str(f), "--out", str(tmp_path / f"{factor:g}.json")])
        assert res.exit_code == 0, res.output
        assert "Traceback" not in res.output and "edge of the sample bank" not in res.output
        own = [line for line in res.output.splitlines() if "read at its own size" in line]
        assert len(own) == 1  # one line says so, with the size
        tall = float(own[0].split("about ")[1].split(" m tall")[0])
        assert tall == pytest.approx(head_ankle * factor / 0.84, rel=0.01, abs=0.006)  # printed to 1 cm
        shapes[factor] = json.loads((tmp_path / f"{factor:g}.json").read_text())
        assert shapes[factor]["character"]["units_m"] == 1.0
    small, giant = shapes[0.05], shapes[19.0]
    assert giant["scale"] / small["scale"] == pytest.approx(19.0 / 0.05, rel=1e-3)  # one global factor
    np.testing.assert_allclose(giant["betas"], small["betas"], atol=1e-3)  # the same shape at any size


@pytest.mark.parametrize("factor", [0.05, 0.14, 14.0, 19.0])
def test_the_skeleton_keeps_the_files_metres(tmp_path, factor):
    from shape_inversion.skeleton_io import read_character

    plain = read_character(FIGURE)
    char = read_character(_scaled(tmp_path, factor))
    assert char.units_m == 1.0 and "metres" in char.units_source
    assert char.head_ankle_height_m == pytest.approx(plain.head_ankle_height_m * factor, rel=1e-6)


def test_a_human_in_centimetres_without_its_scale_is_still_read_in_centimetres(tmp_path):
    from shape_inversion.skeleton_io import read_character

    plain = read_character(FIGURE)
    char = read_character(_scaled(tmp_path, 100.0))  # 145 m in metres: beyond any character's size
    assert char.units_m == pytest.approx(0.01) and char.units_source == "detected"
    assert char.head_ankle_height_m == pytest.approx(plain.head_ankle_height_m, rel=1e-6)
