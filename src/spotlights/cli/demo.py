"""``spotlights demo``: the end-to-end demonstration on bundled CC0 data."""

from __future__ import annotations

from .. import viz
from ..assets import DEMO_VEHICLE, asset_path
from ..geometry import MeshProbe, hit_ratio, load_mesh, load_points, make_rig, save_encoding, save_points
from ..geometry.encode import load_encoding
from ..learning.inference import complete_scan, load_box, load_completer
from ..utils import output_folder
from ._util import add_command


def register(sub) -> None:
    p = add_command(
        sub,
        "demo",
        "run the end-to-end demo on a bundled CC0 vehicle and write pictures",
        "spotlights demo --out out/demo",
        _demo,
    )
    p.add_argument("--out", "-o", default="out/demo", metavar="DIR", help="output folder (default out/demo)")


def _demo(args) -> int:
    from pathlib import Path

    with output_folder(args.out) as out:  # removed again if the demo fails before writing anything
        return _run_demo(Path(out))


def _run_demo(out) -> int:
    name, up, forward = DEMO_VEHICLE
    mesh = load_mesh(asset_path(name), up=up, forward=forward)
    print(f"[1/4] loaded the bundled CC0 vehicle {name}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces")
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
    print(f"[2/4] encoded with the paper's rig and a denser one: {'; '.join(written)}")

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
    print(
        f"[3/4] completed the shipped partial scan ({len(scan)} points, sensor frame) with the pretrained "
        f"{completer.model_name}: {len(res['completed'])} points -> scan_completed.ply, scan_completed.png"
    )
    print(f"[4/4] pictures and files written to {out}/")
    return 0
