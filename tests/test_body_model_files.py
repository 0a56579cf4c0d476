"""Real-file path of the body model loader: safe pickles, npz validation, model-dir lookup."""

import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse
from helpers import tiny_smpl_arrays

from smplik.body_model import ModelFileError, find_model_file, read_model_arrays
from smplik.conventions import Gender


@pytest.fixture
def fake_chumpy(monkeypatch):
    """A stand-in `chumpy.ch.Ch` class, importable only while the pickle is written."""
    chumpy = types.ModuleType("chumpy")
    ch = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

        def __getstate__(self):
            return {"x": self.x, "_cache": {}}

    Ch.__module__ = "chumpy.ch"
    Ch.__qualname__ = "Ch"
    ch.Ch = Ch
    chumpy.ch = ch
    monkeypatch.setitem(sys.modules, "chumpy", chumpy)
    monkeypatch.setitem(sys.modules, "chumpy.ch", ch)
    return Ch


def test_pkl_with_chumpy_objects_loads_without_chumpy(tmp_path, fake_chumpy, monkeypatch):
    a = tiny_smpl_arrays()
    data = dict(a)
    data["shapedirs"] = fake_chumpy(a["shapedirs"])
    data["v_template"] = fake_chumpy(a["v_template"])
    data["J_regressor"] = scipy.sparse.csc_matrix(a["J_regressor"])
    data["bs_style"] = "lbs"
    path = tmp_path / "SMPL_FEMALE.pkl"
    path.write_bytes(pickle.dumps(data, protocol=2))
    monkeypatch.delitem(sys.modules, "chumpy")
    monkeypatch.delitem(sys.modules, "chumpy.ch")
    out = read_model_arrays(path)
    for key in ("v_template", "shapedirs", "J_regressor", "weights", "f"):
        np.testing.assert_allclose(out[key], a[key])
    assert find_model_file(Gender.FEMALE, tmp_path) == path


class Evil:
    def __reduce__(self):
        import os

        return (os.system, ("echo pwned",))


def test_pkl_naming_another_global_is_refused(tmp_path):
    a = tiny_smpl_arrays()
    a["v_template"] = Evil()
    path = tmp_path / "SMPL_NEUTRAL.pkl"
    path.write_bytes(pickle.dumps(a))
    with pytest.raises(ModelFileError, match=r"Refusing to load global '(posix|os|nt)\.system'"):
        read_model_arrays(path)


def test_npz_missing_key_is_named(tmp_path):
    a = tiny_smpl_arrays()
    del a["J_regressor"]
    path = tmp_path / "SMPL_MALE.npz"
    np.savez(path, **a)
    with pytest.raises(ModelFileError, match="missing key 'J_regressor'"):
        read_model_arrays(path)


def test_npz_misshaped_key_is_named(tmp_path):
    a = tiny_smpl_arrays()
    a["weights"] = a["weights"][:, :20]
    path = tmp_path / "SMPL_MALE.npz"
    np.savez(path, **a)
    with pytest.raises(ModelFileError, match="key 'weights' has shape"):
        read_model_arrays(path)


def test_missing_gender_file_is_not_silently_replaced(tmp_path):
    np.savez(tmp_path / "SMPL_NEUTRAL.npz", **tiny_smpl_arrays())
    with pytest.raises(ModelFileError, match="No SMPL female model"):
        find_model_file(Gender.FEMALE, tmp_path)
