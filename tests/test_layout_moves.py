"""What the package moves keep: the tracker's contact labels use the animation pipeline's settings, the
character options are declared once, ``preset="auto"`` is the rig mapper of shape_inversion."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest


def test_contact_config_has_the_cleaning_defaults():
    from smplik.contacts import ContactConfig, foot_contacts
    from workflows.animation.clean import CleanConfig

    clean = CleanConfig()
    for field in dataclasses.fields(ContactConfig):
        assert getattr(ContactConfig(), field.name) == getattr(clean, field.name), field.name
    rng = np.random.default_rng(0)
    p = np.cumsum(rng.normal(0, 0.01, (60, 24, 3)), axis=0)
    p[:, :, 1] -= p[:, :, 1].min()
    np.testing.assert_array_equal(foot_contacts(p, 30.0, ContactConfig()), foot_contacts(p, 30.0, clean))


def test_every_character_command_has_the_same_character_options():
    import inspect

    from shape_inversion.cli import invert_shape
    from workflows.animation.cli import animate_cmd
    from workflows.cli import from_estimate_cmd
    from workflows.editor.cli import edit_cmd
    from workflows.tracking.cli import track_cmd

    names = ["rig", "map_file", "units", "up", "rest", "bind", "positions", "max_joints", "root"]
    for command in (invert_shape, animate_cmd, from_estimate_cmd, edit_cmd, track_cmd):
        params = list(inspect.signature(command).parameters)
        start = params.index("rig")
        assert params[start:start + len(names)] == names, command.__name__
        assert "character_cli" not in params


def test_auto_preset_is_passed_explicitly_by_shape_inversion(shared_data):
    import shape_inversion.auto_preset as auto
    from smplik.data import retarget
    from smplik.data.bvh import read_bvh

    motion = read_bvh(shared_data.cmu("09_06.bvh"))
    assert retarget.resolve_preset(motion, "auto", auto.auto_preset) == auto.auto_preset(motion)
    with pytest.raises(retarget.RetargetError, match="09_06.bvh: preset 'auto' needs a rig mapper"):
        retarget.resolve_preset(motion, "auto")
