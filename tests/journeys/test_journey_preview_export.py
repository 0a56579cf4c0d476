"""Journey: ``smplik scene export`` a scene, then ``smplik data preview`` the BVH smplik wrote, with no options
(every command reading a BVH detects its rig: the preview once assumed CMU's and refused smplik's own files);
a broken file is one ``error:`` line in an 80-column terminal, not a paragraph wrapped over many lines.
"""

from __future__ import annotations

import re

import numpy as np


def test_data_preview_shows_a_bvh_that_smplik_exported(demo, smplik, tmp_path):
    from PIL import Image

    smplik("scene", "export", demo.out / "smpl" / "scene.json", "--out", tmp_path / "exported", "--format", "bvh")
    frames, panel = 3, 200
    for bvh in sorted((tmp_path / "exported").glob("*.bvh")):
        out = tmp_path / f"{bvh.stem}.png"
        run = smplik("data", "preview", bvh, "--out", out, "--frames", str(frames), "--panel", str(panel))
        assert re.search(rf"wrote \S*{out.name} \({bvh.name}: frames ", run.output), run.output
        with Image.open(out) as image:
            pixels = np.asarray(image.convert("RGB"))
        assert pixels.shape[:2] == (int(panel * 1.6), frames * panel)
        assert (pixels.std(axis=(0, 1)) > 5).all()  # something drawn, not a blank strip


def test_a_broken_bvh_is_one_error_line(smplik, tmp_path):
    bvh = tmp_path / ("a_long_name_as_exporters_write_them_" * 3 + ".bvh")
    bvh.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    run = smplik("data", "preview", bvh, "--out", tmp_path / "strip.png", ok=False)
    assert run.returncode == 1
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bvh}: "), run.stderr
    assert not (tmp_path / "strip.png").exists()
