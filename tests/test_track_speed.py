"""The speed-ups of track completion give the same answers: one KD-tree crop for every box of a scan, and the
box rig's rays kept per box size."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.geometry.boxes import Box, crop_boxes
from spotlights.geometry.rig import parse_rig
from spotlights.learning.rays import directions_for_extents

from builders import brute_force_crop


def test_one_tree_crop_equals_each_box_by_hand():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-8, 8, size=(3000, 3))
    boxes = [
        Box.from_yaw(rng.uniform(-6, 6, 3), rng.uniform(0.5, 4.5, 3), float(rng.uniform(-np.pi, np.pi)))
        for _ in range(12)
    ]
    got = crop_boxes(pts, boxes, 0.15, 0.10)
    for b, g in zip(boxes, got):
        want = brute_force_crop(pts, b, 0.15, 0.10)
        np.testing.assert_array_equal(g, want)
    assert sum(len(g) for g in got) > 0
    assert crop_boxes(np.zeros((0, 3)), boxes[:2])[0].shape == (0,)


def test_kept_rays_equal_fresh_rays_in_any_batch_order():
    rig = parse_rig("box-8x8-ellipsoid-s1")
    e = np.array([[0.8, 0.5, 0.33], [0.7, 0.6, 0.39], [0.9, 0.4, 0.17]])
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    first = directions_for_extents(rig, e)
    again = directions_for_extents(rig, e[::-1])[::-1]  # served from the kept rays
    for k in range(3):
        fresh = rig.for_box(e[k]).directions.astype(np.float32)
        np.testing.assert_array_equal(first[k], fresh)
        np.testing.assert_array_equal(again[k], fresh)
    np.testing.assert_allclose(np.linalg.norm(first, axis=-1), 1.0, atol=1e-6)


def test_few_query_tree_gives_brute_force_distances():
    from spotlights.geometry.neighbors import NearestNeighbors
    from spotlights.metrics.consistency import fidelity

    rng = np.random.default_rng(1)
    c = rng.normal(size=(3000, 3))
    p = rng.normal(size=(40, 3))
    brute = np.sqrt(((p[:, None, :] - c[None]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(NearestNeighbors(c, few_queries=True).distances(p), brute, rtol=0, atol=1e-12)
    assert fidelity(p, c) == pytest.approx(brute.mean(), abs=1e-12)
    c32, p32 = c.astype(np.float32), p.astype(np.float32)  # float32 points: distances still in float64
    brute32 = np.sqrt(((p32[:, None, :].astype(np.float64) - c32[None].astype(np.float64)) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(NearestNeighbors(c32, few_queries=True).distances(p32), brute32, rtol=0, atol=1e-12)


def _clip_by_hand(m, depths, keep, dirs, half):
    """clip_to_boxes's depths and kept rays from geometry.box_clamp.ray_box_interval (numpy), ray by ray."""
    from spotlights.geometry.box_clamp import ray_box_interval

    o = m.origins.double().numpy()
    d = depths.double().numpy().copy()
    k = keep.numpy().copy()
    for b in range(len(d)):
        t_in, t_out = ray_box_interval(o, dirs[b].double().numpy(), half[b].double().numpy())
        meets = (t_in <= t_out) & (t_out > 0)
        t = np.minimum(np.maximum(2.0 * np.maximum(d[b], 0.0), np.maximum(t_in, 0.0)), t_out)
        d[b] = np.where(k[b] & meets, t / 2.0, d[b])
        k[b] &= meets
    return d, k


def test_box_clip_with_kept_intervals_equals_the_slabs_by_hand():
    """A tracked box comes back frame after frame: its rays' intervals are kept (by the bytes of its box and rays).
    Clipped depths equal numpy's slab method ray by ray, on the first call, from the kept intervals, for a box
    whose rays changed in place, and with no interval kept at all."""
    torch = pytest.importorskip("torch")
    from spotlights.geometry.rig import make_rig_spec
    from spotlights.learning.models.sanet_hit import HitSANet

    torch.manual_seed(0)
    m = HitSANet(make_rig_spec(8, 8, kind="box"), code_size=16, encoder_widths=(8, 16, 16), hidden=(16,)).eval()
    rng = np.random.default_rng(5)
    sizes = np.array([[4.5, 1.9, 1.6], [12.0, 2.9, 3.6], [4.5, 1.9, 1.6]])
    e = sizes / np.linalg.norm(sizes, axis=1, keepdims=True)
    dirs = torch.from_numpy(np.ascontiguousarray(directions_for_extents(m.rig, e)))
    half = torch.from_numpy(0.5 * e + 0.02).float()
    depths = torch.from_numpy(rng.uniform(-0.1, 1.0, (3, m.rig.n_rays))).float()
    keep = torch.from_numpy(rng.uniform(size=(3, m.rig.n_rays)) < 0.9)
    want_d, want_k = _clip_by_hand(m, depths, keep, dirs, half)
    for _ in range(2):  # computed, then kept
        d, k, _ = m.clip_to_boxes(depths, keep, dirs, half)
        np.testing.assert_allclose(d.double().numpy(), want_d, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(k.numpy(), want_k)
    assert 0 < int(k.sum()) < int(keep.sum())  # some kept rays miss their box, some are clipped
    dirs[2] = dirs[1]  # the third box's rays change in place (its box does not): its interval is computed again
    want_d, want_k = _clip_by_hand(m, depths, keep, dirs, half)
    d, k, _ = m.clip_to_boxes(depths, keep, dirs, half)
    np.testing.assert_allclose(d.double().numpy(), want_d, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(k.numpy(), want_k)
    m.INTERVAL_CACHE_SIZE = 0  # nothing kept: the same bytes
    d0, k0, s0 = m.clip_to_boxes(depths, keep, dirs, half)
    assert torch.equal(d0, d) and torch.equal(k0, k)


def _without_timings(x, out: str):
    """A run's JSON without its clock readings (``timings``, ``wall_seconds``, ``completion_seconds``) and with
    its output folder named ``OUT``."""
    if isinstance(x, dict):
        return {
            k: _without_timings(v, out)
            for k, v in x.items()
            if k not in ("timings", "wall_seconds", "completion_seconds")
        }
    if isinstance(x, list):
        return [_without_timings(v, out) for v in x]
    return x.replace(out, "OUT") if isinstance(x, str) else x


def test_frames_read_once_give_the_bytes_of_frames_read_twice(tmp_path, monkeypatch):
    """``real complete --fuse`` reads each frame once (the track plan keeps what it read); with nothing kept (every
    frame read again) and no ray-box interval kept, the same files, the same PLY bytes, the same JSON but clocks."""
    pytest.importorskip("torch")
    import spotlights.completion.fusion as plans
    from spotlights.cli import main
    from spotlights.data.real.nuscenes import NuScenesReader
    from spotlights.learning.models.sanet import SANet

    from helpers import LIDAR, need
    from learning_fixtures import make_checkpoint

    src = need(LIDAR / "nuscenes")
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    loads = []
    load = NuScenesReader.load
    monkeypatch.setattr(NuScenesReader, "load", lambda self, key: loads.append(key) or load(self, key))

    def run(name):
        out = tmp_path / name
        argv = ["real", "complete", str(src), "--format", "nuscenes", "--out", str(out), "-c", str(ck), "--no-clip"]
        assert main([*argv, "--frames", "0:3", "--fuse", "past:3", "--refine-boxes", "--no-pictures", "-q"]) == 0
        return out

    once = run("once")
    assert len(loads) == 3 and len(set(loads)) == 3
    monkeypatch.setattr(plans, "KEEP_POINTS", 0)
    monkeypatch.setattr(SANet, "INTERVAL_CACHE_SIZE", 0)
    twice = run("twice")
    assert len(loads) == 3 + 6  # the plan's reading, then the frame loop's
    files = sorted(p.relative_to(once) for p in once.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(twice) for p in twice.rglob("*") if p.is_file())
    assert sum(p.suffix == ".ply" for p in files) > 3  # the frames' scenes and the tracks
    for rel in files:
        a, b = (once / rel).read_bytes(), (twice / rel).read_bytes()
        if rel.suffix == ".json":
            assert _without_timings(json.loads(a), str(once)) == _without_timings(json.loads(b), str(twice)), rel
        else:
            assert a == b, rel
