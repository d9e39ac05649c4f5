"""LiDAR simulator: checked against closed forms (boxes) and brute force (a full revolution)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from spotlights.data.lidar import LidarSimulator, SensorModel, VehiclePose, hdl64e, sensor_preset
from spotlights.errors import ParameterError

from helpers import CARS, need, slab_interval

BOX = np.array([4.5, 1.8, 1.5])  # length, width, height (metres)


def box_mesh(center=(0.3, -0.2, 0.1)):
    m = trimesh.creation.box(extents=BOX)
    m.apply_translation(center)
    return m


def box_distance(p, center, half):
    """Exact distance of points to the surface of an axis-aligned box (closed form)."""
    q = np.abs(p - center) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(np.max(q, axis=1), 0.0)
    return np.abs(outside + inside)


def slab_hits(origin, dirs, lo, hi):
    """Brute-force ray/box intersection (slab method), independent of Embree: (K,) t or inf."""
    t0, t1 = slab_interval(origin, dirs, lo, hi)
    return np.where((t1 >= t0) & (t1 > 0), np.maximum(t0, 0), np.inf)


def test_hdl64e_sensor_model():
    s = hdl64e()
    el = s.beam_elevations
    assert el.shape == (64,) and el[0] == pytest.approx(2.0) and el[-1] == pytest.approx(-24.9)
    assert np.allclose(np.diff(el), -26.9 / 63)
    assert s.mount_height == pytest.approx(1.73) and s.range_noise == pytest.approx(0.02)
    assert s.n_columns == round(360 / 0.17)
    assert s.n_columns * s.effective_azimuth_step == pytest.approx(360.0)
    assert SensorModel.from_dict(s.to_dict()) == s
    assert sensor_preset("vlp16").n_beams == 16
    with pytest.raises(ParameterError):
        SensorModel(dropout=1.0)
    with pytest.raises(ParameterError):
        sensor_preset("nope")


@pytest.mark.parametrize("seed", range(6))
def test_window_culling_loses_no_return(seed):
    """The beams cast inside the box's window give exactly the returns of a full revolution."""
    sensor = hdl64e(azimuth_step=0.4, range_noise=0.0)
    m = box_mesh()
    sim = LidarSimulator(m.vertices, m.faces, sensor)
    rng = np.random.default_rng(seed)
    pose = VehiclePose(
        float(rng.uniform(3.5, 25)), float(rng.uniform(-np.pi, np.pi)), float(rng.uniform(-np.pi, np.pi))
    )
    scan = sim.scan(pose, np.random.default_rng(0))
    full = sim.scan_full(pose)
    assert len(full.points) > 20
    a = sorted(zip(scan.beam.tolist(), scan.column.tolist()))
    b = sorted(zip(full.beam.tolist(), full.column.tolist()))
    assert a == b
    assert scan.n_rays < full.n_rays / 5


def test_scan_matches_closed_form_box():
    """Returns lie on the box (closed-form distance), on faces facing the sensor, at the beam
    angles of the sensor model, and their number equals a brute-force slab test of every beam."""
    sensor = hdl64e(range_noise=0.0)
    center = np.array([0.3, -0.2, 0.1])
    half = BOX / 2
    m = box_mesh(center)
    sim = LidarSimulator(m.vertices, m.faces, sensor)
    for k, pose in enumerate([VehiclePose(6.0, 0.3, 0.0), VehiclePose(12.0, -2.0, 1.1), VehiclePose(25.0, 2.5, -0.4)]):
        scan = sim.scan(pose, np.random.default_rng(k))
        p = scan.points
        assert len(p) > 30
        assert box_distance(p, center, half).max() < 1e-4
        # Face of each point (the axis where it sits on the box's boundary) faces the sensor.
        sensor_obj = np.linalg.inv(sim.object_to_sensor(pose)) @ np.array([0, 0, 0, 1.0])
        q = (p - center) / half
        axis = np.argmax(np.abs(q), axis=1)
        normal = np.zeros_like(p)
        normal[np.arange(len(p)), axis] = np.sign(q[np.arange(len(p)), axis])
        assert np.all(np.einsum("ij,ij->i", normal, sensor_obj[:3] - p) > 0)
        # Beam angles in the sensor frame.
        ps = (sim.object_to_sensor(pose) @ np.c_[p, np.ones(len(p))].T).T[:, :3]
        el = np.degrees(np.arctan2(ps[:, 2], np.hypot(ps[:, 0], ps[:, 1])))
        assert np.allclose(el, sensor.beam_elevations[scan.beam], atol=1e-3)
        az = np.degrees(np.arctan2(ps[:, 1], ps[:, 0])) % 360
        expect = (scan.column * sensor.effective_azimuth_step) % 360
        assert np.allclose(np.angle(np.exp(1j * np.radians(az - expect))), 0, atol=1e-4)
        # Count against brute force over the whole revolution (slab method in the sensor frame).
        elv = np.radians(sensor.beam_elevations)
        azv = np.arange(sensor.n_columns) * np.radians(sensor.effective_azimuth_step)
        ee, aa = np.meshgrid(elv, azv, indexing="ij")
        d = np.stack([np.cos(ee) * np.cos(aa), np.cos(ee) * np.sin(aa), np.sin(ee)], -1).reshape(-1, 3)
        r = sim.object_to_sensor(pose)[:3, :3]
        b = sim.box_center_in_sensor(pose)
        d_obj = d @ r  # rotate directions into the object frame (R^T d)
        o_obj = r.T @ (-b) + center
        t = slab_hits(o_obj, d_obj, center - half, center + half)
        assert np.isfinite(t).sum() == len(p)
        # The box stands on the ground: its bottom is at z = -mount height in the sensor frame.
        corners = (sim.object_to_sensor(pose) @ np.c_[np.array(m.vertices), np.ones(8)].T).T
        assert corners[:, 2].min() == pytest.approx(-sensor.mount_height)


def test_noise_and_dropout_statistics():
    sensor = hdl64e(range_noise=0.02, dropout=0.3)
    center = np.zeros(3)
    m = box_mesh(center)
    sim = LidarSimulator(m.vertices, m.faces, sensor)
    pose = VehiclePose(5.0, 0.0, 0.0)  # heading 0, straight ahead: the sensor sees the rear face x = -2.25
    sim0 = LidarSimulator(m.vertices, m.faces, hdl64e(range_noise=0.0))
    clean = sim0.scan(pose, np.random.default_rng(0))
    noisy = sim.scan(pose, np.random.default_rng(1))
    assert abs(len(noisy.points) / len(clean.points) - 0.7) < 0.05
    # Range error of every kept return: its distance from the sensor minus the clean one's.
    origin = (np.linalg.inv(sim.object_to_sensor(pose)) @ np.array([0, 0, 0, 1.0]))[:3]
    key_clean = {(b, c): i for i, (b, c) in enumerate(zip(clean.beam.tolist(), clean.column.tolist()))}
    idx = np.array([key_clean[(b, c)] for b, c in zip(noisy.beam.tolist(), noisy.column.tolist())])
    err = np.linalg.norm(noisy.points - origin, axis=1) - np.linalg.norm(clean.points[idx] - origin, axis=1)
    assert len(err) > 500
    assert abs(np.std(err) - 0.02) < 0.002 and abs(np.mean(err)) < 0.003
    # The noise is along the ray: the noisy point, the clean point and the sensor are collinear.
    u = (noisy.points - origin) / np.linalg.norm(noisy.points - origin, axis=1, keepdims=True)
    v = (clean.points[idx] - origin) / np.linalg.norm(clean.points[idx] - origin, axis=1, keepdims=True)
    assert np.allclose(u, v, atol=1e-9)


def test_beam_dropout_removes_whole_beams():
    m = box_mesh()
    clean_sim = LidarSimulator(m.vertices, m.faces, hdl64e(range_noise=0.0))
    sim = LidarSimulator(m.vertices, m.faces, hdl64e(range_noise=0.0, beam_dropout=0.5))
    kept, total = 0, 0
    for k in range(20):
        pose = VehiclePose(6.0 + k, 0.1 * k, 0.3 * k)
        clean = clean_sim.scan(pose, np.random.default_rng(k))
        scan = sim.scan(pose, np.random.default_rng(k))
        beams = set(scan.beam.tolist())
        assert beams <= set(clean.beam.tolist())
        # every surviving beam keeps all of its returns
        assert len(scan.points) == int(np.isin(clean.beam, list(beams)).sum())
        kept += len(beams)
        total += len(set(clean.beam.tolist()))
    assert 0.35 < kept / total < 0.65


def test_ground_occludes_and_sensor_outside():
    m = box_mesh()
    sim = LidarSimulator(m.vertices, m.faces, hdl64e())
    with pytest.raises(ParameterError):
        sim.scan(VehiclePose(1.0, 0.0, 0.0), np.random.default_rng(0))
    # A beam pointing at the ground in front of the box never returns an object point: every
    # return is above the ground, z >= bottom of the box.
    scan = sim.scan(VehiclePose(4.0, 0.0, 0.7), np.random.default_rng(0))
    assert scan.points[:, 2].min() >= sim.lo[2] - 0.1


def test_unit_frame_transform():
    """sensor_to_unit maps the scan (sensor frame) onto (p_object - box centre) / R."""
    m = box_mesh((1.0, 2.0, 3.0))
    sim = LidarSimulator(m.vertices, m.faces, hdl64e(range_noise=0.0))
    pose = VehiclePose(9.0, 1.0, 2.0)
    scan = sim.scan(pose, np.random.default_rng(0))
    ps = (sim.object_to_sensor(pose) @ np.c_[scan.points, np.ones(len(scan.points))].T).T
    unit = (sim.box_normalization(pose).matrix @ ps.T).T[:, :3]
    r = 0.5 * np.linalg.norm(BOX)
    assert np.allclose(unit, (scan.points - np.array([1.0, 2.0, 3.0])) / r, atol=1e-9)
    # The vehicle's forward axis in the sensor frame points at the heading.
    fwd = sim.object_to_sensor(pose)[:3, :3] @ np.array([1.0, 0, 0])
    assert np.allclose(fwd, [math.cos(2.0), math.sin(2.0), 0.0])


def test_car_window_equals_full_revolution():
    need(CARS)
    from spotlights.geometry.io import load_mesh

    mesh = load_mesh(CARS / "sedan" / "037-CAR02.ply")
    sim = LidarSimulator(mesh.vertices, mesh.faces, hdl64e(azimuth_step=0.5, range_noise=0.0))
    for k in range(3):
        rng = np.random.default_rng(10 + k)
        pose = VehiclePose(float(rng.uniform(4, 30)), float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
        a = sim.scan(pose, rng)
        b = sim.scan_full(pose)
        assert sorted(zip(a.beam.tolist(), a.column.tolist())) == sorted(zip(b.beam.tolist(), b.column.tolist()))
