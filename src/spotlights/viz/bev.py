"""A bird's-eye raster of a completed frame: numpy paints the points into an image, PIL draws boxes and text.

The frame picture of ``spotlights complete --show`` and ``real complete`` (FRAME.png): the scan (grey), every
completion (green), every object's observed input (purple, drawn last and larger so that it shows through its
completion), the boxes' outlines (black) labelled with their ids, the sensor (a triangle at the origin), a
metre grid with coordinates, a scale bar, a legend and a title. A nuScenes frame costs a few hundredths of a
second of CPU (against about 0.8 s for matplotlib's figure with close-ups); the close-ups (``--closeups``) stay
matplotlib's (:func:`spotlights.viz.scene.scene_png`).

Drawn on two layers, then written as an 8-bit palette PNG: numpy paints every pixel's base colour (white, grid,
grey, green, purple: :data:`BASE_COLOURS`) and PIL draws the black ink (text antialiased, lines, outlines) on an
``L`` image; the palette (:data:`PALETTE`) holds each base colour under :data:`INK_LEVELS` shades of ink, so the
picture needs no colour search (an RGB encoding of the same picture costs several times more).

Frames: the scan's sensor frame, metres; x to the right of the picture, y up. :class:`BevCanvas` maps metres to
pixels.
"""

from __future__ import annotations

import functools
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

GREY = (170, 170, 170)
PURPLE = (142, 68, 173)
GREEN = (39, 174, 96)
BLACK = (0, 0, 0)
GRID = (232, 232, 232)
WHITE = (255, 255, 255)
MAX_PIXELS_PER_M = 24.0
MIN_PIXELS_PER_M = 3.0
MAX_PLOT_PX = (1500, 1000)
"""The largest plot area (width, height) in pixels; the scale (pixels per metre, within
:data:`MIN_PIXELS_PER_M`..:data:`MAX_PIXELS_PER_M`) is the largest that fits the frame's window."""
MARGIN = (60, 40, 20, 44)
"""Pixels around the plot: left (y coordinates), top (title), right, bottom (x coordinates)."""
CAPTION_WIDTH = 400
"""Pixels of the column right of the plot that lists the objects' captions (id: class, points...)."""


@functools.lru_cache(maxsize=8)
def _font(size: int):
    """PIL's default font at ``size`` pixels (loaded once per size)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def nice_step(length: float) -> float:
    """A round length (1, 2 or 5 x 10^k) at most ``length`` (> 0)."""
    e = 10.0 ** math.floor(math.log10(length))
    return max(m * e for m in (1.0, 2.0, 5.0) if m * e <= length)


def frame_window(objects: Sequence, margin: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """(lo (2,), hi (2,)) metres of the bird's-eye window: every box plus ``margin`` metres, and the sensor (as
    :func:`spotlights.viz.scene.bev_window`)."""
    centers = np.array([np.asarray(o.center, dtype=np.float64)[:2] for o in objects], dtype=np.float64).reshape(-1, 2)
    reach = np.array([o.reach for o in objects], dtype=np.float64).reshape(-1, 1)
    if len(centers) == 0:
        return np.array([-10.0, -10.0]), np.array([10.0, 10.0])
    lo = np.minimum((centers - reach).min(axis=0) - margin, -3.0)
    hi = np.maximum((centers + reach).max(axis=0) + margin, 3.0)
    return lo, hi


@dataclass(frozen=True)
class BevCanvas:
    """Metres of the sensor frame (x, y) -> pixels of the picture (column, row): ``px_per_m`` pixels a metre, the
    window ``lo``..``hi`` (metres) drawn inside the plot area whose top-left pixel is ``origin`` (column, row)."""

    lo: tuple[float, float]
    hi: tuple[float, float]
    px_per_m: float
    origin: tuple[int, int]

    @classmethod
    def fit(cls, lo, hi, max_plot=MAX_PLOT_PX, margin=MARGIN) -> BevCanvas:
        """The canvas of window ``lo``..``hi`` at the largest scale whose plot fits ``max_plot`` pixels."""
        span = np.maximum(np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64), 1e-6)
        s = float(np.clip(min(max_plot[0] / span[0], max_plot[1] / span[1]), MIN_PIXELS_PER_M, MAX_PIXELS_PER_M))
        return cls((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])), s, (margin[0], margin[1]))

    @property
    def plot_size(self) -> tuple[int, int]:
        """(width, height) of the plot area, pixels."""
        return (
            int(math.ceil((self.hi[0] - self.lo[0]) * self.px_per_m)),
            int(math.ceil((self.hi[1] - self.lo[1]) * self.px_per_m)),
        )

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the picture without its caption column, pixels (plot area and :data:`MARGIN`)."""
        w, h = self.plot_size
        return w + MARGIN[0] + MARGIN[2], h + MARGIN[1] + MARGIN[3]

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """(K, 2) float pixel coordinates (column, row; pixel (r, c) covers [c, c+1) x [r, r+1)) of (K, >= 2)
        points in metres (x, y of the sensor frame)."""
        return np.stack(self.columns_rows(xy), axis=1)

    def columns_rows(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (K,) float64 columns and (K,) rows of :meth:`to_pixel`, as two arrays (no (K, 2) array is made)."""
        p = np.asarray(xy)
        p = p.reshape(-1, p.shape[-1])
        col = p[:, 0].astype(np.float64)
        col -= self.lo[0]
        col *= self.px_per_m
        col += self.origin[0]
        row = p[:, 1].astype(np.float64)
        np.subtract(self.hi[1], row, out=row)
        row *= self.px_per_m
        row += self.origin[1]
        return col, row


def paint_points(image: np.ndarray, canvas: BevCanvas, points: np.ndarray, color, radius: int = 0) -> None:
    """Paint (K, >= 2) points (metres) into ``image`` (H, W, 3) uint8 in place with ``color``: each a
    square of (2 ``radius`` + 1) pixels; points outside the plot area are dropped. The pixels hit are marked once
    in a mask and painted in one assignment (however many points share a pixel); pixels of
    :meth:`BevCanvas.columns_rows`."""
    if points is None or len(points) == 0:
        return
    col, row = canvas.columns_rows(points)
    np.floor(col, out=col)
    np.floor(row, out=row)
    w, h = canvas.plot_size
    c0, r0 = canvas.origin
    inside = (col >= c0) & (col < c0 + w) & (row >= r0) & (row < r0 + h)
    c, r = col[inside].astype(np.intp), row[inside].astype(np.intp)
    width = image.shape[1]
    hit = np.zeros(image.shape[0] * width, dtype=bool)  # flat over (H, W): any strides of ``image`` work
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            rr = np.clip(r + dr, r0, r0 + h - 1) if radius else r
            cc = np.clip(c + dc, c0, c0 + w - 1) if radius else c
            hit[rr * width + cc] = True
    image[hit.reshape(image.shape[:2])] = color


#: The picture's colours under the ink, in palette order (white first: the background).
BASE_COLOURS = (WHITE, GRID, GREY, GREEN, PURPLE)
_BASE = {c: i for i, c in enumerate(BASE_COLOURS)}

#: Shades of black ink (text, lines, outlines; 0: none, INK_LEVELS - 1: black) over each base colour: antialiased
#: text in 32 steps, as the eye sees it.
INK_LEVELS = 32

#: The palette of the picture: base colour b with ink q is entry b * INK_LEVELS + q, ``round(b * (1 - q / 31))``.
PALETTE = bytes(
    int(round(c * (1.0 - q / (INK_LEVELS - 1)))) for base in BASE_COLOURS for q in range(INK_LEVELS) for c in base
)

#: An ink value (0..255, an ``L`` image's) -> its shade (0..INK_LEVELS - 1).
_SHADE = np.round(np.arange(256) * (INK_LEVELS - 1) / 255.0).astype(np.uint8)


class _LayeredDraw:
    """The drawing calls of the picture (``PIL.ImageDraw``'s) on two layers: each pixel's base colour (an index into
    :data:`BASE_COLOURS`, painted by numpy) and black ink over it (an ``L`` image: antialiased text, lines,
    outlines). A shape filled or outlined with a base colour is opaque: it sets the base under it and wipes the ink
    drawn there before, as drawing it on the RGB picture would; its pixels are PIL's (drawn on a scratch image)."""

    def __init__(self, base: np.ndarray) -> None:
        from PIL import Image, ImageDraw

        self.base = base
        h, w = base.shape
        self.ink = Image.new("L", (w, h), 0)
        self._ink = ImageDraw.Draw(self.ink)
        self._scratch = Image.new("L", (w, h), 0)
        self._mask = ImageDraw.Draw(self._scratch)

    def _opaque(self, xy, colour, kind: str, width: int) -> None:
        """A rectangle filled (``kind`` "fill") or outlined ("outline") with the base colour ``colour``."""
        self._ink.rectangle(xy, **{kind: 0}, width=width)
        self._mask.rectangle(xy, **{kind: 255}, width=width)
        h, w = self.base.shape
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        x0, y0 = max(0, int(np.floor(p[:, 0].min())) - 2), max(0, int(np.floor(p[:, 1].min())) - 2)
        x1, y1 = min(w, int(np.ceil(p[:, 0].max())) + 3), min(h, int(np.ceil(p[:, 1].max())) + 3)
        if x1 <= x0 or y1 <= y0:
            return
        hit = np.asarray(self._scratch.crop((x0, y0, x1, y1))) > 0
        self.base[y0:y1, x0:x1][hit] = _BASE[tuple(colour)]
        self._mask.rectangle((x0, y0, x1 - 1, y1 - 1), fill=0)

    def rectangle(self, xy, fill=None, outline=None, width: int = 1) -> None:
        for kind, colour in (("fill", fill), ("outline", outline)):  # PIL's order: the fill, then the outline
            if colour is None:
                continue
            if tuple(colour) == BLACK:
                self._ink.rectangle(xy, **{kind: 255}, width=width)
            else:
                self._opaque(xy, colour, kind, width)

    def line(self, xy, fill=BLACK, width: int = 1) -> None:
        self._ink.line(xy, fill=_ink_of(fill), width=width)

    def polygon(self, xy, fill=BLACK) -> None:
        self._ink.polygon(xy, fill=_ink_of(fill))

    def text(self, xy, text: str, fill=BLACK, font=None, anchor: str | None = None) -> None:
        self._ink.text(xy, text, fill=_ink_of(fill), font=font, anchor=anchor)

    def textbbox(self, xy, text: str, font=None, anchor: str | None = None):
        return self._ink.textbbox(xy, text, font=font, anchor=anchor)

    def textlength(self, text: str, font=None) -> float:
        return self._ink.textlength(text, font=font)

    def indexed(self) -> np.ndarray:
        """(H, W) uint8 palette indices (:data:`PALETTE`) of the two layers."""
        return self.base * np.uint8(INK_LEVELS) + _SHADE[np.asarray(self.ink)]


def _ink_of(colour) -> int:
    """The ink value of a colour drawn over the base: black only (the picture's lines and text are black)."""
    if tuple(colour) != BLACK:
        raise ValueError(f"the picture draws lines and text in black, got {colour}")
    return 255


def bev_image(
    scan: np.ndarray,
    objects: Sequence,
    title: str | None = None,
    id_note: str = "boxes: object id",
    window: tuple[np.ndarray, np.ndarray] | None = None,
    max_plot: tuple[int, int] = MAX_PLOT_PX,
):
    """The bird's-eye picture of a frame as a PIL image (RGB) and its :class:`BevCanvas`.

    Parameters
    ----------
    scan : (N, >= 2) raw scan points (x, y first; float32 or float64), sensor frame, metres (every point inside the
        window is drawn, one pixel each).
    objects : :class:`~spotlights.viz.scene.SceneObject`-like objects (``label``, ``box`` with ``corners()``,
        ``center``, ``reach``, ``partial`` (K, >= 2), ``completion`` (L, >= 2) or None), sensor frame, metres.
    title : the line above the picture; id_note : what the box labels are (in the legend).
    window : (lo (2,), hi (2,)) metres drawn (default :func:`frame_window`); max_plot : the largest plot area.
    """
    pic, canvas = _bev_indexed(scan, objects, title, id_note, window, max_plot)
    return pic.convert("RGB"), canvas


def _bev_indexed(scan, objects, title, id_note, window, max_plot=MAX_PLOT_PX):
    """:func:`bev_image`'s picture as an 8-bit palette image (:data:`BASE_COLOURS`, each in :data:`INK_LEVELS`
    shades of black ink over it: :data:`PALETTE`) and its canvas."""
    from PIL import Image

    objects = list(objects)
    lo, hi = window if window is not None else frame_window(objects)
    canvas = BevCanvas.fit(lo, hi, max_plot)
    width, height = canvas.image_size
    captions = [f"{o.label}: {o.caption}" for o in objects if getattr(o, "caption", "")]
    plot_width = width
    if captions:
        width += CAPTION_WIDTH
        height = max(height, MARGIN[1] + 16 * (len(captions) + 1) + 10)
    base = np.zeros((height, width), dtype=np.uint8)  # BASE_COLOURS' indices: white
    step = nice_step((canvas.hi[0] - canvas.lo[0]) / 6.0)
    xs = np.arange(math.ceil(canvas.lo[0] / step) * step, canvas.hi[0] + 1e-9, step)
    ys = np.arange(math.ceil(canvas.lo[1] / step) * step, canvas.hi[1] + 1e-9, step)
    _paint_layers(base, canvas, xs, ys, scan, objects)
    draw = _LayeredDraw(base)
    small, font = _font(11), _font(13)
    _draw_axes(draw, canvas, xs, ys, small)
    _draw_boxes(draw, canvas, objects, small)
    _draw_sensor_and_scale(draw, canvas, small)
    _draw_legend(draw, canvas, id_note, small)
    r0 = canvas.origin[1]
    if captions:  # the objects, one line each (long lines cut at the column's edge)
        x = plot_width + 4
        draw.text((x, r0), "objects", fill=BLACK, font=font, anchor="lt")
        for i, text in enumerate(captions):
            while len(text) > 8 and draw.textlength(text, font=small) > CAPTION_WIDTH - 12:
                text = text[:-2] + "\u2026" if text.endswith("\u2026") else text[:-1] + "\u2026"
            draw.text((x, r0 + 20 + 16 * i), text, fill=BLACK, font=small, anchor="lt")
    if title:  # centred over the plot, moved right as far as it needs to start inside the picture
        cx = max(plot_width / 2, draw.textlength(title, font=font) / 2 + 6)
        draw.text((cx, r0 / 2), title, fill=BLACK, font=font, anchor="mm")
    pic = Image.fromarray(draw.indexed(), mode="P")
    pic.putpalette(PALETTE)
    return pic, canvas


def xy_of(points) -> np.ndarray:
    """(K, 2) x, y (metres; the points' own float type, a view where it can be) of (K, >= 2) points; (0, 2) for
    none."""
    a = np.asarray(points)
    return a.reshape(len(a), -1)[:, :2] if a.size else np.zeros((0, 2))


def _paint_layers(image: np.ndarray, canvas: BevCanvas, xs, ys, scan, objects: list) -> None:
    """Paint into ``image`` (H, W) uint8 of :data:`BASE_COLOURS` indices: the metre grid at ``xs``/``ys``
    (metres), the scan (grey), the completions (green), then the partial inputs (purple, larger)."""
    c0, r0 = canvas.origin
    pw, ph = canvas.plot_size
    for x in xs:  # the metre grid, under everything
        image[r0 : r0 + ph, int(canvas.to_pixel([[x, 0.0]])[0, 0])] = _BASE[GRID]
    for y in ys:
        image[int(canvas.to_pixel([[0.0, y]])[0, 1]), c0 : c0 + pw] = _BASE[GRID]
    paint_points(image, canvas, xy_of(scan), _BASE[GREY])
    comps = [xy_of(o.completion) for o in objects if o.completion is not None and len(o.completion)]
    if comps:
        paint_points(image, canvas, np.concatenate(comps), _BASE[GREEN])
    parts = [xy_of(o.partial) for o in objects]
    if parts:
        paint_points(image, canvas, np.concatenate(parts), _BASE[PURPLE], radius=1)


def _draw_axes(draw, canvas: BevCanvas, xs, ys, small) -> None:
    """The plot's frame, the grid lines' coordinates (metres) and the axis names."""
    c0, r0 = canvas.origin
    pw, ph = canvas.plot_size
    draw.rectangle([c0 - 1, r0 - 1, c0 + pw, r0 + ph], outline=BLACK)
    for x in xs:
        col = canvas.to_pixel([[x, 0.0]])[0, 0]
        draw.text((col, r0 + ph + 4), f"{x:g}", fill=BLACK, font=small, anchor="mt")
    for y in ys:
        row = canvas.to_pixel([[0.0, y]])[0, 1]
        draw.text((c0 - 5, row), f"{y:g}", fill=BLACK, font=small, anchor="rm")
    draw.text((c0 + pw / 2, r0 + ph + 20), "x (m, sensor frame)", fill=BLACK, font=small, anchor="mt")
    draw.text((12, r0 + ph / 2), "y (m)", fill=BLACK, font=small, anchor="lm")


def _draw_boxes(draw, canvas: BevCanvas, objects: list, small) -> None:
    """Each box's bottom face (black), then its label above its northmost corner on white."""
    for o in objects:  # each box's bottom face, then its id above its northmost corner
        k = canvas.to_pixel(o.box.corners()[[1, 3, 7, 5, 1]])
        draw.line([tuple(p) for p in k], fill=BLACK, width=1)
    for o in objects:
        k = canvas.to_pixel(o.box.corners())
        at = (float(canvas.to_pixel([o.center])[0, 0]), float(k[:, 1].min()) - 3)
        box = draw.textbbox(at, str(o.label), font=small, anchor="mb")
        draw.rectangle([box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1], fill=WHITE)
        draw.text(at, str(o.label), fill=BLACK, font=small, anchor="mb")


def _draw_sensor_and_scale(draw, canvas: BevCanvas, small) -> None:
    """The sensor (a triangle at the origin, when inside the plot) and the scale bar (lower left)."""
    c0, r0 = canvas.origin
    pw, ph = canvas.plot_size
    s = canvas.to_pixel([[0.0, 0.0]])[0]
    if c0 <= s[0] < c0 + pw and r0 <= s[1] < r0 + ph:
        draw.polygon([(s[0], s[1] - 7), (s[0] - 6, s[1] + 5), (s[0] + 6, s[1] + 5)], fill=BLACK)
        draw.text((s[0], s[1] + 8), "sensor", fill=BLACK, font=small, anchor="mt")
    bar = nice_step((canvas.hi[0] - canvas.lo[0]) / 5.0)  # the scale bar, lower left of the plot
    x0, y0 = c0 + 12, r0 + ph - 14
    draw.line([(x0, y0), (x0 + bar * canvas.px_per_m, y0)], fill=BLACK, width=3)
    draw.text((x0 + bar * canvas.px_per_m / 2, y0 - 4), f"{bar:g} m", fill=BLACK, font=small, anchor="mb")


def _draw_legend(draw, canvas: BevCanvas, id_note: str, small) -> None:
    """The legend box in the plot's upper right corner: the three point colours and the box labels."""
    c0, r0 = canvas.origin
    pw, _ = canvas.plot_size
    legend = [(GREY, "raw scan"), (GREEN, "completion"), (PURPLE, "partial input"), (BLACK, id_note)]
    lw = max(draw.textlength(t, font=small) for _, t in legend) + 30
    lx, ly = c0 + pw - lw - 6, r0 + 6
    draw.rectangle([lx, ly, lx + lw, ly + 16 * len(legend) + 6], fill=WHITE, outline=GRID)
    for i, (color, text) in enumerate(legend):
        y = ly + 6 + 16 * i
        if i < 3:
            draw.rectangle([lx + 6, y + 2, lx + 15, y + 11], fill=color)
        else:
            draw.rectangle([lx + 6, y + 2, lx + 15, y + 11], outline=color)
        draw.text((lx + 22, y + 7), text, fill=BLACK, font=small, anchor="lm")


def bev_png(
    scan: np.ndarray,
    objects: Sequence,
    title: str | None = None,
    id_note: str = "boxes: object id",
    window: tuple[np.ndarray, np.ndarray] | None = None,
) -> bytes:
    """The PNG bytes of :func:`bev_image`'s picture, written as the 8-bit palette image it is drawn as
    (:data:`PALETTE`; zlib level 3, run-length strategy): a few tens of kB."""
    pic, _ = _bev_indexed(scan, objects, title, id_note, window)
    buf = io.BytesIO()
    pic.save(buf, format="PNG", compress_level=3, compress_type=3)  # zlib's Z_RLE: runs of one colour
    return buf.getvalue()


__all__ = [
    "BASE_COLOURS",
    "INK_LEVELS",
    "PALETTE",
    "BevCanvas",
    "bev_image",
    "bev_png",
    "frame_window",
    "nice_step",
    "paint_points",
    "xy_of",
]
