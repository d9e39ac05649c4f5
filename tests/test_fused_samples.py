"""Fused-window training samples (spotlights.learning.fused) on a box-shaped vehicle: inputs and targets
checked against the box's own geometry."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.geometry.boxes import Box, unit_extents
from spotlights.geometry.encode import decode
from spotlights.geometry.rig import parse_rig

EXTENTS = (4.0, 1.8, 1.5)
RIG = "box-8x8-ellipsoid-s1"


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("torch")
    from spotlights.learning.fused import simulate_pool

    path = tmp_path_factory.mktemp("mesh") / "box.ply"
    trimesh.creation.box(extents=EXTENTS).export(path)
    return simulate_pool([path], sequences=1, frames=4, rates=(2.0,), sensors=("hdl32e",), rig=RIG, seed=5)


def box_surface_residual(points: np.ndarray, half: np.ndarray) -> np.ndarray:
    """0 on the surface of the axis-aligned box of half-sizes ``half``: max_i |p_i| / half_i - 1."""
    return np.max(np.abs(points) / half, axis=1) - 1.0


@pytest.mark.parametrize("p_true", [1.0, 0.0])
def test_samples_and_targets_lie_on_the_vehicle(pool, p_true):
    from spotlights.learning.fused import draw_sample

    rng = np.random.default_rng(0)
    for _ in range(4):
        smp = draw_sample(pool, rng, max_window=3, p_true=p_true)
        assert smp["partial"].shape == (256, 3) and smp["partial"].dtype == np.float32
        assert 1 <= smp["n_frames"] <= smp["k"] <= 3 and smp["true_boxes"] == (p_true == 1.0)
        size = smp["size"]
        r = 0.5 * np.linalg.norm(size)
        e = unit_extents(size)
        pts, hit = decode(smp["depths"], parse_rig(RIG), extents=e)
        assert hit.mean() > 0.5
        target = pts[hit] * r  # metres, the sample's box frame
        if p_true == 1.0:
            np.testing.assert_allclose(size, EXTENTS, atol=1e-9)
            # true boxes: the target's hits and the input both lie on the box-shaped car
            assert np.abs(box_surface_residual(target, np.array(EXTENTS) / 2)).max() < 1e-3
            inp = smp["partial"] * r  # range noise 2 cm along each ray: within 10 cm of the faces, most far closer
            assert np.all(np.abs(inp) <= np.array(EXTENTS) / 2 + 0.1)
            assert np.median(np.abs(box_surface_residual(inp, np.array(EXTENTS) / 2))) < 0.02
        else:
            # noisy boxes: the car is off the box by the noise; the target follows the car, not the box
            assert np.abs(box_surface_residual(target, np.array(EXTENTS) / 2)).max() > 1e-3


def test_target_in_a_noisy_box_is_the_car_moved_into_that_box(pool):
    """Frame 0's noisy-box target, decoded and moved through noisy -> sensor -> true box frame, lies on the car."""
    rows = pool.frames[0]
    f = rows[0]
    nb, tb = f["noisy_box"], f["true_box"]
    pts, hit = decode(f["depths_noisy"].astype(np.float32), parse_rig(RIG), extents=unit_extents(nb.size))
    in_true = tb.to_object(nb.from_object(pts[hit] * nb.radius))
    assert np.abs(box_surface_residual(in_true, np.array(EXTENTS) / 2)).max() < 1e-3
    assert isinstance(nb, Box) and not np.allclose(nb.center, tb.center)
