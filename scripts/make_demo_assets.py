"""Regenerate the demo's shipped partial scan (src/spotlights/assets/demo_scan.*).

A simulated HDL-64E scan of the bundled CC0 Kenney sedan (scaled to 4.3 m) standing
11 m from the sensor: the points are in the *sensor* frame (metres), as a user's LiDAR would give
them, and the box JSON is what a 3-D detector would report (centre, size, yaw).

    python scripts/make_demo_assets.py
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from spotlights.assets import DEMO_VEHICLE, asset_path
from spotlights.data.lidar import LidarSimulator, VehiclePose, hdl64e
from spotlights.geometry import load_mesh, save_points

OUT = Path(__file__).resolve().parents[1] / "src" / "spotlights" / "assets"


def main() -> None:
    name, up, forward = DEMO_VEHICLE
    mesh = load_mesh(asset_path(name), up=up, forward=forward)
    mesh.apply_scale(1.7)  # the toy-sized Kenney car (2.55 m long) to a real car's 4.3 m
    sim = LidarSimulator(mesh.vertices, mesh.faces, hdl64e())
    pose = VehiclePose(distance=11.0, azimuth=math.radians(35.0), heading=math.radians(-120.0))
    scan = sim.scan(pose, np.random.default_rng(7))
    m = sim.object_to_sensor(pose)
    pts = scan.points @ m[:3, :3].T + m[:3, 3]
    save_points(OUT / "demo_scan.pcd", pts)
    box = {
        "center": [round(float(c), 6) for c in sim.box_center_in_sensor(pose)],
        "size": [round(float(s), 6) for s in sim.size],
        "yaw": round(pose.heading, 6),
        "source": f"simulated HDL-64E scan of {name} (CC0), scripts/make_demo_assets.py",
    }
    (OUT / "demo_scan_box.json").write_text(json.dumps(box, indent=2) + "\n")
    print(f"{len(pts)} points -> {OUT / 'demo_scan.pcd'}; box -> {OUT / 'demo_scan_box.json'}")


if __name__ == "__main__":
    main()
