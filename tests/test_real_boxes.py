"""Box transforms of the real-data readers against hand-computed corners and independent formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spotlights.data.real.base import Box, quaternion_to_matrix
from spotlights.data.real.kitti import box_from_label, read_calib, velo_from_rect

from helpers import LIDAR, need


def same_corner_sets(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    """True when every corner of a has a corner of b within atol and vice versa (order-free)."""
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    return bool(np.all(d.min(axis=1) <= atol) and np.all(d.min(axis=0) <= atol))


# The usual KITTI axis swap: camera x = -velo y, camera y = -velo z, camera z = velo x.
PERM = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _calib(t=(0.0, 0.0, 0.0)):
    tr = np.zeros((3, 4))
    tr[:, :3] = PERM
    tr[:, 3] = t
    return {"R0_rect": np.eye(3), "Tr_velo_to_cam": tr}


def _label(h, w, length, x, y, z, ry):
    return np.array([0, 0, 0, 0, 0, 0, 100, 100, h, w, length, x, y, z, ry], dtype=np.float64)[1:]


def test_kitti_box_hand_corners_ry0():
    # Car 1.5 high, 1.6 wide, 4 long, bottom centre (2, 1.7, 10) in the camera, ry = 0.
    box = box_from_label("Car", _label(1.5, 1.6, 4.0, 2.0, 1.7, 10.0, 0.0), velo_from_rect(_calib()))
    # Hand: centre (cam) = (2, 0.95, 10) -> velo (10, -2, -0.95). ry = 0 faces camera +x = velo -y,
    # so the 4 m length runs along velo y, the 1.6 m width along velo x; the bottom is at velo z = -1.7.
    hand = np.array([[x, y, z] for x in (9.2, 10.8) for y in (-4.0, 0.0) for z in (-1.7, -0.2)])
    assert same_corner_sets(box.corners(), hand, 1e-9)
    np.testing.assert_allclose(box.center, [10.0, -2.0, -0.95], atol=1e-12)
    np.testing.assert_allclose(box.size, [4.0, 1.6, 1.5])
    np.testing.assert_allclose(box.rotation[:, 0], [0, -1, 0], atol=1e-12)  # forward
    np.testing.assert_allclose(box.rotation[:, 2], [0, 0, 1], atol=1e-12)  # up
    assert box.yaw == pytest.approx(-math.pi / 2)
    assert box.cls == "car"


def test_kitti_box_hand_corners_with_translation_and_heading():
    t = np.array([0.1, -0.2, 0.3])  # p_cam = PERM @ p_velo + t
    ry = 0.3
    box = box_from_label("Van", _label(2.0, 1.8, 5.0, -1.0, 1.5, 20.0, ry), velo_from_rect(_calib(t)))
    # Hand: velo = PERM^T (cam - t). Camera corners of a box with heading ry (devkit convention:
    # x along length rotated by R_y(ry), y from 0 (bottom) to -h, z along width).
    c, s = math.cos(ry), math.sin(ry)
    cam = []
    for dx in (2.5, -2.5):
        for dz in (0.9, -0.9):
            for dy in (0.0, -2.0):
                cam.append([-1.0 + c * dx + s * dz, 1.5 + dy, 20.0 - s * dx + c * dz])
    hand = (np.array(cam) - t) @ PERM  # row-vector form of PERM^T @ (cam - t)
    assert same_corner_sets(box.corners(), hand, 1e-9)
    assert box.yaw == pytest.approx(-ry - math.pi / 2)  # the standard camera->LiDAR heading
    assert box.cls == "caravan"


def test_kitti_real_calib_matches_devkit_corners():
    """Our boxes vs the KITTI devkit recipe (corners in the rectified camera, then inverse R0 and inverse rigid Tr)."""
    root = need(LIDAR / "kitti-object" / "training")
    calib = read_calib(root / "calib" / "000001.txt")
    t = velo_from_rect(calib)
    for line in (root / "label_2" / "000001.txt").read_text().splitlines()[:3]:
        f = line.split()
        h, w, length, x, y, z, ry = (float(v) for v in f[8:15])
        ry_m = np.array([[math.cos(ry), 0, math.sin(ry)], [0, 1, 0], [-math.sin(ry), 0, math.cos(ry)]])
        xc = [length / 2, length / 2, -length / 2, -length / 2, length / 2, length / 2, -length / 2, -length / 2]
        yc = [0, 0, 0, 0, -h, -h, -h, -h]
        zc = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
        rect = (ry_m @ np.array([xc, yc, zc])).T + [x, y, z]
        ref = (np.linalg.inv(calib["R0_rect"]) @ rect.T).T  # rect -> unrectified camera
        r, tt = calib["Tr_velo_to_cam"][:, :3], calib["Tr_velo_to_cam"][:, 3]
        velo = (ref - tt) @ np.linalg.inv(r).T  # inverse of the rigid velo -> cam
        box = box_from_label(f[0], np.array([float(v) for v in f[1:15]]), t)
        # R0_rect and Tr are rotations only to ~1e-5: our box uses the nearest exact rotation.
        assert same_corner_sets(box.corners(), velo, 5e-3)


def test_quaternion_matches_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    mine = quaternion_to_matrix(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is scalar-last
    np.testing.assert_allclose(mine, ref, atol=1e-12)


def test_av2_style_box_hand_corners():
    # Yaw 90 degrees: quaternion (cos 45, 0, 0, sin 45). Box 4 x 2 x 1.5 at (1, 2, 3).
    rot = quaternion_to_matrix(math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))
    box = Box(np.array([1.0, 2.0, 3.0]), np.array([4.0, 2.0, 1.5]), rot, "REGULAR_VEHICLE", "car")
    hand = np.array([[x, y, z] for x in (0.0, 2.0) for y in (0.0, 4.0) for z in (2.25, 3.75)])
    assert same_corner_sets(box.corners(), hand, 1e-12)
    assert box.yaw == pytest.approx(math.pi / 2)
