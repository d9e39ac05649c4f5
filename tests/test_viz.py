"""The viz package: no pyplot state, pictures of the expected size and content, the z-buffer
rasteriser against closed forms, and the HTML viewer (self-contained page; a real browser draws it)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from helpers import CARS, LIDAR, REPO, need, run_cli, src_pythonpath


def _png(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB")).astype(np.int64)


def _count_color(img: np.ndarray, rgb, tol: int = 12) -> int:
    """Pixels within ``tol`` (per channel) of ``rgb``."""
    return int(np.sum(np.all(np.abs(img - np.asarray(rgb)) <= tol, axis=-1)))


def _hex(color: str) -> tuple[int, int, int]:
    return tuple(int(color[i : i + 2], 16) for i in (1, 3, 5))


# --- no global matplotlib state ---------------------------------------------------------------
def test_viz_sets_no_backend_and_no_pyplot(tmp_path):
    """Drawing with viz leaves the caller's backend as it was (here svg), never calls
    matplotlib.use, and never imports pyplot (no figure manager holds figures)."""
    code = f"""
import sys, matplotlib
calls = []
matplotlib.use = lambda *a, **k: calls.append(a)
before = matplotlib.get_backend()
import numpy as np, trimesh
from spotlights import viz
from spotlights.viz import density
pts = np.random.default_rng(0).normal(size=(500, 3))
viz.render_layers(r"{tmp_path}/a.png", [viz.Layer(pts, "tab:green", "pts")])
viz.render_mesh(r"{tmp_path}/b.png", trimesh.creation.box())
density.plot_caps(r"{tmp_path}/c.png", np.linspace(0, 0.9, 10),
                  {{60.0: {{"alpha0": np.linspace(1, 2, 10), "alpha90": np.linspace(1, 3, 10)}}}},
                  [{{"angle": 60.0, "uniformity": 2.0, "uniformity_095": 3.0, "hit_ratio_05": 0.5}}])
print(before, matplotlib.get_backend(), len(calls), "matplotlib.pyplot" in sys.modules)
"""
    env = dict(os.environ, MPLBACKEND="svg", PYTHONPATH=src_pythonpath())
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=240)
    assert out.returncode == 0, out.stderr
    before, after, n_use, pyplot = out.stdout.split()
    assert before == after == "svg"
    assert n_use == "0" and pyplot == "False"
    for name in "abc":
        assert (tmp_path / f"{name}.png").stat().st_size > 1000


def test_no_matplotlib_use_in_sources():
    src = (REPO / "src" / "spotlights").rglob("*.py")
    offenders = [
        str(p) for p in src if "matplotlib.use(" in p.read_text() or "import matplotlib.pyplot" in p.read_text()
    ]
    assert offenders == []


# --- pictures ------------------------------------------------------------------------------------
def test_render_layers_size_and_content(tmp_path):
    from spotlights import viz

    pts = np.random.default_rng(1).uniform(-1, 1, size=(3000, 3))
    out = viz.render_layers(tmp_path / "p.png", [viz.Layer(pts, "#27ae60", "cloud", 6.0, 1.0)], title="t", dpi=100)
    img = _png(out)
    assert img.shape == (520, 1000, 3)  # two 5-inch views x 5.2 inches at 100 dpi
    # both panels show green points: the 3-D view (left half) and the top view (right half)
    green = _hex("#27ae60")
    assert _count_color(img[:, :500], green) > 2000
    assert _count_color(img[:, 500:], green) > 2000


def test_render_encoding_has_colour_bar(tmp_path):
    from types import SimpleNamespace

    import trimesh

    from spotlights import viz
    from spotlights.geometry.encode import MeshProbe
    from spotlights.geometry.rig import make_rig

    probe = MeshProbe(trimesh.creation.icosphere(subdivisions=3, radius=0.5))
    rig = make_rig(8, 32, angle=60.0)
    enc = SimpleNamespace(depths=probe.encode(rig), rig=rig)  # what render_encoding reads
    out = viz.render_encoding(tmp_path / "e.png", enc)
    img = _png(out)
    # the colour bar: a tall strip whose rows run through the turbo colours (dark red at the top)
    right = img[:, int(img.shape[1] * 0.85) :]
    assert _count_color(right, (122, 4, 3), tol=30) > 20  # turbo(1.0)
    assert _count_color(right, (48, 18, 59), tol=30) > 20  # turbo(0.0)


def test_rasterizer_occlusion_and_area():
    """Closed forms: a triangle covers its area in pixels (to within its perimeter); of two
    overlapping squares the nearer one is seen whatever the face order."""
    from spotlights.viz.raster import rasterize

    tri = np.array([[[10.0, 10.0], [90.0, 10.0], [10.0, 70.0]]])
    face, _ = rasterize(tri, np.zeros((1, 3)), 100, 100)
    area = 0.5 * 80 * 60
    assert abs(int((face == 0).sum()) - area) <= 80 + 60 + 100
    sq = lambda x0, y0, s: np.array(
        [[[x0, y0], [x0 + s, y0], [x0 + s, y0 + s]], [[x0, y0], [x0 + s, y0 + s], [x0, y0 + s]]]
    )
    tris = np.concatenate([sq(20, 20, 40), sq(40, 40, 40)])  # faces 0,1 far square; 2,3 near square
    depth = np.array([[5.0] * 3, [5.0] * 3, [1.0] * 3, [1.0] * 3])
    for order in (np.arange(4), np.arange(4)[::-1]):
        f, d = rasterize(tris[order], depth[order], 100, 100)
        seen = order[f[50, 50]]  # the overlap: the near square
        assert seen in (2, 3) and d[50, 50] == 1.0
        assert order[f[30, 30]] in (0, 1) and f[90, 90] == -1


def test_render_mesh_top_view_is_opaque(tmp_path):
    """A dense closed mesh seen from the top covers its silhouette without holes (no face subsampling)."""
    import trimesh

    from spotlights import viz
    from spotlights.viz.raster import shade_mesh

    mesh = trimesh.creation.icosphere(subdivisions=5)  # 20480 faces
    rgba, extent = shade_mesh(mesh.vertices, mesh.faces, 90.0, -90.0, size=400)
    cov = rgba[..., 3] > 0
    h = 400 / (extent[1] - extent[0])
    disc = np.pi * (h * 1.0) ** 2  # the unit sphere's silhouette in pixels
    assert abs(cov.sum() - disc) / disc < 0.02
    out = viz.render_mesh(tmp_path / "m.png", mesh, title="sphere", dpi=80)
    assert _png(out).shape == (416, 800, 3)


def test_splat_points_matches_a_per_pixel_loop():
    """Each pixel shows the nearest of the points whose disc covers it (brute force over pixels and points)."""
    from spotlights.viz.raster import splat_points

    rng = np.random.default_rng(0)
    k, w, h = 60, 23, 17
    xy = rng.uniform(-2, [w + 2, h + 2], (k, 2))
    depth = rng.permutation(k).astype(float)  # distinct depths: no ties
    rgb = rng.uniform(0, 1, (k, 3))
    dia = rng.choice([0.4, 1.0, 2.0, 3.0, 4.6], k)
    img = splat_points(xy, depth, rgb, dia, w, h)
    assert img.shape == (h, w, 4) and img.dtype == np.float32
    want = np.zeros((h, w, 4), dtype=np.float32)
    best = np.full((h, w), -np.inf)
    for i in range(k):
        d = max(int(np.rint(dia[i])), 1)
        off = np.arange(d) - (d - 1) / 2.0
        for ox in off:
            for oy in off:
                if ox * ox + oy * oy > (d / 2.0) ** 2 + 1e-9:
                    continue
                c, r = int(np.floor(xy[i, 0] + ox)), int(np.floor(xy[i, 1] + oy))
                if 0 <= c < w and 0 <= r < h and depth[i] > best[r, c]:
                    best[r, c] = depth[i]
                    want[r, c] = [*rgb[i], 1.0]
    assert np.array_equal(img, want)
    assert np.array_equal(splat_points(np.zeros((0, 2)), [], np.zeros((0, 3)), [], 4, 3), np.zeros((3, 4, 4)))


def test_scene_picture_labels_ids(tmp_path):
    from spotlights.geometry.boxes import Box
    from spotlights.viz.scene import SceneObject, render_scene

    rng = np.random.default_rng(0)
    ground = np.c_[rng.uniform(-20, 20, (5000, 2)), np.full(5000, -1.0)]
    objs = [
        SceneObject(
            "track-a",
            Box([8.0, 2.0, 0.0], [4.0, 1.8, 1.5]),
            rng.normal([8, 2, 0], 0.4, (256, 3)),
            rng.normal([8, 2, 0], 0.6, (800, 3)),
            "car",
        )
    ]
    out = render_scene(tmp_path / "s.png", ground, objs, title="scene")
    img = _png(out)
    assert _count_color(img, _hex("#8e44ad")) > 200  # purple inputs visible (not hidden by grey)
    assert _count_color(img, _hex("#27ae60")) > 200


# --- the HTML viewer -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def cloud_page(tmp_path_factory):
    pytest.importorskip("plotly")
    d = tmp_path_factory.mktemp("view")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(4000, 3)) * [2.0, 1.0, 0.5]
    np.save(d / "cloud.npy", pts.astype(np.float32))
    proc = run_cli("view", d / "cloud.npy", "--out", d / "view.html")
    assert proc.returncode == 0, proc.stderr
    return d


def test_view_page_is_self_contained(cloud_page):
    text = (cloud_page / "view.html").read_text()
    assert "Plotly.newPlot" in text and len(text) > 3_000_000  # plotly.js embedded (~4.7 MB)
    import re

    srcs = re.findall(r"<script[^>]*\bsrc\s*=", text, flags=re.I)
    assert srcs == []  # no external script
    assert "aspectmode" in text and '"data"' in text


def test_view_kinds_and_errors(tmp_path):
    pytest.importorskip("plotly")
    from spotlights.viz import html

    boxes = tmp_path / "boxes.json"
    boxes.write_text(json.dumps({"boxes": [{"center": [1, 2, 0], "size": [4, 2, 1.5], "yaw": 0.3, "id": "car-7"}]}))
    traces, what = html.file_traces(boxes)
    assert what == "1 box" and list(traces[1].text) == ["car-7"]
    # a scene PLY with source/object fields: raw grey, completion green, partial purple
    n = 300
    v = np.random.default_rng(0).normal(size=(n, 3)).astype(np.float32)
    ply = tmp_path / "scene.ply"
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar source\nproperty int object\nend_header\n"
    )
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("source", "u1"), ("object", "<i4")])
    rec["x"], rec["y"], rec["z"] = v.T
    rec["source"] = np.arange(n) % 3
    rec["object"] = np.where(rec["source"] == 0, -1, 4)
    ply.write_bytes(header.encode() + rec.tobytes())
    traces, what = html.file_traces(ply)
    colours = [t.marker.color for t in traces]
    assert colours == [html.GREY, html.GREEN, html.PURPLE]
    assert all(len(t.x) == 100 for t in traces)
    proc = run_cli("view", tmp_path / "nope.ply", "--out", tmp_path / "x.html")
    assert proc.returncode == 2 and "nope.ply" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "x.html").exists()


def test_view_serve_answers_the_page_over_loopback(tmp_path):
    """'view --serve --port 0': the URL and the 'ssh -L' line are printed, the page is fetched over
    loopback with urllib (the same self-contained page as --out), other paths are 404, and Ctrl-C
    (SIGINT) stops the server with exit code 0; every step is bounded in time."""
    pytest.importorskip("plotly")
    import queue
    import re
    import signal
    import threading
    import urllib.error
    import urllib.request

    scan = REPO / "src" / "spotlights" / "assets" / "demo_scan.pcd"
    env = dict(os.environ, PYTHONPATH=src_pythonpath(), PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "spotlights", "view", str(scan), "--serve", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
        # a suite started in the background ('cmd &' in a script) inherits SIGINT ignored, and Python then
        # installs no KeyboardInterrupt handler: give the server Ctrl-C's default disposition, as in a terminal
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(ln) for ln in proc.stdout], daemon=True).start()
    try:
        seen, url = [], None
        while url is None:
            line = lines.get(timeout=120)  # building the page: a few seconds
            seen.append(line)
            m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
            if m:
                url, port = m.group(0), int(m.group(1))
        ssh = lines.get(timeout=10)
        assert f"ssh -L {port}:localhost:{port} user@host" in ssh, seen + [ssh]
        with urllib.request.urlopen(url, timeout=30) as resp:
            assert resp.status == 200 and resp.headers["Content-Type"].startswith("text/html")
            text = resp.read().decode("utf-8")
        assert "Plotly.newPlot" in text and len(text) > 3_000_000
        assert re.findall(r"<script[^>]*\bsrc\s*=", text, flags=re.I) == []  # self-contained
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(url + "other.js", timeout=30)
        assert err.value.code == 404
        proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # say where the server hangs
            proc.send_signal(signal.SIGABRT)  # PYTHONFAULTHANDLER: every thread's stack on stderr
            proc.wait(timeout=30)
            pytest.fail("view --serve did not stop within 30 s of SIGINT; its threads:\n" + proc.stderr.read())
        assert rc == 0, proc.stderr.read()
        assert "Traceback" not in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
    assert list(tmp_path.iterdir()) == []  # --serve without --out writes no file


def test_view_serve_options(tmp_path):
    """--port/--host need --serve; a busy port is a one-line error; loopback detection."""
    pytest.importorskip("plotly")
    import socket

    from spotlights.viz import serve

    scan = REPO / "src" / "spotlights" / "assets" / "demo_scan.pcd"
    proc = run_cli("view", scan, "--port", "8123", "--out", tmp_path / "v.html")
    assert proc.returncode == 2 and "--serve" in proc.stderr and not (tmp_path / "v.html").exists()
    assert serve.is_loopback("127.0.0.1") and serve.is_loopback("::1") and serve.is_loopback("localhost")
    assert not serve.is_loopback("0.0.0.0") and not serve.is_loopback("192.168.1.20")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        with pytest.raises(serve.SpotlightsError, match="choose another --port"):
            serve.make_server(b"x", "127.0.0.1", busy.getsockname()[1])


def test_show_html_of_a_mesh(tmp_path):
    pytest.importorskip("plotly")
    mesh = next(need(CARS).rglob("*.ply"))
    proc = run_cli("show", mesh, "--html", tmp_path / "m.html", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "m.html").stat().st_size > 3_000_000
    assert not list(tmp_path.glob("*.png"))  # --html alone: no picture


def _chromium() -> str | None:
    env = os.environ.get("SPOTLIGHTS_CHROMIUM")
    if env:
        return env
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _screenshot(page: Path, png: Path, timeout: float = 120) -> None:
    """Headless Chromium, network off (own network namespace when possible, else a dead proxy and
    no name resolution), a fresh profile; waits for rendering and writes a 1200 x 900 screenshot."""
    chrome = _chromium()
    with tempfile.TemporaryDirectory() as profile:
        cmd = [
            chrome,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--enable-unsafe-swiftshader",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={profile}",
            "--host-resolver-rules=MAP * ~NOTFOUND",
            "--proxy-server=127.0.0.1:9",
            "--window-size=1200,900",
            "--hide-scrollbars",
            "--virtual-time-budget=20000",
            f"--screenshot={png}",
            page.resolve().as_uri(),
        ]
        unshare = shutil.which("unshare")
        if unshare and subprocess.run([unshare, "-n", "true"], capture_output=True).returncode == 0:
            cmd = [unshare, "-n"] + cmd  # no network device at all
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert png.exists(), proc.stderr[-2000:]


@pytest.mark.skipif(
    _chromium() is None,
    reason="Chromium not found: install it (Debian/Ubuntu: apt-get install chromium) "
    "or set SPOTLIGHTS_CHROMIUM to a Chrome/Chromium binary",
)
@pytest.mark.slow
def test_page_draws_points_in_a_real_browser(tmp_path):
    """The page opens offline in headless Chromium and the points are drawn: pixels of the point
    colour fill the plot area; with the cloud hidden (legend-only) the same area has none."""
    pytest.importorskip("plotly")
    from spotlights.viz import html

    pts = np.random.default_rng(0).normal(size=(4000, 3)) * [2.0, 1.0, 0.5]
    colour = "#27ae60"
    shown = html.page([("cloud", [html.points_trace(pts, "cloud", colour, 4.0)])], "browser test")
    html.write_html(tmp_path / "shown.html", shown)
    hidden = html.page([("cloud", [html.points_trace(pts, "cloud", colour, 4.0)])], "browser test")
    hidden.update_traces(visible="legendonly")
    html.write_html(tmp_path / "hidden.html", hidden)
    counts = {}
    for name in ("shown", "hidden"):
        _screenshot(tmp_path / f"{name}.html", tmp_path / f"{name}.png")
        img = _png(tmp_path / f"{name}.png")
        plot_area = img[60:860, 100:1000]  # below the title, left of the legend's column
        counts[name] = _count_color(plot_area, _hex(colour), tol=40)
    assert counts["shown"] > 3000, counts
    assert counts["hidden"] < 50, counts


@pytest.mark.skipif(
    _chromium() is None, reason="Chromium not found: apt-get install chromium (or set SPOTLIGHTS_CHROMIUM)"
)
@pytest.mark.slow
def test_real_show_page_in_browser(tmp_path):
    """A whole real scene: the page of 'view observations.h5' draws the grey raw scan in Chromium."""
    pytest.importorskip("plotly")
    src = need(LIDAR / "kitti-object" / "training-fov-cropped")
    proc = run_cli("real", "extract", src, "--format", "kitti", "--out", tmp_path / "k.h5", "-q")
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("view", tmp_path / "k.h5", "--out", tmp_path / "k.html")
    assert proc.returncode == 0, proc.stderr
    _screenshot(tmp_path / "k.html", tmp_path / "k.png")
    img = _png(tmp_path / "k.png")
    assert _count_color(img[60:860, 100:1000], _hex("#9a9a9a"), tol=25) > 2000
    assert _count_color(img[60:860, 100:1000], _hex("#8e44ad"), tol=40) > 50


def test_predictions_figure_colours_by_distance(tmp_path):
    """A prediction lying on the ground truth is drawn in the colour of distance 0 (viridis' first),
    one 0.3 away in the colour of the scale's top (yellow)."""
    from spotlights.viz import render_predictions

    rng = np.random.default_rng(0)
    gt = rng.normal(size=(4000, 3))
    gt /= np.linalg.norm(gt, axis=1, keepdims=True) * 1.5
    exact = gt[::4].copy()
    far = exact * (1 + 0.45)  # radius 1/1.5 -> 0.967: 0.3 from the sphere
    ex = [{"label": "sphere", "partial": gt[gt[:, 0] > 0.3], "gt": gt, "predictions": [("exact", exact), ("far", far)]}]
    out = render_predictions(tmp_path / "p.png", ex, title="t", vmax=0.3, dpi=80)
    img = _png(out)
    assert img.shape[0] > 200 and img.shape[1] > 800
    ncol = 4
    w = img.shape[1] / (ncol + 0.8 / 2.6)
    exact_panel, far_panel = img[:, int(w) : int(2 * w)], img[:, int(2 * w) : int(3 * w)]
    dark, yellow = (68, 1, 84), (253, 231, 37)
    assert _count_color(exact_panel, dark, 20) > 200 and _count_color(exact_panel, yellow, 30) < 20
    assert _count_color(far_panel, yellow, 30) > 200 and _count_color(far_panel, dark, 20) < 20


def test_complete_html(tmp_path):
    pytest.importorskip("plotly")
    pytest.importorskip("torch")
    assets = REPO / "src" / "spotlights" / "assets"
    proc = run_cli(
        "complete",
        assets / "demo_scan.pcd",
        "--box",
        assets / "demo_scan_box.json",
        "--out",
        tmp_path / "c.ply",
        "--html",
        tmp_path / "c.html",
    )
    assert proc.returncode == 0, proc.stderr
    text = (tmp_path / "c.html").read_text()
    assert "completion (" in text and "partial input (" in text and "raw scan" in text


def test_real_show_html(tmp_path):
    pytest.importorskip("plotly")
    pytest.importorskip("torch")
    src = need(LIDAR / "kitti-object" / "training-fov-cropped")
    assert run_cli("real", "extract", src, "--format", "kitti", "--out", tmp_path / "k.h5", "-q").returncode == 0
    proc = run_cli("real", "show", tmp_path / "k.h5", "--frame", "002155", "--html", tmp_path / "k.html", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    text = (tmp_path / "k.html").read_text()
    assert '"#' in text and "boxes" in text  # rows as ids: KITTI has no track ids
    assert not list(tmp_path.glob("*.png"))


@pytest.mark.slow
def test_real_complete_html_pages_share_one_local_script(tmp_path):
    pytest.importorskip("plotly")
    pytest.importorskip("torch")
    src = need(LIDAR / "kitti-object" / "training-fov-cropped")
    proc = run_cli(
        "real", "complete", src, "--format", "kitti", "--out", tmp_path / "out", "--frames", "002155", "--html", "-q"
    )
    assert proc.returncode == 0, proc.stderr
    page = (tmp_path / "out" / "002155.html").read_text()
    assert '<script charset="utf-8" src="plotly.min.js"' in page and "http" not in page.split("<body>")[0]
    assert (tmp_path / "out" / "plotly.min.js").stat().st_size > 3_000_000


def test_view_without_plotly_says_how_to_install(tmp_path):
    code = (
        "import sys; sys.modules['plotly'] = None; sys.modules['plotly.graph_objects'] = None\n"
        "from spotlights.cli import main\n"
        f"sys.exit(main(['view', r'{REPO / 'src' / 'spotlights' / 'assets' / 'demo_scan.pcd'}', '-o', r'{tmp_path / 'v.html'}']))"
    )
    env = dict(os.environ, PYTHONPATH=src_pythonpath())
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2 and "pip install 'spotlights[viewer]'" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not (tmp_path / "v.html").exists()


def test_the_viewer_reads_boxes_with_the_one_box_parser(tmp_path):
    """Generic box files and a completion summary's boxes give the same boxes; a box without a heading is refused
    as everywhere else (the one parser)."""
    import json

    from spotlights.errors import InputFileError
    from spotlights.geometry.boxes import Box
    from spotlights.viz.html import read_boxes_json

    box = Box([1.0, 2.0, 0.5], [4.2, 1.8, 1.5], yaw=0.3, label="car", track_id="7")
    (tmp_path / "summary.json").write_text(json.dumps({"objects": [{"object": 7, "box": box.to_dict()}]}))
    generic = [{"center": [1.0, 2.0, 0.5], "size": [4.2, 1.8, 1.5], "yaw": 0.3, "label": "car"}]
    (tmp_path / "boxes.json").write_text(json.dumps(generic))
    (a,), (b,) = read_boxes_json(tmp_path / "summary.json"), read_boxes_json(tmp_path / "boxes.json")
    np.testing.assert_allclose(a.corners(), box.corners(), atol=1e-9)
    np.testing.assert_allclose(b.corners(), box.corners(), atol=1e-9)
    assert (a.label, b.label) == ("7", "car")
    (tmp_path / "bad.json").write_text(json.dumps([{"center": [0, 0, 0], "size": [4, 2, 1.5]}]))
    with pytest.raises(InputFileError, match="needs 'yaw' or 'rotation'"):
        read_boxes_json(tmp_path / "bad.json")
