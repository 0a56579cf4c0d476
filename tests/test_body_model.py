"""Our FK against smplx for the built-in model, and the export round trip through plain smplx."""

import numpy as np
import pytest
import smplx
import torch
from typer.testing import CliRunner

from smplik.body_model import BodyModelSet, load_body_model, read_model_arrays
from smplik.cli.main import app
from smplik.conventions import Gender


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SMPLIK_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "cache"))
    monkeypatch.delenv("SMPLIK_MODEL_DIR", raising=False)


def random_pose(B, seed):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(B, 3, generator=g), torch.randn(B, 23, 3, generator=g) * 0.5,
            torch.randn(B, 3, generator=g), torch.randn(B, 10, generator=g) * 1.5)


@pytest.mark.parametrize("gender", list(Gender))
def test_fk_equals_smplx_joints(gender):
    model = load_body_model(gender)
    go, bp, tr, betas = random_pose(16, hash(gender.value) % 1000)
    ours = model.joints(go, bp, tr, betas)
    _, theirs = model.vertices(go, bp, tr, betas)
    assert (ours - theirs).abs().max() < 1e-5


def test_exported_file_loads_in_plain_smplx(tmp_path):
    out = tmp_path / "SMPL_FEMALE.npz"
    res = CliRunner().invoke(app, ["body", "export", "--gender", "female", "--out", str(out)])
    assert res.exit_code == 0, res.output
    from smplx.vertex_ids import vertex_ids

    layer = smplx.SMPL(model_path="", data_struct=smplx.utils.Struct(**dict(np.load(out))),
                       vertex_ids={k: 0 for k in vertex_ids["smplh"]}, use_hands=False, use_feet_keypoints=False)
    go, bp, tr, betas = random_pose(8, 7)
    joints = layer(global_orient=go, body_pose=bp.reshape(8, 69), transl=tr, betas=betas).joints[:, :24]
    ours = load_body_model("female").joints(go, bp, tr, betas)
    assert (ours - joints).abs().max() < 1e-5
    assert read_model_arrays(out)["v_template"].shape[1] == 3


def test_model_dir_serves_real_files_and_set_stacks_genders(tmp_path):
    for g in Gender:
        np.savez(tmp_path / f"SMPL_{g.value.upper()}.npz", **load_body_model(g).export_arrays())
    loaded = load_body_model("male", tmp_path)
    assert loaded.source.endswith("SMPL_MALE.npz")
    assert loaded.fingerprint == load_body_model("male").fingerprint
    bodies = BodyModelSet.load(tmp_path)
    betas = torch.randn(5, 10)
    gi = torch.tensor([0, 1, 2, 1, 0])
    expected = torch.stack([bodies.models[int(i)].rest_joints(b) for b, i in zip(betas, gi, strict=True)])
    torch.testing.assert_close(bodies.rest_joints(betas, gi), expected)


def test_bad_betas_shape_is_named():
    with pytest.raises(ValueError, match="betas shape"):
        load_body_model("neutral").rest_joints(torch.zeros(3, 8))


def test_fingerprint_holds_across_floating_point_noise():
    """The built-in body is generated on the user's machine, and other CPUs and BLAS kernels give arrays
    that differ by ~1e-12: the fingerprint (which model files and their .onnx graphs are checked
    against) must not change with that noise, and must change with any real edit of the geometry."""
    from smplik.body_model import BodyModel

    model = load_body_model("neutral")
    rng = np.random.default_rng(0)

    def variant(scale: float, key: str = "v_template") -> BodyModel:
        arrays = dict(model.arrays)
        arrays[key] = arrays[key] + scale * rng.standard_normal(arrays[key].shape)
        return BodyModel.from_arrays(arrays, model.gender, "variant")

    assert variant(3e-12).fingerprint == variant(3e-12, "J_regressor").fingerprint == model.fingerprint
    assert variant(3e-12, "shapedirs").fingerprint == model.fingerprint
    assert variant(1e-4).fingerprint != model.fingerprint  # a tenth of a millimetre is another body
    assert variant(1e-4, "shapedirs").fingerprint != model.fingerprint
