"""Hostile values through the library: meshes, rigs, boxes, readers' options and sequence noise."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import ParameterError


def test_sequence_size_noise_is_bounded_and_never_flattens_a_box():
    from spotlights.data.synthetic.sequences import MAX_SIZE_SIGMA, MIN_SIZE_FACTOR, BoxNoise
    from spotlights.geometry.boxes import Box

    with pytest.raises(ParameterError, match="`size_sigma`"):
        BoxNoise(size_rel=5.0)
    noise = BoxNoise(size_rel=MAX_SIZE_SIGMA)
    box = Box.from_yaw(np.zeros(3), np.array([4.0, 1.8, 1.5]), 0.0)
    rng = np.random.default_rng(0)
    sizes = np.array([noise.apply(box, rng).size for _ in range(2000)])
    assert (sizes >= MIN_SIZE_FACTOR * box.size - 1e-12).all() and (sizes > 0).all()


def test_box_with_infinite_yaw_is_a_clear_error():
    from spotlights.geometry.boxes import Box

    for yaw in (float("inf"), float("nan")):
        with pytest.raises(ParameterError, match="yaw must be a finite number"):
            Box.from_yaw(np.zeros(3), np.ones(3), yaw)
        with pytest.raises(ParameterError, match="yaw must be a finite number"):
            Box(np.zeros(3), np.ones(3), yaw=yaw)
        with pytest.raises(ParameterError, match="yaw must be a finite number"):
            Box(np.zeros(3), np.ones(3), yaw)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("mesh", ["car.ply", None, np.zeros((10, 3)), 3.0])
def test_encode_mesh_refuses_what_is_not_a_mesh(mesh):
    """A path, None or a point array gave an AttributeError deep in the ray caster."""
    import spotlights
    from spotlights.errors import ParameterError

    with pytest.raises(ParameterError, match="mesh must be a triangle mesh"):
        spotlights.encode_mesh(mesh, spotlights.make_rig(4, 8))


@pytest.mark.timeout(60)
def test_encode_mesh_refuses_bad_arrays_and_reads_a_rig_name():
    import trimesh

    import spotlights
    from spotlights.errors import ParameterError

    box = trimesh.creation.box(extents=(4.0, 1.8, 1.5))
    by_name = spotlights.encode_mesh(box, "cap-4x8-60")
    assert np.array_equal(by_name, spotlights.encode_mesh(box, spotlights.make_rig(4, 8, angle=60.0)))
    assert (by_name > 0).any()

    class Arrays:
        vertices = box.vertices
        faces = box.faces + len(box.vertices)  # indices past the last vertex

    with pytest.raises(ParameterError, match="faces must be \\(F, 3\\) indices of its 8 vertices"):
        spotlights.encode_mesh(Arrays(), "cap-4x8-60")
    with pytest.raises(ParameterError, match="rig must be a Rig"):
        spotlights.encode_mesh(box, 42)
    with pytest.raises(ParameterError, match="rig 'nonsense' not understood"):
        spotlights.encode_mesh(box, "nonsense")


@pytest.mark.timeout(60)
def test_read_frames_refuses_no_source_and_unknown_options(tmp_path):
    """``read_frames([], "kitti")`` raised IndexError; an option of another reader a TypeError."""
    import spotlights
    from spotlights.errors import ParameterError

    with pytest.raises(ParameterError, match="no source given"):
        spotlights.read_frames([], "kitti")
    with pytest.raises(ParameterError, match="foo are not options of the kitti reader \\(it takes: velodyne\\)"):
        spotlights.read_frames(tmp_path, "kitti", foo=1)
    with pytest.raises(ParameterError, match="not options of the av2 reader \\(it takes: none\\)"):
        spotlights.read_frames(tmp_path, "av2", sequences=["a"])
    with pytest.raises(ParameterError, match="unknown format 'kity'"):
        spotlights.read_frames(tmp_path, "kity")


@pytest.mark.timeout(120)
@pytest.mark.parametrize("scale", [1e-30, 1000.0])
def test_sequences_refuse_a_mesh_not_in_metres_before_writing(tmp_path, scale):
    """A tetrahedron of 1e-30 m drove past the sensor as scans of no points, exit 0."""
    import trimesh

    from helpers import assert_user_error, run_cli

    good = trimesh.creation.box(extents=(4.0, 1.8, 1.5))
    tiny = trimesh.creation.box(extents=(4.0, 1.8, 1.5))
    tiny.apply_scale(scale)
    folder = tmp_path / "meshes"
    folder.mkdir()
    good.export(folder / "a.ply")
    tiny.export(folder / "b.ply")
    for out in ("seqs", "seqs.h5"):
        proc = run_cli(
            "dataset", "sequences", "--meshes", folder, "--sequences", 2, "--frames", 2, "-q", "--out", tmp_path / out
        )
        assert_user_error(proc, "b.ply", "m long: a vehicle to drive past is 0.5-50 m")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meshes"]
