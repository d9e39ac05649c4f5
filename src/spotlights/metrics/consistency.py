"""Consistency of completions across frames (PCN's metric; the paper's Table 2), fidelity, MMD, the noise floor.

numpy + pykdtree only.

With no ground truth on real scans, a completion model is scored by how much
its completions of the *same object* in *consecutive frames* agree. For two
point sets A (earlier frame) and B (later frame), with unsquared Euclidean
nearest-neighbour distances ``d(a, B) = min_b ||a - b||_2``:

- ``d_ab``  = mean over a in A of d(a, B)   (one-sided, earlier -> later)
- ``d_ba``  = mean over b in B of d(b, A)   (one-sided, later -> earlier)
- ``cd``    = d_ab + d_ba  **(headline)**: exactly the paper's Eq. (1), the
  two-sided Chamfer distance with unsquared (L2-norm) distances, the same
  definition PCN uses for its consistency metric.
- ``cd_half`` = (d_ab + d_ba) / 2: the same quantity halved (the "CD-L1" that
  many completion codebases print).
- ``cd_l2`` = mean of d(a, B)^2 + mean of d(b, A)^2: the squared-distance Chamfer.

Frames: every completion is predicted in the unit frame of its own box. Both
are mapped to the object frame in metres (``p = q * R_i``, R_i = half the
diagonal of that observation's box; box frames are the object frames, so no
other transform is needed) and then divided by the track's mean radius
``R_track`` (mean of R_i over the track's observations). Headline numbers are
in this track-normalised unit frame (equal to comparing unit-frame completions
directly when a track's box size is constant, as for KITTI-360's static
objects); the metre values are reported too (suffix ``_m``).

Aggregation: a track's consecutive observations (ordered by timestamp; frames
where the object was skipped are not counted, so "consecutive" means
consecutive among its observations) form pairs; a track's value is the mean
over its pairs; a class's value the mean over its tracks; ``average`` is the
mean over the classes that have at least one track (the paper's "Average"
column is the mean of its four class columns); ``all_objects`` is the mean
over every track regardless of class.

Consistency alone rewards a model that ignores its input (the same shape for
every scan scores 0), so two per-observation scores of PCN's real-data
evaluation are reported beside it, aggregated the same way (observation ->
mean per track -> per class -> average):

- ``fidelity``: one-sided, mean over the *observed* points (the partial input,
  duplicates from resampling removed) of the unsquared distance to the nearest
  point of the completion, in the observation's unit frame (box half-diagonal
  units; ``fidelity_m`` in metres). How much of what the LiDAR saw the
  completion keeps; a collapsed model scores badly.
- ``mmd`` (minimal matching distance, optional): the headline Chamfer (``cd``,
  two-sided, unsquared, sum of the two means) between the completion and the
  *nearest* shape of a reference set of complete cars (unit frame: the
  synthetic dataset's ground-truth points, normalised like the observation).
  Whether the completion looks like some car.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from ..geometry.distances import chamfer_distance, combine_directions, nearest_distances, reduce_points
from ..geometry.neighbors import NearestNeighbors

METRICS = ("cd", "cd_half", "d_ab", "d_ba", "cd_l2")
METRIC_DOC = {
    "cd": "d_ab + d_ba: two-sided Chamfer distance of the paper's Eq. (1), unsquared Euclidean NN distances (headline)",
    "cd_half": "(d_ab + d_ba) / 2: the same, halved",
    "d_ab": "one-sided: mean over the earlier completion's points of the distance to the nearest point of the later one",
    "d_ba": "one-sided: mean over the later completion's points of the distance to the nearest point of the earlier one",
    "cd_l2": "mean squared NN distance earlier->later + later->earlier (squared-distance Chamfer)",
}


DIVERSITY_DOC = (
    "mean two-sided unsquared Chamfer (d_ab + d_ba) between the completions of different tracked objects "
    "(each object's earliest observation, unit frames), over all pairs of objects; ~0 = the same shape for "
    "every input. consistency_over_diversity = all_objects cd / diversity"
)
OBSERVATION_METRIC_DOC = {
    "fidelity": "one-sided: mean over the observed (partial input) points of the unsquared distance to the nearest "
    "completion point, unit frame of the observation (box half-diagonal units); lower = keeps the input",
    "mmd": "minimal matching distance: min over the reference cars of the two-sided unsquared Chamfer (d_ab + d_ba) "
    "between the completion and the reference car, unit frame; lower = closer to some complete car",
}


def nn_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a),) float64 Euclidean distance from each point of ``a`` (K, 3) to its nearest point of ``b`` (L, 3),
    computed in float64 (:func:`spotlights.geometry.distances.nearest_distances`); ValueError when either is empty."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 3)
    if len(a) == 0 or len(b) == 0:
        raise ValueError("nearest-neighbour distances need two non-empty point sets")
    return nearest_distances(a, b)


def chamfer(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """All Chamfer variants of :data:`METRICS` between point sets ``a`` (K, 3) and ``b`` (L, 3), same frame and units.

    Each is one setting of :func:`spotlights.geometry.distances.chamfer_distance` (float64), from one
    pair of nearest-neighbour queries. ValueError when either set is empty.
    """
    dab = nn_distances(a, b)
    dba = nn_distances(b, a)
    m_ab, m_ba = reduce_points(dab), reduce_points(dba)
    return {
        "cd": combine_directions(m_ab, m_ba, "sum"),
        "cd_half": combine_directions(m_ab, m_ba, "mean"),
        "d_ab": m_ab,
        "d_ba": m_ba,
        "cd_l2": combine_directions(reduce_points(dab * dab), reduce_points(dba * dba), "sum"),
    }


def fidelity(partial: np.ndarray, completion: np.ndarray) -> float:
    """PCN's fidelity: mean over the distinct points of ``partial`` (P, 3) of the distance to the nearest point of
    ``completion`` (K, 3); unsquared, one-sided, same frame and units as the inputs. NaN when K = 0."""
    p = np.unique(np.asarray(partial, dtype=np.float64).reshape(-1, 3), axis=0)
    c = np.asarray(completion, dtype=np.float64).reshape(-1, 3)
    if len(c) == 0 or len(p) == 0:
        return float("nan")
    return chamfer_distance(p, NearestNeighbors(c, few_queries=len(p) * 8 < len(c)), single_directional=True)


def minimal_matching_distance(completion: np.ndarray, references) -> tuple[float, int]:
    """Smallest two-sided Chamfer ``cd`` (unsquared, sum of the two means) between ``completion`` (K, 3)
    and any of ``references`` (R arrays (L_r, 3), or prebuilt
    :class:`~spotlights.geometry.neighbors.NearestNeighbors`, same frame); returns (distance, index of the nearest
    reference). (NaN, -1) when the completion is empty.

    The exact minimum is found with a lower bound: ``d(c, ref)`` >= the one-sided mean from the
    completion alone, so references are visited in increasing order of that bound and the search
    stops when the bound exceeds the best distance so far.
    """
    c = np.asarray(completion, dtype=np.float64).reshape(-1, 3)
    if len(c) == 0:
        return float("nan"), -1
    trees = [
        r if isinstance(r, NearestNeighbors) else NearestNeighbors(np.asarray(r, dtype=np.float64)) for r in references
    ]
    if not trees:
        raise ValueError("the minimal matching distance needs at least one reference shape")
    lower = np.array([chamfer_distance(c, t, single_directional=True) for t in trees])  # one side of each Chamfer
    best, arg = float("inf"), -1
    ctree = NearestNeighbors(c)
    for r in np.argsort(lower, kind="stable"):
        if lower[r] >= best:
            break
        cd = combine_directions(lower[r], chamfer_distance(trees[r], ctree, single_directional=True), "sum")
        if cd < best:
            best, arg = float(cd), int(r)
    return best, arg


def diversity(completions, object_keys, timestamps) -> tuple[float, int]:
    """How much completions of *different* objects differ: the mean two-sided Chamfer ``cd``
    (unsquared, sum of the two one-sided means) over all pairs of distinct objects, each object
    represented by its earliest non-empty completion, in the unit frames as given.

    ``completions``: n arrays (K_i, 3); ``object_keys``: n hashables; ``timestamps``: (n,) numbers (ints or floats, compared as given).
    Returns (mean, number of objects); (NaN, count) with fewer than two objects. A model that
    outputs one template whatever its input has diversity ~0 and a trivially perfect
    consistency; ``all_objects cd / diversity`` compares how much a completion moves for the
    same object with how much it moves between objects.
    """
    ts = np.asarray(timestamps)
    first: dict = {}
    for i, k in enumerate(object_keys):
        if len(completions[i]) == 0:
            continue
        if k not in first or (ts[i], i) < (ts[first[k]], first[k]):
            first[k] = i
    rows = sorted(first.values())
    if len(rows) < 2:
        return float("nan"), len(rows)
    vals = [chamfer(completions[a], completions[b])["cd"] for n, a in enumerate(rows) for b in rows[n + 1 :]]
    return float(np.mean(vals)), len(rows)


def same_observation_cd(a_list, b_list, scale) -> np.ndarray:
    """The resampling noise floor: (n,) two-sided Chamfer ``cd`` between a_i and b_i (two completions of the same
    observation, unit frame) times ``scale[i]``; NaN when one is empty."""
    out = np.full(len(a_list), np.nan)
    for i, (a, b) in enumerate(zip(a_list, b_list)):
        if len(a) and len(b):
            out[i] = chamfer(a, b)["cd"] * float(scale[i])
    return out


def consecutive_pairs(object_keys, timestamps) -> list[tuple[int, int]]:
    """Pairs (i, j) of rows that are consecutive observations of the same object.

    ``object_keys`` (n hashables: e.g. (sequence, track_id)) and ``timestamps``
    (n numbers, ints or floats: 0.25 and 0.5 stay apart). Rows of an object are ordered by (timestamp, row); objects seen
    once give no pair. Pairs are returned sorted by (first row's object order, time).
    """
    groups: dict = defaultdict(list)
    for i, k in enumerate(object_keys):
        groups[k].append(i)
    ts = np.asarray(timestamps)
    pairs: list[tuple[int, int]] = []
    for k in sorted(groups, key=lambda k: groups[k][0]):
        rows = sorted(groups[k], key=lambda i: (ts[i], i))
        pairs.extend(zip(rows[:-1], rows[1:]))
    return pairs


@dataclass
class TrackResult:
    """Consistency of one tracked object: means over its consecutive pairs."""

    key: tuple
    cls: str
    n_observations: int
    n_pairs: int
    n_pairs_empty: int
    values: dict  # metric -> mean (track-normalised unit frame), metric + "_m" -> metres


def track_consistency(
    completions, object_keys, timestamps, classes, radii, per_observation: dict | None = None
) -> list[TrackResult]:
    """Per-track consistency.

    Parameters
    ----------
    completions : n arrays (K_i, 3), unit frame of observation i (K_i may differ, may be 0).
    object_keys : n hashables identifying the object (tracks with one row are ignored).
    timestamps : (n,) numbers (ints or floats, never cut) ordering the observations of a track.
    classes : n class names (a track's class is that of its first observation).
    radii : (n,) float, R_i = half the box diagonal of observation i, metres.

    per_observation : optional {name: (n,) float} per-observation scores (e.g. ``fidelity``,
        ``mmd``); each track gets the mean over its observations (NaN ones left out).

    Pairs with an empty completion are not scored and counted in ``n_pairs_empty``;
    a track whose every pair is empty is returned with NaN values.
    """
    per_observation = {k: np.asarray(v, dtype=np.float64) for k, v in (per_observation or {}).items()}
    radii = np.asarray(radii, dtype=np.float64)
    pairs = consecutive_pairs(object_keys, timestamps)
    by_track: dict = defaultdict(list)
    for i, j in pairs:
        by_track[object_keys[i]].append((i, j))
    members: dict = defaultdict(list)
    for i, k in enumerate(object_keys):
        members[k].append(i)
    out = []
    for key, plist in by_track.items():
        rows = members[key]
        r_track = float(np.mean(radii[rows]))
        vals = defaultdict(list)
        empty = 0
        for i, j in plist:
            a = np.asarray(completions[i], dtype=np.float64).reshape(-1, 3)
            b = np.asarray(completions[j], dtype=np.float64).reshape(-1, 3)
            if len(a) == 0 or len(b) == 0:
                empty += 1
                continue
            c = chamfer(a * radii[i], b * radii[j])  # object frame, metres
            for m in METRICS:
                scale = r_track * r_track if m == "cd_l2" else r_track
                vals[m].append(c[m] / scale)
                vals[m + "_m"].append(c[m])
        values = {
            m: (float(np.mean(vals[m])) if vals[m] else float("nan")) for m in [*METRICS, *(x + "_m" for x in METRICS)]
        }
        for name, v in per_observation.items():
            finite = v[rows][np.isfinite(v[rows])]
            values[name] = float(finite.mean()) if finite.size else float("nan")
        out.append(TrackResult(key, str(classes[rows[0]]), len(rows), len(plist), empty, values))
    return out


def aggregate(tracks: list[TrackResult], classes=None) -> dict:
    """Class means, their mean (``average``) and the mean over all tracks (``all_objects``).

    Returns ``{"classes": {cls: {"n_objects", "n_pairs", metric...}}, "average": {...},
    "all_objects": {...}}``; tracks with NaN values (every pair empty) are left out
    of the means and counted in ``n_objects_unscored``. Per-observation scores
    (``fidelity``, ``mmd``) are averaged over the same scored tracks, leaving out a
    track whose every observation had an empty completion (NaN); a class without any
    such value is None for that key and left out of its ``average``.
    """
    keys = [*METRICS, *(x + "_m" for x in METRICS)]
    keys += sorted({k for t in tracks for k in t.values} - set(keys))  # per-observation scores
    names = list(classes) if classes is not None else sorted({t.cls for t in tracks})
    res: dict = {"classes": {}}
    class_means = []
    for c in names:
        entry, n_scored = _class_entry([t for t in tracks if t.cls == c], keys)
        res["classes"][c] = entry
        if n_scored:
            class_means.append(entry)
    res["average"] = {"n_classes": len(class_means)}
    for k in keys:
        res["average"][k] = _mean([np.nan if e[k] is None else e[k] for e in class_means])
    scored = [t for t in tracks if np.isfinite(t.values["cd"])]
    res["all_objects"] = {"n_objects": len(scored), "n_pairs": sum(t.n_pairs - t.n_pairs_empty for t in tracks)}
    for k in keys:
        res["all_objects"][k] = _mean([t.values.get(k, np.nan) for t in scored])
    return res


def _class_entry(ts: list[TrackResult], keys: list[str]) -> tuple[dict, int]:
    """One class's entry of :func:`aggregate` (counts, then the mean of every key over its scored
    tracks) and how many of its tracks were scored."""
    scored = [t for t in ts if np.isfinite(t.values["cd"])]
    entry: dict[str, float | None] = {
        "n_objects": len(scored),
        "n_objects_unscored": len(ts) - len(scored),
        "n_pairs": sum(t.n_pairs - t.n_pairs_empty for t in ts),
    }
    for k in keys:
        entry[k] = _mean([t.values.get(k, np.nan) for t in scored])
    return entry, len(scored)


def _mean(values) -> float | None:
    """Mean of the finite values, None when there is none."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None
