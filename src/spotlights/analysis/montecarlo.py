"""Monte-Carlo check of the ray density with real rigs and real ray casting.

A small flat disc (a triangle fan) is placed inside the unit sphere at distance
``r`` from the centre with its normal at angle ``alpha`` from the outward radial
direction; every ray of a real :class:`~spotlights.geometry.rig.Rig` is cast at it
with :class:`~spotlights.geometry.raycast.RayCaster` (Embree) and the first hits are
counted, separately on the front face (ray against the normal) and on the back
face (a surfel of orientation ``pi - alpha``). The expected count is

    E[hits] = N M * Int_disc rho(x, n) dS,

with ``rho`` from :mod:`spotlights.analysis.density` integrated over the actual
polygon by a product Gauss rule on each fan triangle.

A Fibonacci rig is deterministic, so one placement gives one number with no
statistical meaning. The disc is therefore placed ``n_rotations`` times, each time
rotated about the centre by an independent uniformly random rotation (equivalent to
rotating the rig; ``rho`` depends on ``(r, alpha)`` only). Averaged over rotations,
every viewpoint is uniformly distributed on the sphere and every cap sample's azimuth
is random, so the mean count is exactly ``N * sum_k Int_disc rho_ring(c_k) dS`` over the
rig's discrete polar angles ``c_k = cos t_k = 1 - (1 - cos omega) k / M`` (a left Riemann
sum of the continuum, whose k = 0 term is the central ray of each bundle, aimed exactly at
the centre). Its leading difference from the continuum is the Euler-Maclaurin end term
(:func:`finite_m_correction`), ``|cos alpha| / (8 pi M r^2)`` per unit N*M at the front face
for 90-degree caps: about 1 % of rho at r = 0.3 for M = 1024, 0.1 % at r = 0.9. The
comparison uses quadrature + that term. At the centre itself the expansion fails (all N
central rays cross the centre: a point spike of the discrete rig, +37 % on a disc of
radius 0.08 with M = 1024); there the exact rig expectation
(:func:`centre_disc_expected_density`) is used. In between (discs spanning few caustic
shells ``r = sin t_k``, roughly ``M r a < 20``) neither is exact, so placements there are
not used for the agreement claim.

The standard error is the empirical spread of the per-rotation counts
(``std / sqrt(K)``); the Poisson error ``sqrt(sum of counts) / K`` is reported next to
it (the quasi-random rig is usually more even than Poisson).

Only rays whose line passes within the disc's radius of its centre (and that point
towards it) can hit it; those are selected exactly before the Embree call (a KD-tree over
the rig's cap directions, :class:`RigRays`), which changes no count
(checked against casting every ray in ``tests/test_density_mc.py``) and makes a placement
cost a few milliseconds instead of a pass over all N*M rays.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import ParameterError
from ..geometry.raycast import RayCaster
from ..geometry.rig import cap_directions
from .density import gauss_legendre, rho, rho_at_points, rho_ring

__all__ = [
    "DiscPlacement",
    "MCResult",
    "RigRays",
    "centre_disc_expected_density",
    "count_disc_hits",
    "disc_expected_density",
    "disc_mesh",
    "finite_m_correction",
    "mc_density",
]


@dataclass(frozen=True)
class DiscPlacement:
    """Where a test disc sits: ``r`` in [0, 1) (unit frame), ``alpha`` in radians (normal vs outward radial)."""

    r: float
    alpha: float


@dataclass
class MCResult:
    """Monte-Carlo density of one face of one disc placement.

    Attributes:
        angle: cap half-angle of the rig, degrees. r, alpha: surfel of this face (the back
            face of a disc placed at ``alpha`` is reported as ``pi - alpha``), radians.
        side: "front" or "back". n_primary, n_secondary: N and M of the rig. n_rotations: K.
        disc_radius, area: the disc (polygon area, unit frame). hits: total over the K rotations.
        rho_mc: mean hits / (N*M * area), per unit N*M. se_mc: empirical standard error of
            rho_mc over the rotations. se_poisson: sqrt(hits) / (K N M area).
        rho_quad: continuum quadrature density averaged over the disc. correction: the rig's
            finite-M term (:func:`finite_m_correction`; at ``r = 0`` the exact rig value of
            :func:`centre_disc_expected_density` minus rho_quad). rho_expected = rho_quad + correction.
        rho_center: continuum density at the disc centre. z: (rho_mc - rho_expected) / se_mc.
        shells: cap steps spanned by the disc, ``M (eps_max - eps_min) / (1 - cos omega)`` with
            ``eps = sqrt(1 - r'^2)`` over the disc's points: the number of the rig's caustic shells
            ``r = sin t_k`` the disc averages over. The finite-M term is reliable for ``shells >= 3``
            (checked down to 3.3 in docs/analysis.md); below that the discreteness of the cap shows.
    """

    angle: float
    r: float
    alpha: float
    side: str
    n_primary: int
    n_secondary: int
    n_rotations: int
    disc_radius: float
    area: float
    hits: int
    rho_mc: float
    se_mc: float
    se_poisson: float
    rho_quad: float
    correction: float
    rho_expected: float
    rho_center: float
    z: float
    shells: float

    def to_dict(self) -> dict:
        """Plain-dict view (for CSV rows)."""
        return asdict(self)


def _disc_frame(r: float, alpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre ``(0, 0, r)``, normal ``(sin a, 0, cos a)`` and an orthonormal tangent pair (all (3,) float64)."""
    c = np.array([0.0, 0.0, r])
    n = np.array([np.sin(alpha), 0.0, np.cos(alpha)])
    t1 = np.array([np.cos(alpha), 0.0, -np.sin(alpha)])
    t2 = np.cross(n, t1)
    return c, n, t1, t2


def disc_mesh(r: float, alpha: float, radius: float, segments: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat disc (triangle fan) with centre on +z at distance ``r`` and normal at ``alpha`` from +z.

    Args:
        r: centre distance from the origin (unit frame). alpha: radians. radius: disc radius.
        segments: boundary vertices of the fan.
    Returns:
        vertices (segments+1, 3) float64 (vertex 0 = centre), faces (segments, 3) int64,
        normal (3,) float64 (the front side).
    """
    if segments < 3:
        raise ParameterError(f"a disc needs at least 3 segments, got {segments}")
    c, n, t1, t2 = _disc_frame(r, alpha)
    phi = 2.0 * np.pi * np.arange(segments) / segments
    ring = c + radius * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
    vertices = np.vstack([c, ring])
    k = np.arange(segments)
    faces = np.stack([np.zeros(segments, dtype=np.int64), 1 + k, 1 + (k + 1) % segments], axis=1)
    return vertices, faces, n


def _polygon_area(radius: float, segments: int) -> float:
    return 0.5 * segments * radius * radius * np.sin(2.0 * np.pi / segments)


def _disc_average(r: float, alpha: float, radius: float, segments: int, order: int, fn) -> tuple[float, float]:
    """Average of ``fn(points (..., 3), normals (..., 3)) -> (...)`` over the polygonal disc, both faces.

    Product rule on every (thin) fan triangle: ``order`` Gauss-Legendre nodes along the radius
    (weight including the Jacobian ``s``) x the angular midpoint. Against a 512-segment, 40-node
    reference, the disc average of ``rho`` is within 1e-4 relative for order 8 and 64 segments, and
    within 3e-4 where the disc straddles the kink of a cap's density at ``r = sin(omega)``.
    Returns ``(front, back)``.
    """
    vertices, faces, n = disc_mesh(r, alpha, radius, segments)
    zs, ws = gauss_legendre(order)
    s, wsn = 0.5 * (zs + 1.0), 0.5 * ws
    w, wwn = np.array([0.5]), np.array([1.0])
    c = vertices[0]
    v1 = vertices[faces[:, 1]]  # (S, 3)
    v2 = vertices[faces[:, 2]]
    # point = c + s ((1 - w) v1 + w v2 - c); dA = s |(v1 - c) x (v2 - c)| ds dw
    edge = (1.0 - w)[None, :, None] * v1[:, None, :] + w[None, :, None] * v2[:, None, :]  # (S, W, 3)
    pts = c + s[None, None, :, None] * (edge - c)[:, :, None, :]  # (S, W, O, 3)
    jac = np.linalg.norm(np.cross(v1 - c, v2 - c), axis=1)  # (S,) = 2 * triangle area
    weights = jac[:, None, None] * wwn[None, :, None] * (wsn * s)[None, None, :]
    area = weights.sum()
    normals = np.broadcast_to(n, pts.shape)
    vals = fn(np.stack([pts, pts]), np.stack([normals, -normals]))  # front and back in one call
    return float(np.sum(weights * vals[0]) / area), float(np.sum(weights * vals[1]) / area)


def _r_alpha(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.linalg.norm(points, axis=-1)
    cos_a = np.einsum("...k,...k->...", points, normals) / np.maximum(r, 1e-300)
    return r, np.arccos(np.clip(cos_a, -1.0, 1.0))


def disc_expected_density(
    r: float, alpha: float, radius: float, angle: float = 90.0, segments: int = 64, order: int = 8
) -> tuple[float, float]:
    """Quadrature density averaged over the polygonal disc, front and back face, per unit ``N*M``.

    Integrates :func:`~spotlights.analysis.density.rho_at_points` over the fan triangles
    (see :func:`_disc_average`) and divides by the polygon area.

    Returns:
        ``(front, back)``: mean density on the face the normal points to, and on the other face.
    """
    return _disc_average(r, alpha, radius, segments, order, lambda p, n: rho_at_points(p, n, angle=angle))


def finite_m_correction(
    r: float, alpha: float, radius: float, n_secondary: int, angle: float = 90.0, segments: int = 64, order: int = 8
) -> tuple[float, float]:
    """Leading finite-M term of a real rig's rotation-averaged density on the disc, per unit ``N*M``.

    The core's cap samples sit at ``c_k = cos t_k = 1 - (1 - cos omega) k / M``, k = 0..M-1 (sample 0
    is the central ray, aimed exactly at the centre). Averaged over rotations the density is
    ``(1/M) sum_k rho_ring(c_k)``; by Euler-Maclaurin this is the continuum ``rho`` plus
    ``(rho_ring(1) - rho_ring(cos omega)) / (2M)`` + O(1/(M^2 r^2)). ``rho_ring(1) = |cos alpha| / (4 pi r^2)``:
    the N central rays all pass through the centre, which a continuum of rays would not do.
    Valid when the disc spans many caustic shells ``r = sin t_k`` (``M r disc_radius >> 1``);
    it fails at the centre itself, where every bundle's central ray crosses.

    Returns: ``(front, back)`` disc averages of the correction.
    """
    cos_om = float(np.cos(np.radians(angle)))

    def fn(p, n):
        rr, aa = _r_alpha(p, n)
        return (rho_ring(rr, aa, 1.0) - rho_ring(rr, aa, cos_om)) / (2.0 * n_secondary)

    return _disc_average(r, alpha, radius, segments, order, fn)


def centre_disc_expected_density(radius: float, n_secondary: int, angle: float = 90.0) -> float:
    """Exact rotation-averaged density of a real rig on a disc centred on the sphere centre, per unit ``N*M``.

    A line at distance ``b`` from the centre with isotropic random orientation crosses a disc of
    radius ``a`` through the centre with probability ``P(b) = 1 - (2/pi) arcsin(b / a)`` (``b < a``).
    Cap sample ``k`` of a bundle passes at ``b_k = sin t_k`` from the centre (``cos t_k = 1 -
    (1 - cos omega) k / M``), so each face receives on average ``(N / 2) sum_k P(b_k)`` rays per
    rotation: the density is ``sum_k P(b_k) / (2 M pi a^2)``, whatever the disc's orientation. The
    ``k = 0`` term (every bundle's central ray crosses the centre) makes it exceed the continuum
    ``1 / (8 pi (1 - cos omega))`` by a large factor for small discs. Returns the mean over the
    circular disc (the 64-gon used in the Monte-Carlo differs by < 0.2 % in area).
    """
    omega = np.radians(angle)
    k = np.arange(int(n_secondary), dtype=np.float64)
    cos_t = 1.0 - (1.0 - np.cos(omega)) * k / n_secondary
    b = np.sqrt(np.clip(1.0 - cos_t * cos_t, 0.0, None))
    p = np.where(b < radius, 1.0 - (2.0 / np.pi) * np.arcsin(np.clip(b / radius, 0.0, 1.0)), 0.0)
    return float(p.sum() / (2.0 * n_secondary * np.pi * radius * radius))


def _cap_steps_spanned(vertices: np.ndarray, radius: float, n_secondary: int, angle: float) -> float:
    """``M (eps_max - eps_min) / (1 - cos omega)``, ``eps = sqrt(1 - |x|^2)`` over the disc (vertex 0 = centre)."""
    c = vertices[0]
    n = np.cross(vertices[1] - c, vertices[2] - c)
    n /= np.linalg.norm(n)
    foot = (c @ n) * n  # the origin projected onto the disc's plane
    off = foot - c
    if np.linalg.norm(off) > radius:
        foot = c + off * (radius / np.linalg.norm(off))
    r2 = np.concatenate([np.einsum("ij,ij->i", vertices, vertices), [foot @ foot]])
    eps = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    return float(n_secondary * (eps.max() - eps.min()) / (1.0 - np.cos(np.radians(angle))))


def _random_rotations(k: int, seed: int) -> np.ndarray:
    """(k, 3, 3) float64 uniformly random rotations (normalised Gaussian quaternions), reproducible."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((k, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )


class RigRays:
    """The rays of a rig indexed for repeated culling against small discs: built once, queried per disc.

    Uses the rig's documented layout (ray ``i*M + k`` = cap sample ``k`` expressed in viewpoint ``i``'s
    frame, see :mod:`spotlights.geometry.rig`): a KD-tree over the M cap directions answers, for every
    viewpoint at once, which of its rays point within a given angle of the disc, in O(N log M) instead
    of a pass over all N*M rays. The layout is verified on a sample of rays when the index is built;
    if it does not match, culling falls back to a vectorised test over every ray.

    Attributes: rig; primary (N, 3) float64; frames (N, 3, 3) float64 (rows u, v, w).
    """

    def __init__(self, rig):
        from scipy.spatial import cKDTree

        self.rig = rig
        self.primary = np.ascontiguousarray(rig.primary)
        self.frames = np.ascontiguousarray(rig.frames)
        local = cap_directions(rig.n_secondary, rig.angle)  # (M, 3) in (u, v, w) coordinates
        n, m = rig.n_primary, rig.n_secondary
        directions = rig.directions.reshape(n, m, 3)
        # verify the documented layout on a reproducible sample of rays (all of them for small rigs)
        idx = np.random.default_rng(0).choice(n * m, size=min(n * m, 20_000), replace=False)
        i, k = np.divmod(idx, m)
        rebuilt = np.einsum("sj,sjc->sc", local[k], self.frames[i])
        self._tree = cKDTree(local) if np.max(np.abs(rebuilt - directions[i, k])) < 1e-9 else None
        self._directions = directions
        self._omega = float(np.radians(rig.angle))

    def candidates(self, centre: np.ndarray, radius: float) -> np.ndarray:
        """Sorted flat indices ``i*M + k`` of every ray that passes within ``radius`` of ``centre``.

        Exact superset of the rays that can hit a disc of circumradius ``radius`` centred at
        ``centre`` (``|centre| + radius < 1``): a ray from ``o`` hits the ball iff the angle between
        its direction and ``centre - o`` is at most ``arcsin(radius / |centre - o|)``. A small
        relative margin (1e-9) keeps rays on the boundary; Embree decides those.
        """
        centre = np.asarray(centre, dtype=np.float64)
        w = centre - self.primary  # (N, 3)
        dist = np.linalg.norm(w, axis=1)
        if np.any(dist <= radius):
            raise ParameterError("the disc must lie strictly inside the unit sphere")
        m = self.rig.n_secondary
        if self._tree is None:  # brute force over all rays
            d = self._directions
            t0 = d @ centre - np.einsum("nmk,nk->nm", d, self.primary)
            dist2 = (dist * dist)[:, None] - t0 * t0
            return np.flatnonzero((dist2 <= radius * radius * (1.0 + 1e-6) + 1e-12) & (t0 > 0.0))
        unit_w = w / dist[:, None]
        half = np.arcsin(radius / dist)
        # only viewpoints whose cap can reach the ball: angle(axis, w) <= omega + half
        axis_cos = -np.einsum("nc,nc->n", self.primary, unit_w)
        sources = np.flatnonzero(np.arccos(np.clip(axis_cos, -1.0, 1.0)) <= self._omega + half + 1e-9)
        if len(sources) == 0:
            return np.zeros(0, dtype=np.int64)
        target = np.einsum("njc,nc->nj", self.frames[sources], unit_w[sources])  # unit target in (u, v, w)
        chord = 2.0 * np.sin(0.5 * half[sources]) * (1.0 + 1e-9) + 1e-12
        lists = self._tree.query_ball_point(target, chord)
        sizes = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
        total = int(sizes.sum())
        if total == 0:
            return np.zeros(0, dtype=np.int64)
        k = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=total)
        i = np.repeat(sources.astype(np.int64), sizes)
        return np.sort(i * m + k)


def count_disc_hits(
    rig, vertices: np.ndarray, faces: np.ndarray, normal: np.ndarray, cull: bool = True, rays: RigRays | None = None
) -> tuple[int, int]:
    """Cast every ray of ``rig`` at one disc with Embree and count first hits per face.

    Args:
        rig: a :class:`~spotlights.geometry.rig.Rig` (rays in the unit frame).
        vertices: (V, 3) float64 disc vertices, vertex 0 its centre (as :func:`disc_mesh`).
        faces: (F, 3) int64. normal: (3,) float64 front normal.
        cull: pre-select the rays whose line passes within the disc's circumradius of its
            centre, in front of the origin (exact: no other ray can hit); False casts all rays.
        rays: a :class:`RigRays` of ``rig`` to reuse across calls (built if None).
    Returns:
        ``(front_hits, back_hits)``: rays hitting against the normal / along it.
    """
    origins, directions = rig.origins, rig.directions
    if cull:
        if rays is None:
            rays = RigRays(rig)
        centre = vertices[0]
        radius = float(np.max(np.linalg.norm(vertices - centre, axis=1)))
        keep = rays.candidates(centre, radius)
        origins, directions = origins[keep], directions[keep]
    caster = RayCaster(vertices, faces)
    hit = np.isfinite(caster.distances(origins, directions))  # a plane disc: the side is sign(d . n)
    facing = directions[hit] @ normal
    return int(np.sum(facing < 0.0)), int(np.sum(facing > 0.0))


def mc_density(
    rig,
    placements,
    disc_radius: float = 0.08,
    n_rotations: int = 16,
    seed: int = 0,
    segments: int = 64,
    progress: bool = False,
) -> list[MCResult]:
    """Monte-Carlo ray density at several disc placements for one real rig.

    Args:
        rig: :class:`~spotlights.geometry.rig.Rig` (its ``angle`` is the cap used in the
            quadrature it is compared with).
        placements: iterable of :class:`DiscPlacement` or ``(r, alpha)`` pairs (alpha in radians).
            The whole disc must lie inside the sphere: ``sqrt(r^2 + disc_radius^2) < 1`` and
            ``r + disc_radius < 1`` when the disc is tilted.
        disc_radius: radius of the test disc (unit frame).
        n_rotations: K random rotations per placement (>= 2 for an error estimate).
        seed: seeds the rotations; same seed and arguments give identical results.
        progress: show a tqdm bar over the K x placements ray casts.
    Returns:
        Two :class:`MCResult` per placement (front face, then back face), in order.
    """
    placements = [p if isinstance(p, DiscPlacement) else DiscPlacement(float(p[0]), float(p[1])) for p in placements]
    _check_mc_arguments(placements, disc_radius, n_rotations, segments)
    from tqdm import tqdm

    rotations = _random_rotations(n_rotations * len(placements), seed).reshape(len(placements), n_rotations, 3, 3)
    area = _polygon_area(disc_radius, segments)
    rays = RigRays(rig)
    results: list[MCResult] = []
    bar = tqdm(
        total=len(placements) * n_rotations, desc=f"MC {rig.name}", unit="disc", disable=not progress, leave=False
    )
    for j, p in enumerate(placements):
        vertices, faces, normal = disc_mesh(p.r, p.alpha, disc_radius, segments)
        counts = np.zeros((n_rotations, 2), dtype=np.int64)
        for k in range(n_rotations):
            q = rotations[j, k]
            counts[k] = count_disc_hits(rig, vertices @ q.T, faces, q @ normal, rays=rays)
            bar.update(1)
        quad, corr = _expected_density(rig, p, disc_radius, segments)
        shells = _cap_steps_spanned(vertices, disc_radius, rig.n_secondary, rig.angle)
        results += _placement_results(rig, p, counts, quad, corr, area, disc_radius, shells)
    bar.close()
    return results


def _check_mc_arguments(placements: list[DiscPlacement], disc_radius: float, n_rotations: int, segments: int) -> None:
    """Raise ParameterError unless ``n_rotations >= 2``, ``0 < disc_radius < 1`` and every disc fits
    inside the unit sphere."""
    if n_rotations < 2:
        raise ParameterError("n_rotations must be >= 2 to estimate the statistical error")
    if not (0.0 < disc_radius < 1.0):
        raise ParameterError(f"disc radius must be in (0, 1), got {disc_radius}")
    for p in placements:
        far = np.max(np.linalg.norm(disc_mesh(p.r, p.alpha, disc_radius, segments)[0], axis=1))
        if p.r < 0 or far >= 1.0:
            raise ParameterError(f"disc at r={p.r:g} with radius {disc_radius:g} does not fit inside the unit sphere")


def _expected_density(rig, p: DiscPlacement, disc_radius: float, segments: int) -> tuple:
    """``(quad, corr)``: the quadrature's (front, back) disc densities per unit N*M and the rig's
    finite-M corrections (at the centre: the exact rig expectation minus the quadrature)."""
    quad = disc_expected_density(p.r, p.alpha, disc_radius, angle=rig.angle, segments=segments)
    if p.r == 0.0:  # the centre: exact rig expectation (the finite-M expansion does not apply)
        exact = centre_disc_expected_density(disc_radius, rig.n_secondary, angle=rig.angle)
        corr = (exact - quad[0], exact - quad[1])
    else:
        corr = finite_m_correction(p.r, p.alpha, disc_radius, rig.n_secondary, angle=rig.angle, segments=segments)
    return quad, corr


def _placement_results(
    rig, p: DiscPlacement, counts: np.ndarray, quad, corr, area: float, disc_radius: float, shells: float
) -> list[MCResult]:
    """The front and back :class:`MCResult` of one placement from its (K, 2) int64 hit ``counts``."""
    n_rotations = len(counts)
    nm = rig.n_rays
    results = []
    for col, side, alpha in ((0, "front", p.alpha), (1, "back", np.pi - p.alpha)):
        c = counts[:, col].astype(np.float64)
        scale = 1.0 / (nm * area)
        rho_mc = float(c.mean() * scale)
        se = float(c.std(ddof=1) / np.sqrt(n_rotations) * scale)
        se_p = float(np.sqrt(c.sum()) / n_rotations * scale)
        expect = quad[col] + corr[col]
        z = (rho_mc - expect) / se if se > 0 else (0.0 if rho_mc == expect else np.inf)
        results.append(
            MCResult(
                angle=float(rig.angle),
                r=float(p.r),
                alpha=float(alpha),
                side=side,
                n_primary=int(rig.n_primary),
                n_secondary=int(rig.n_secondary),
                n_rotations=int(n_rotations),
                disc_radius=float(disc_radius),
                area=float(area),
                hits=int(c.sum()),
                rho_mc=rho_mc,
                se_mc=se,
                se_poisson=se_p,
                rho_quad=float(quad[col]),
                correction=float(corr[col]),
                rho_expected=float(expect),
                rho_center=float(rho(p.r, alpha, angle=rig.angle)),
                z=float(z),
                shells=float(shells),
            )
        )
    return results
