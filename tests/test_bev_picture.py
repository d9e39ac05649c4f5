"""The bird's-eye raster of a frame (``spotlights.viz.bev``): every object's box, observed input and completion is
painted where its metres fall (pixel checks on a tiny scene whose pixels are computed by hand), the scan in grey,
labels and legend in black; the PNG decodes to that image."""

from __future__ import annotations

import io

import numpy as np
import pytest

from spotlights.geometry.boxes import Box
from spotlights.viz.bev import GREEN, GREY, MARGIN, PURPLE, BevCanvas, bev_image, bev_png, nice_step
from spotlights.viz.scene import SceneObject

PIL = pytest.importorskip("PIL.Image")


def tiny_scene():
    """Three boxes (one turned 90 degrees, one without a completion), each with 3 input points near its rear and 3
    completion points at its front half, and a scan line far from every box."""
    objects = []
    for i, (cx, cy, yaw, done) in enumerate(
        [(10.0, 5.0, 0.0, True), (20.0, -6.0, np.pi / 2, True), (-8.0, 9.0, 0.0, False)]
    ):
        box = Box.from_yaw(np.array([cx, cy, 0.8]), np.array([4.0, 2.0, 1.5]), yaw)
        rot = box.rotation
        part = np.array([[-1.5, -0.5, 0.0], [-1.5, 0.0, 0.0], [-1.5, 0.5, 0.0]]) @ rot.T + box.center
        comp = np.array([[1.2, -0.5, 0.0], [1.2, 0.0, 0.0], [1.2, 0.5, 0.0]]) @ rot.T + box.center if done else None
        objects.append(SceneObject(label=f"id{i}", box=box, partial=part, completion=comp, caption=f"car {i}"))
    scan = np.stack([np.linspace(-5, 25, 40), np.full(40, -15.0), np.zeros(40)], axis=1)
    return scan, objects


def pixel(canvas: BevCanvas, xy) -> tuple[int, int]:
    """(row, column) of a point in metres, by hand: x right from lo[0], y up from hi[1], then the margins."""
    col = (xy[0] - canvas.lo[0]) * canvas.px_per_m + MARGIN[0]
    row = (canvas.hi[1] - xy[1]) * canvas.px_per_m + MARGIN[1]
    return int(np.floor(row)), int(np.floor(col))


def test_window_scale_and_pixels_by_hand():
    canvas = BevCanvas.fit(np.array([-10.0, -20.0]), np.array([50.0, 20.0]), max_plot=(1200, 1000))
    assert canvas.px_per_m == 20.0  # 1200 px / 60 m, 1000 px / 40 m = 25: the smaller
    assert canvas.plot_size == (1200, 800)
    np.testing.assert_allclose(canvas.to_pixel([[0.0, 0.0]]), [[10 * 20 + MARGIN[0], 20 * 20 + MARGIN[1]]])
    assert nice_step(7.3) == 5.0 and nice_step(23.0) == 20.0 and nice_step(0.9) == 0.5


def test_every_object_box_input_and_completion_is_drawn():
    scan, objects = tiny_scene()
    pic, canvas = bev_image(scan, objects, title="tiny")
    img = np.asarray(pic)
    assert img.shape[2] == 3 and canvas.px_per_m > 3
    for o in objects:
        for p in o.partial:  # inputs: purple, drawn last (3 x 3 pixels)
            r, c = pixel(canvas, p)
            assert tuple(img[r, c]) == PURPLE, (o.label, p)
        if o.completion is not None:
            for p in o.completion:
                r, c = pixel(canvas, p)
                assert tuple(img[r, c]) == GREEN, (o.label, p)
        k = o.box.corners()
        for a, b in ((1, 3), (3, 7), (7, 5), (5, 1)):  # the bottom face's four edges: black at their midpoints
            r, c = pixel(canvas, (k[a] + k[b]) / 2)
            patch = img[r - 1 : r + 2, c - 1 : c + 2].reshape(-1, 3)
            assert (patch.max(axis=1) < 60).any(), (o.label, a, b)
        r, c = pixel(canvas, (o.center[0], k[:, 1].max()))  # its label just above the box: dark text pixels
        above = img[r - 20 : r - 2, c - 15 : c + 16].reshape(-1, 3)
        assert (above.max(axis=1) < 100).sum() >= 5, o.label
    for p in scan[::7]:
        r, c = pixel(canvas, p)
        assert tuple(img[r, c]) == GREY


def test_the_png_decodes_to_the_image():
    scan, objects = tiny_scene()
    pic, _ = bev_image(scan, objects, title="tiny", id_note="boxes: object id")
    png = bev_png(scan, objects, title="tiny", id_note="boxes: object id")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.array_equal(np.asarray(PIL.open(io.BytesIO(png)).convert("RGB")), np.asarray(pic))
    assert png == bev_png(scan, objects, title="tiny", id_note="boxes: object id")  # same scene, same bytes


@pytest.mark.timeout(120)
def test_complete_show_draws_the_raster_and_closeups_the_matplotlib_figure(tmp_path, capsys):
    """``complete --show`` draws the bird's-eye raster (PIL: no matplotlib in the file); ``--closeups`` the
    matplotlib figure with a close-up per object; ``--closeups`` without ``--show`` is one line."""
    from spotlights.cli import main

    assets = __import__("spotlights").__file__.rsplit("/", 1)[0] + "/assets"
    base = ["complete", f"{assets}/demo_scan.pcd", "--box", f"{assets}/demo_scan_box.json", "-q"]
    assert main([*base, "--out", str(tmp_path / "a.ply"), "--show", str(tmp_path / "a.png")]) == 0
    assert main([*base, "--out", str(tmp_path / "b.ply"), "--show", str(tmp_path / "b.png"), "--closeups"]) == 0
    raster, figure = (tmp_path / "a.png").read_bytes(), (tmp_path / "b.png").read_bytes()
    assert b"matplotlib" not in raster and b"matplotlib" in figure
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "c.ply"), "--closeups"]) == 2
    assert "--closeups goes with --show" in capsys.readouterr().err and not (tmp_path / "c.ply").exists()
