"""BVH reader: hierarchy, channel orders, End Sites, 6-channel joints, FK, errors, writer round trip."""

import numpy as np
import pytest

from smplik.data.bvh import BVHError, format_bvh, parse_bvh, read_bvh, write_bvh


def rx(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def ry(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def rz(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 1.0 2.0 3.0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Chest
  {
    OFFSET 0.0 10.0 0.0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0.0 5.0 0.0
    }
  }
  JOINT Leg
  {
    OFFSET 2.0 -1.0 0.0
    CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
    JOINT Foot
    {
      OFFSET 0.0 -8.0 0.0
      CHANNELS 3 Yrotation Xrotation Zrotation
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
10 20 30 30 -20 10 15 25 35 0.5 0.25 0 40 -10 5 20 30 -40
"""


CHEST_CHANNELS = "CHANNELS 3 Xrotation Yrotation Zrotation"


def write(tmp_path, text, name="clip.bvh"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_hierarchy_offsets_channels_end_sites(tmp_path):
    m = read_bvh(write(tmp_path, SMALL))
    assert m.joint_names == ("Hips", "Chest", "Leg", "Foot")
    assert m.parents == (-1, 0, 0, 2)
    np.testing.assert_allclose(m.offsets, [[1, 2, 3], [0, 10, 0], [2, -1, 0], [0, -8, 0]])
    assert m.channels[1] == ("Xrotation", "Yrotation", "Zrotation")
    assert len(m.channels[2]) == 6
    assert m.end_site_parents == (1,)
    np.testing.assert_allclose(m.end_site_offsets, [[0, 5, 0]])
    assert m.num_frames == 2 and m.values.shape == (2, 18)
    assert m.frame_time == pytest.approx(1 / 30, rel=1e-5)
    np.testing.assert_allclose(m.local_rotations[0], np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-12)


def test_rotation_orders_positions_and_fk(tmp_path):
    m = read_bvh(write(tmp_path, SMALL))
    R_hips = rz(30) @ ry(-20) @ rx(10)  # ZYX channels -> Rz Ry Rx
    R_chest = rx(15) @ ry(25) @ rz(35)  # XYZ channels -> Rx Ry Rz
    R_leg = rz(40) @ ry(-10) @ rx(5)
    R_foot = ry(20) @ rx(30) @ rz(-40)  # YXZ
    for j, R in enumerate([R_hips, R_chest, R_leg, R_foot]):
        np.testing.assert_allclose(m.local_rotations[1, j], R, atol=1e-12)
    # Root: position channels replace its OFFSET; 6-channel Leg: frame 0's position channels are zero
    # beside a non-zero OFFSET (MakeHuman's delta layout), so they are ADDED to its OFFSET.
    assert m.position_mode == "add"
    p_hips = np.array([10, 20, 30])
    np.testing.assert_allclose(m.root_positions[1], p_hips)
    np.testing.assert_allclose(m.local_translations[1, 2], [2.5, -0.75, 0.0])
    p_chest = p_hips + R_hips @ [0, 10, 0]
    p_leg = p_hips + R_hips @ [2.5, -0.75, 0]
    p_foot = p_leg + R_hips @ R_leg @ [0, -8, 0]
    np.testing.assert_allclose(m.positions[1], [p_hips, p_chest, p_leg, p_foot], atol=1e-12)
    np.testing.assert_allclose(m.global_rotations[1, 3], R_hips @ R_leg @ R_foot, atol=1e-12)
    np.testing.assert_allclose(m.end_site_positions()[1, 0], p_chest + R_hips @ R_chest @ [0, 5, 0], atol=1e-12)
    R0, p0 = m.rest_pose()
    np.testing.assert_allclose(p0, [[1, 2, 3], [1, 12, 3], [3, 1, 3], [3, -7, 3]])


def test_writer_round_trip(tmp_path):
    m = read_bvh(write(tmp_path, SMALL))
    out = write_bvh(tmp_path / "out.bvh", m)
    m2 = read_bvh(out)
    assert m2.joint_names == m.joint_names and m2.channels == m.channels and m2.parents == m.parents
    np.testing.assert_allclose(m2.positions, m.positions, atol=1e-5)
    np.testing.assert_allclose(m2.end_site_offsets, m.end_site_offsets)


def test_format_bvh_rejects_bad_shapes():
    with pytest.raises(ValueError, match="values shape"):
        format_bvh(["a"], [-1], np.zeros((1, 3)), [("Xrotation",)], np.zeros((2, 2)), 0.01)


def error_of(tmp_path, text):
    path = write(tmp_path, text, "bad.bvh")
    with pytest.raises(BVHError) as info:
        read_bvh(path)
    msg = str(info.value)
    assert str(path) in msg
    assert isinstance(info.value, ValueError)
    return msg


def test_error_truncated_file(tmp_path):
    text = SMALL.rsplit("\n", 2)[0] + "\n"  # drop the last frame line
    msg = error_of(tmp_path, text)
    assert "truncated" in msg and "Frames: 2" in msg and "only 1 frame lines" in msg


def test_error_too_few_values_names_line_and_frame(tmp_path):
    text = SMALL.replace("0.5 0.25 0 40 -10 5 20 30 -40", "0.5 0.25 0 40 -10 5 20 30")
    msg = error_of(tmp_path, text)
    assert "line 30" in msg and "frame 1 has 17 values" in msg and "18 channels" in msg


def test_error_non_numeric_value(tmp_path):
    msg = error_of(tmp_path, SMALL.replace("0.5 0.25", "0.5 abc"))
    assert "line 30" in msg and "'abc' is not a number" in msg


def test_error_channel_count_mismatch(tmp_path):
    msg = error_of(tmp_path, SMALL.replace(CHEST_CHANNELS, "CHANNELS 3 Xrotation Yrotation"))
    assert "line 9" in msg and "'Chest'" in msg and "declares 3 channels but lists 2" in msg


def test_error_unknown_channel_name(tmp_path):
    msg = error_of(tmp_path, SMALL.replace(CHEST_CHANNELS, "CHANNELS 3 Xrotation Wrotation Zrotation"))
    assert "unknown channel name 'Wrotation'" in msg


def test_error_unsupported_rotation_order(tmp_path):
    msg = error_of(tmp_path, SMALL.replace(CHEST_CHANNELS, "CHANNELS 3 Xrotation Yrotation Xrotation"))
    assert "unsupported rotation order" in msg and "'Chest'" in msg


def test_error_missing_hierarchy(tmp_path):
    msg = error_of(tmp_path, SMALL.replace("HIERARCHY\n", ""))
    assert "missing HIERARCHY" in msg


def test_error_missing_motion(tmp_path):
    msg = error_of(tmp_path, SMALL.split("MOTION")[0])
    assert "MOTION" in msg


def test_error_unclosed_hierarchy(tmp_path):
    msg = error_of(tmp_path, SMALL.split("MOTION")[0].rsplit("}", 1)[0])
    assert "unexpected end of hierarchy" in msg


def test_error_bad_offset(tmp_path):
    msg = error_of(tmp_path, SMALL.replace("OFFSET 0.0 10.0 0.0", "OFFSET 0.0 x 0.0"))
    assert "line 8" in msg and "OFFSET of joint 'Chest'" in msg


def test_error_missing_file(tmp_path):
    with pytest.raises(BVHError, match="cannot read BVH file"):
        read_bvh(tmp_path / "nope.bvh")


def test_parse_string_names_source():
    with pytest.raises(BVHError, match="^<string>: missing HIERARCHY"):
        parse_bvh("MOTION\n")
