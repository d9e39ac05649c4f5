"""A small z-buffer rasteriser for triangle meshes (numpy, orthographic camera).

matplotlib draws 3-D polygons with the painter's algorithm (one depth per face), which
shows far faces through near ones on dense or interpenetrating meshes. Pictures of
meshes are therefore rasterised here, pixel by pixel with a depth test, and shown as an
image: every pixel shows the nearest face, whatever the face count or order.
"""

from __future__ import annotations

import numpy as np


def view_basis(elev: float, azim: float) -> np.ndarray:
    """(3, 3) rows: screen right, screen up, and the direction *towards* the viewer.

    Same convention as matplotlib's ``view_init(elev, azim)`` (degrees): the viewer sits
    at ``(cos e cos a, cos e sin a, sin e)``; at ``elev=90, azim=-90`` right = +x, up = +y.
    """
    e, a = np.radians(elev), np.radians(azim)
    toward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.cross(toward, right)
    return np.stack([right, up, toward])


def rasterize(
    tri_xy: np.ndarray, tri_depth: np.ndarray, width: int, height: int, chunk: int = 1 << 20
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterisation of triangles given in pixel coordinates.

    Parameters
    ----------
    tri_xy : (T, 3, 2) float, vertex positions in pixels (x right, y down; pixel (i, j)
        covers [j, j+1) x [i, i+1), sampled at its centre).
    tri_depth : (T, 3) float, depth of each vertex (smaller = nearer the viewer),
        interpolated linearly over the face (exact for an orthographic camera).
    width, height : image size in pixels.
    chunk : candidate pixels tested at once (memory bound).

    Returns
    -------
    face : (height, width) int64, index of the nearest face at each pixel, -1 for none.
    depth : (height, width) float64, its depth (inf for none).
    """
    tri_xy = np.asarray(tri_xy, dtype=np.float64)
    tri_depth = np.asarray(tri_depth, dtype=np.float64)
    a, b, c = tri_xy[:, 0], tri_xy[:, 1], tri_xy[:, 2]
    v0, v1 = b - a, c - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    lo = np.floor(tri_xy.min(axis=1) - 0.5).astype(np.int64)  # first pixel whose centre may be inside
    hi = np.ceil(tri_xy.max(axis=1) - 0.5).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    side = np.max(hi - lo + 1, axis=1)
    ok = (np.abs(den) > 1e-12) & (side > 0)
    pix_all, dep_all, face_all = [], [], []
    ids = np.flatnonzero(ok)
    if len(ids):
        # bucket faces by the power of two that covers their bounding box: one grid per bucket
        cls = np.ceil(np.log2(np.maximum(side[ids], 1))).astype(np.int64)
        for k in np.unique(cls):
            s = 1 << int(k)
            grid = np.stack(np.meshgrid(np.arange(s), np.arange(s), indexing="xy"), axis=-1).reshape(-1, 2)
            members = ids[cls == k]
            step = max(1, chunk // (s * s))
            for i0 in range(0, len(members), step):
                f = members[i0 : i0 + step]
                px = lo[f][:, None, :] + grid[None]  # (F, s*s, 2) pixel indices (x, y)
                inb = (px[..., 0] <= hi[f][:, None, 0]) & (px[..., 1] <= hi[f][:, None, 1])
                p = px + 0.5 - a[f][:, None, :]
                l1 = (p[..., 0] * v1[f][:, None, 1] - v1[f][:, None, 0] * p[..., 1]) / den[f][:, None]
                l2 = (v0[f][:, None, 0] * p[..., 1] - p[..., 0] * v0[f][:, None, 1]) / den[f][:, None]
                l0 = 1.0 - l1 - l2
                eps = -1e-9
                inside = inb & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
                fi, ci = np.nonzero(inside)
                if len(fi) == 0:
                    continue
                fd = tri_depth[f]
                d = l0[fi, ci] * fd[fi, 0] + l1[fi, ci] * fd[fi, 1] + l2[fi, ci] * fd[fi, 2]
                q = px[fi, ci]
                pix_all.append(q[:, 1] * width + q[:, 0])
                dep_all.append(d)
                face_all.append(f[fi])
    face = np.full(height * width, -1, dtype=np.int64)
    depth = np.full(height * width, np.inf)
    if pix_all:
        pix, dep, fc = np.concatenate(pix_all), np.concatenate(dep_all), np.concatenate(face_all)
        order = np.lexsort((fc, dep, pix))  # per pixel: nearest first (ties: lowest face index)
        pix, dep, fc = pix[order], dep[order], fc[order]
        first = np.ones(len(pix), dtype=bool)
        first[1:] = pix[1:] != pix[:-1]
        face[pix[first]] = fc[first]
        depth[pix[first]] = dep[first]
    return face.reshape(height, width), depth.reshape(height, width)


def shade_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    elev: float,
    azim: float,
    size: int = 800,
    center=None,
    half: float | None = None,
    base=(0.55, 0.65, 0.85),
) -> tuple[np.ndarray, tuple]:
    """An orthographic, shaded RGBA image of a mesh seen from (elev, azim) degrees.

    Parameters
    ----------
    vertices : (V, 3) float, faces : (F, 3) int.
    size : image side in pixels (square). center, half : the square of the view in
        screen coordinates is ``center +- half`` (default: fits the mesh's bounding sphere
        so that every view has the same scale).
    base : RGB of the surface.

    Returns
    -------
    rgba : (size, size, 4) float in [0, 1]; background transparent.
    extent : (left, right, bottom, top) of the image in screen coordinates (for ``imshow``):
        ``p @ right`` and ``p @ up`` of :func:`view_basis`; from the top (elev 90, azim -90)
        these are the mesh's x and y.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    basis = view_basis(elev, azim)
    if center is None:
        lo, hi = v.min(axis=0), v.max(axis=0)
        center = (lo + hi) / 2.0
        half = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-9) * 1.02
    s = (v - center) @ basis.T  # (V, 3): right, up, toward the viewer
    scale = size / (2.0 * half)
    xy = np.stack([(s[:, 0] + half) * scale, (half - s[:, 1]) * scale], axis=1)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    face, _ = rasterize(xy[f], -s[f, 2], size, size)
    # two-sided lighting: a key light above-left of the viewer plus ambient
    light = basis[2] + 0.45 * basis[1] - 0.35 * basis[0]
    light /= np.linalg.norm(light)
    shade = 0.30 + 0.70 * np.abs(n @ light)
    rgba = np.zeros((size, size, 4))
    hit = face >= 0
    rgba[hit, :3] = np.clip(shade[face[hit], None] * np.asarray(base)[None], 0.0, 1.0)
    rgba[hit, 3] = 1.0
    cr, cu = float(np.dot(center, basis[0])), float(np.dot(center, basis[1]))
    return rgba, (cr - half, cr + half, cu - half, cu + half)


def splat_points(
    xy: np.ndarray, depth: np.ndarray, rgb: np.ndarray, diameter: np.ndarray, width: int, height: int
) -> np.ndarray:
    """Points drawn as small discs into an RGBA image with a depth test (the nearest point wins each pixel).

    Parameters
    ----------
    xy : (K, 2) float pixel coordinates (x right, y down; pixel (i, j) covers ``[j, j+1) x [i, i+1)``).
    depth : (K,) float, larger = nearer the viewer. rgb : (K, 3) float colours in [0, 1].
    diameter : (K,) float disc diameters in pixels (at least one pixel is drawn per point).
    width, height : the image size in pixels.

    Returns (height, width, 4) float32 RGBA, alpha 1 where a point was drawn and 0 elsewhere.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    rgb = np.asarray(rgb, dtype=np.float32).reshape(-1, 3)
    dia = np.maximum(np.rint(np.asarray(diameter, dtype=np.float64).reshape(-1)), 1).astype(np.int64)
    img = np.zeros((height, width, 4), dtype=np.float32)
    if len(xy) == 0:
        return img
    cols, rows, src = [], [], []
    for d in np.unique(dia):  # a few marker sizes: one set of disc offsets each
        idx = np.flatnonzero(dia == d)
        off = np.arange(d) - (d - 1) / 2.0
        ox, oy = np.meshgrid(off, off)
        keep = ox**2 + oy**2 <= (d / 2.0) ** 2 + 1e-9
        ox, oy = ox[keep], oy[keep]
        cx = np.floor(xy[idx, 0][:, None] + ox[None]).astype(np.int64)
        cy = np.floor(xy[idx, 1][:, None] + oy[None]).astype(np.int64)
        cols.append(cx.ravel())
        rows.append(cy.ravel())
        src.append(np.repeat(idx, len(ox)))
    c, r, s = np.concatenate(cols), np.concatenate(rows), np.concatenate(src)
    ok = (c >= 0) & (c < width) & (r >= 0) & (r < height)
    c, r, s = c[ok], r[ok], s[ok]
    order = np.argsort(depth[s], kind="stable")  # far first: the nearest comes last
    r, c, s = r[order], c[order], s[order]
    flat = (r * width + c)[::-1]
    _, last = np.unique(flat, return_index=True)  # each pixel's last (nearest) writer, whatever numpy's write order
    last = len(flat) - 1 - last
    r, c, s = r[last], c[last], s[last]
    img[r, c, :3] = rgb[s]
    img[r, c, 3] = 1.0
    return img
