"""A shape per track: one completion of a vehicle, placed in every frame through that frame's box.

With ``--fuse WINDOW`` every frame of a track is completed from its own fused window, so a parked car seen in 40
frames gets 40 slightly different shapes. With ``track_shape`` (``real complete --fuse all|past:K --track-shape``)
each track keeps **one shape** in its box frame (object frame: x forward, y left, z up, box centre, metres):

* **offline** (``fuse all``): the track's shape is the completion of its first completed frame, whose input is
  the whole track fused (``all``: every frame of the track, under the refined boxes with ``refine_boxes``); every
  other frame shows that shape, put in its scan frame through its own (refined) box. One completion per track.
* **causal** (``fuse past:K``): the shape is made at the track's first completed frame and made again at the
  first completed frame K or more positions after the one that made the shape in use, each time from that frame's
  ``past:K`` window (frames up to it, never a later one); the frames between show the shape in use. A frame's
  shape depends on its own and earlier frames only.

The frame that makes a shape is completed in its own (refined) box resized to the per-side median size of the
track's boxes (offline: all of them; causal: those up to it; :meth:`TrackShapes.maker_box`), so the shape has the
track's size rather than one noisy frame's; its result then shows the shape in its own box like the others.

A shape is kept in the frame of the track's box (not of a box turned around by the heading check: a shape made
with its heading turned is shown turned in every frame, ``flipped`` as in the frame that made it).

**Sizes.** A shape is one size, so the frames of a track whose boxes disagree in size are not given one shape:
:func:`size_groups` puts each frame, in time order, in the first group of the track whose reference size (the
median of its frames so far, per side) every side of the frame's box is within :data:`SIZE_TOLERANCE` (20%) of,
else in a new group; :func:`split_by_size` splits a track of several groups into one track per group (the first
keeps the track id, the others are ``ID-sizeN``), each fused, refined and shaped on its own and listed in
``tracks.json`` with ``size_group`` and ``split_from`` (the totals count ``n_size_splits``). The grouping is causal
(a frame's group depends on earlier frames only). Simulated detector noise of 5% a side leaves a frame outside
20% of a running median about once in a few hundred frames; a car and a bus never share a group.

:class:`TrackShapes` does this inside :class:`~spotlights.completion.fusion.TrackPlan` (``TrackPlan(...,
track_shape=True)``): the frame loop calls :meth:`TrackPlan.place_shapes` on each frame's
:class:`~spotlights.completion.results.SceneResult` after :func:`~spotlights.completion.frame.complete_scene`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..data.tracks import WindowPolicy
from ..errors import ParameterError
from ..geometry.boxes import Box
from ..metrics.consistency import fidelity
from .results import ObjectResult

LOG = logging.getLogger(__name__)

#: The largest relative difference of a box side (length, width or height) from its size group's reference (the
#: median of the group's frames so far) for the frame to join the group (:func:`size_groups`).
SIZE_TOLERANCE = 0.20

#: The shape modes by window kind: ``all`` gives one offline shape per track, ``past:K`` a causal one.
SHAPE_MODES = {"all": "offline", "past": "causal"}


def shape_mode(policy: WindowPolicy) -> str:
    """``"offline"`` for ``fuse all``, ``"causal"`` for ``fuse past:K``; a one-line :class:`ParameterError` naming
    ``track_shape`` and ``fuse`` for any other window (``none``: nothing fused; ``centered:K``: neither the whole
    track nor the past only)."""
    mode = SHAPE_MODES.get(policy.kind)
    if mode is None:
        raise ParameterError(
            f"`track_shape` needs `fuse` all (one shape per track) or past:K (a shape made again every K frames from "
            f"the past ones), not {policy}",
            "track_shape",
            "fuse",
        )
    return mode


def size_groups(sizes: np.ndarray, tolerance: float = SIZE_TOLERANCE) -> np.ndarray:
    """(n,) int64 size group of each of a track's boxes, in time order.

    sizes : (n, 3) float box sides (length, width, height), metres, in time order.
    tolerance : the largest relative difference of a side from a group's reference size.

    Frame ``t`` joins the first group (in the order they were made) whose reference size - the per-side median of
    the group's frames before ``t`` - every side of frame ``t`` is within ``tolerance`` of (``|s / ref - 1| <=
    tolerance``), else it starts a new group. Groups are numbered 0, 1, ... in the order they start; a frame's
    group depends on the frames up to it only."""
    s = np.asarray(sizes, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(tolerance) or tolerance < 0:
        raise ParameterError(f"`tolerance` must be a finite number >= 0, got {tolerance}", "tolerance")
    members: list[list[int]] = []
    out = np.zeros(len(s), np.int64)
    for t, size in enumerate(s):
        for g, rows in enumerate(members):
            ref = np.median(s[rows], axis=0)
            if np.all(np.abs(size / ref - 1.0) <= tolerance):
                rows.append(t)
                out[t] = g
                break
        else:
            members.append([t])
            out[t] = len(members) - 1
    return out


def split_by_size(tracks: dict, where: dict, tolerance: float = SIZE_TOLERANCE) -> tuple[dict, dict, int]:
    """Split the tracks of a :class:`~spotlights.completion.fusion.TrackPlan` whose boxes fall in several
    :func:`size_groups`: one track per group (same class of object as the plan's, its lists cut to the group's
    frames). Returns ``(tracks, where, n_split)``: the new {(sequence, track id): track} (the first group keeps
    its key, group ``g`` >= 1 is ``ID-size{g + 1}``, made unique), the new {frame key: {box index: (track,
    position)}} and the number of tracks split. Each track gets ``size_group`` (1-based) and ``split_from`` (the
    original id, or None)."""
    out: dict = {}
    n_split = 0
    for key, tr in tracks.items():
        groups = size_groups(np.array([f.box.size for f in tr.frames]), tolerance)
        tr.size_group, tr.split_from = 1, None
        if groups.max(initial=0) == 0:
            out[key] = tr
            continue
        n_split += 1
        for g in range(int(groups.max()) + 1):
            rows = np.flatnonzero(groups == g)
            tid = tr.track_id if g == 0 else f"{tr.track_id}-size{g + 1}"
            while g and ((tr.sequence, tid) in tracks or (tr.sequence, tid) in out):
                tid += "-"
            part = type(tr)(tr.sequence, tid)
            part.keys = [tr.keys[i] for i in rows]
            part.box_index = [tr.box_index[i] for i in rows]
            part.frames = [tr.frames[i] for i in rows]
            part.size_group, part.split_from = g + 1, tr.track_id
            out[(tr.sequence, tid)] = part
        LOG.info("track %s: boxes of %d sizes (beyond %g%%): split", tr.track_id, groups.max() + 1, 100 * tolerance)
    new_where: dict = {}
    for tr in out.values():
        for pos, (fkey, i) in enumerate(zip(tr.keys, tr.box_index)):
            new_where.setdefault(fkey, {})[i] = (tr, pos)
    # the frames' boxes in the order the plan listed them
    ordered = {k: {i: new_where[k][i] for i in where[k] if i in new_where.get(k, {})} for k in where}
    return out, ordered, n_split


@dataclass(frozen=True)
class Shape:
    """One track's shape: ``points`` (K, 3) float64 in the box frame of the track's box at ``position`` (object
    frame, metres), made at that position of the track; ``flipped``: made with the box turned around."""

    position: int
    points: np.ndarray
    flipped: bool


def place_shape(o: ObjectResult, box: Box, shape: Shape) -> None:
    """Show ``shape`` as the completion of the completed object ``o`` whose (refined) box is ``box`` (scan frame),
    in place: ``box`` and ``used_box`` (``box``, turned around when the shape was made so), ``completion`` (scan
    frame, metres), ``completion_unit`` (float32, its unit frame), ``partial_unit`` / ``seen_unit`` moved from the
    unit frame of the box ``o`` was completed in into that of the new used box, and ``fidelity`` of the shape to
    the object's input (unit frame)."""
    used = box.flipped() if shape.flipped else box
    before = o.used_box if o.used_box is not None else o.box
    for name in ("partial_unit", "seen_unit"):
        p = getattr(o, name)
        if p is not None:
            scan = before.normalization().from_unit(np.asarray(p, dtype=np.float64))
            setattr(o, name, used.normalization().to_unit(scan).astype(np.float32))
    comp = box.from_object(shape.points)
    o.completion = comp
    o.box, o.used_box, o.flipped = box, used, shape.flipped
    o.completion_unit = used.normalization().to_unit(comp).astype(np.float32)
    o.fidelity = None if o.partial_unit is None or not len(comp) else fidelity(o.partial_unit, o.completion_unit)
    o.fidelity_flipped = None


class TrackShapes:
    """The shapes of a plan's tracks (module docstring): {track key: [:class:`Shape`, ...]} in the order made.

    policy : the plan's window (``all``: offline, one shape; ``past:K``: causal, made again every K frames)."""

    def __init__(self, policy: WindowPolicy) -> None:
        self.mode = shape_mode(policy)
        self.refresh = policy.k if self.mode == "causal" else None
        self.shapes: dict[tuple, list[Shape]] = {}

    def shape_at(self, key: tuple, pos: int) -> Shape | None:
        """The shape frame ``pos`` of track ``key`` shows when it is not made there: the latest made at a position
        up to ``pos`` (None: none yet)."""
        made = [s for s in self.shapes.get(key, []) if s.position <= pos]
        return max(made, key=lambda s: s.position) if made else None

    def makes(self, key: tuple, pos: int) -> bool:
        """Whether a completed frame ``pos`` of track ``key`` makes the track's shape: no shape is made up to it,
        or (causal) the one in use was made ``refresh`` or more positions earlier, or it made one already."""
        prior = self.shape_at(key, pos)
        if prior is None or prior.position == pos:
            return True
        return self.refresh is not None and pos - prior.position >= self.refresh

    def maker_box(self, tr, pos: int) -> Box | None:
        """The box frame ``pos`` of track ``tr`` is completed in when it makes the track's shape: its own (refined)
        box with the per-side median size of the track's boxes (offline: all its frames; causal: those up to
        ``pos``), so that the one shape has the track's size, not one frame's; None when it does not make one."""
        if not self.makes((tr.sequence, tr.track_id), pos):
            return None
        frames = tr.frames if self.mode == "offline" else tr.frames[: pos + 1]
        return tr.boxes[pos].replace(size=np.median(np.array([f.box.size for f in frames]), axis=0))

    def apply(self, hits: dict, result) -> None:
        """For one frame's ``result`` (:class:`~spotlights.completion.results.SceneResult`) and its tracked boxes
        ``hits`` ({box index: (track, position)}): a completed box that makes its track's shape keeps its
        completion and records it (box frame of ``track.boxes[position]``), the others show the shape in use
        (:func:`place_shape` through ``track.boxes[position]``)."""
        for o in result.completed:
            hit = hits.get(o.index)
            if hit is None:
                continue
            tr, pos = hit
            key = (tr.sequence, tr.track_id)
            box = tr.boxes[pos]
            if self.makes(key, pos):
                prior = self.shape_at(key, pos)
                if prior is None or prior.position != pos:
                    made = Shape(pos, box.to_object(o.completion), bool(o.flipped))
                    self.shapes.setdefault(key, []).append(made)
                    self.shapes[key].sort(key=lambda s: s.position)
                    prior = made
                place_shape(o, box, prior)  # completed in the track's median size: shown in its own box
                continue
            shape = self.shape_at(key, pos)
            if shape is None:  # a frame that makes no shape comes after the one that made it: a bug otherwise
                raise RuntimeError(f"track {key}: no shape made before its frame {pos}")
            place_shape(o, box, shape)

    def needed(self, hits: dict, completed: set) -> bool:
        """Whether a frame whose completed box indices are ``completed`` makes some track's shape (``real complete
        --resume`` completes such a skipped frame again, in memory, for the frames after it)."""
        return any(self.makes((tr.sequence, tr.track_id), pos) for i, (tr, pos) in hits.items() if i in completed)

    def made_at(self, key: tuple) -> list[int]:
        """The positions of track ``key`` that made its shapes."""
        return [s.position for s in self.shapes.get(key, [])]


__all__ = [
    "SHAPE_MODES",
    "SIZE_TOLERANCE",
    "Shape",
    "TrackShapes",
    "place_shape",
    "shape_mode",
    "size_groups",
    "split_by_size",
]
