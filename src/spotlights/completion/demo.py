"""The end-to-end demonstration on bundled CC0 data (``spotlights demo``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from .. import logs, viz
from ..assets import DEMO_VEHICLE, asset_path
from ..geometry import MeshProbe, hit_ratio, load_mesh, load_points, make_rig, save_encoding, save_points
from ..geometry.box_json import load_box
from ..geometry.encode import load_encoding
from ..learning.inference import complete_scan, load_completer


def run_demo(out: Path, log: Callable[[str], None] = logs.info) -> None:
    """The end-to-end demonstration (``spotlights demo``) into the folder ``out``: the bundled
    CC0 vehicle encoded with two rigs (``.npz``, ``.ply`` points in metres, ``.png``), and the
    shipped partial scan (sensor frame) completed by the pretrained SA-Net
    (``scan_completed.ply``/``.png``); ``log`` receives the four progress lines."""
    name, up, forward = DEMO_VEHICLE
    mesh = load_mesh(asset_path(name), up=up, forward=forward)
    log(f"[1/4] loaded the bundled CC0 vehicle {name}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces")
    viz.render_mesh(out / "vehicle_mesh.png", mesh, title=f"{name} (CC0), object frame: x forward, z up")

    probe = MeshProbe(mesh)
    written = []
    for rig in (make_rig(32, 64, 60), make_rig(64, 128, 60)):
        depths = probe.encode(rig)
        enc_path = out / f"vehicle_{rig.name}.npz"
        save_encoding(enc_path, depths, rig, probe.normalization)
        enc = load_encoding(enc_path)
        save_points(out / f"vehicle_{rig.name}.ply", enc.points(frame="original"))
        viz.render_encoding(out / f"vehicle_{rig.name}.png", enc)
        written.append(f"{rig.name}: hit ratio {hit_ratio(depths):.3f}")
    log(f"[2/4] encoded with the paper's rig and a denser one: {'; '.join(written)}")

    # Completion of a shipped partial scan (sensor frame + detector box) with the pretrained SA-Net.

    scan = load_points(asset_path("demo_scan.pcd"))
    box = load_box(asset_path("demo_scan_box.json"))
    completer = load_completer()  # the pretrained SA-Net shipped in the package
    res = complete_scan(scan, box, completer)
    save_points(out / "scan_completed.ply", res["completed"])
    layers = [
        viz.Layer(scan, "tab:purple", f"partial scan ({len(scan)} points)", 3.0, 0.8),
        viz.Layer(res["completed"], "tab:green", f"SA-Net completion ({len(res['completed'])} points)", 3.0, 0.6),
    ]
    viz.render_layers(
        out / "scan_completed.png",
        layers,
        title="simulated HDL-64E scan of the CC0 sedan, completed by the pretrained SA-Net (sensor frame)",
    )
    log(
        f"[3/4] completed the shipped partial scan ({len(scan)} points, sensor frame) with the pretrained "
        f"{completer.model_name}: {len(res['completed'])} points -> scan_completed.ply, scan_completed.png"
    )
    log(f"[4/4] pictures and files written to {out}/")
