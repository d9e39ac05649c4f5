"""The README's main job (`spotlights demo`) and the shipped pretrained SA-Net.

The shipped partial scan was simulated from the bundled CC0 sedan (scaled by 1.7,
scripts/make_demo_assets.py), so the mesh is independent truth for its completion.
"""

import json

import numpy as np
import pytest

from helpers import run_cli

torch = pytest.importorskip("torch", reason="the learning extra (torch) is not installed")

from spotlights.assets import DEMO_VEHICLE, asset_path  # noqa: E402
from spotlights.geometry import load_mesh, load_points, sample_surface  # noqa: E402
from spotlights.geometry.frames import normalization_from_box  # noqa: E402


def _mean_nn(a, b):
    from scipy.spatial import cKDTree

    return float(cKDTree(b).query(a)[0].mean())


@pytest.mark.slow
def test_demo_writes_pictures_and_completion(tmp_path):
    r = run_cli("demo", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    for name in (
        "vehicle_mesh.png",
        "vehicle_cap-32x64-60.png",
        "vehicle_cap-32x64-60.npz",
        "scan_completed.ply",
        "scan_completed.png",
    ):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "[4/4]" in r.stdout


def test_pretrained_sanet_completes_the_unseen_side():
    from spotlights.geometry.box_json import load_box
    from spotlights.learning.inference import complete_scan, load_completer

    scan = load_points(asset_path("demo_scan.pcd"))
    box = load_box(asset_path("demo_scan_box.json"))
    res = complete_scan(scan, box, load_completer())
    # Ground truth: the mesh the scan came from, placed by the box (object frame -> sensor frame).
    name, up, forward = DEMO_VEHICLE
    mesh = load_mesh(asset_path(name), up=up, forward=forward)
    mesh.apply_scale(1.7)
    mesh.apply_translation(-(mesh.bounds[0] + mesh.bounds[1]) / 2)
    norm = normalization_from_box(box.center, box.size, box.yaw)
    surface_unit = sample_surface(mesh, 16384, seed=0) / norm.radius  # object frame -> unit frame
    done_unit = norm.to_unit(res["completed"])
    scan_unit = norm.to_unit(scan)
    assert np.allclose(json.loads(asset_path("demo_scan_box.json").read_text())["size"], box.size)
    # The scan sees one side only; the completion must cover the car much better ...
    completeness_scan = _mean_nn(surface_unit, scan_unit)
    completeness_done = _mean_nn(surface_unit, done_unit)
    assert completeness_done < 0.7 * completeness_scan, (completeness_done, completeness_scan)
    # ... while its points stay near the surface (accuracy, unit frame).
    assert _mean_nn(done_unit, surface_unit) < 0.06
    assert len(res["completed"]) > 300
