"""Scenes over time in a rerun recording (``.rrd``): ``real complete --rerun FILE.rrd`` (and ``complete SCENE --rerun``).

A completed frame (the scene's result, :func:`spotlights.completion.frame.complete_scene`) is logged at its
place on two timelines, ``frame`` (its position in the run, 0, 1, ...) and ``time`` (its timestamp, seconds, as a
duration from the run's first frame), so the rerun viewer scrubs through a sequence. Entities, per sequence
``SEQ`` (omitted for data without sequences), all in the frame's scan frame (metres):

* ``SEQ/scan``: every point of the scan (grey; the points of completed objects blue);
* ``SEQ/boxes/given``: every box of the frame as the data gives it (labelled with its track id or label);
* ``SEQ/boxes/used``: the box each completed object was completed in (refined with ``--refine-boxes``, turned
  when the heading check flipped it), green;
* ``SEQ/fused``: the other frames' points each object got from its track window (``--fuse``), orange;
* ``SEQ/completion``: every completion, red.

The recording is written to a temporary name and renamed when closed without error (nothing is left
behind otherwise). Needs the optional ``rerun-sdk`` package (``pip install 'spotlights[rerun]'``);
:func:`read_recording` reads a file back (entities and frame counts) for tests and checks.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from ..errors import OutputFileError, ParameterError
from ..geometry.sampling import voxel_downsample
from ..outputs import check_writable

GREY, BLUE, GREEN, ORANGE, RED, WHITE = (
    (150, 150, 150),
    (60, 120, 255),
    (40, 200, 80),
    (255, 150, 30),
    (230, 40, 40),
    (220, 220, 220),
)


def _rerun():
    # rerun-sdk's own log lines (a full disk: a WARN and an ERROR from its writer thread) would stand beside the
    # command's one-line error; its failures reach us as exceptions. A RUST_LOG the user set is kept.
    os.environ.setdefault("RUST_LOG", "off")
    try:
        import rerun as rr
    except ImportError:
        raise ParameterError(
            "`rerun` needs the rerun-sdk package: pip install 'spotlights[rerun]' (or pip install rerun-sdk)", "rerun"
        ) from None
    return rr


def check_rerun_path(path) -> Path:
    """``path`` as a Path, refused in one line when rerun-sdk is missing or the name does not end in ``.rrd``
    (call it before any work, so a bad option costs nothing)."""
    p = Path(path)
    if p.suffix.lower() != ".rrd":
        raise ParameterError(f"{p}: a rerun recording's name must end in .rrd")
    if not p.parent.exists() and str(p.parent) not in ("", "."):
        raise ParameterError(f"{p}: its folder {p.parent} does not exist")
    _rerun()
    check_writable(p)  # a folder named x.rrd, a read-only folder: refused before the work, naming the recording
    return p


def _boxes(rr, boxes, color, labels=None):
    from scipy.spatial.transform import Rotation

    if not boxes:
        return rr.Boxes3D(centers=np.zeros((0, 3)), half_sizes=np.zeros((0, 3)))
    quats = Rotation.from_matrix(np.stack([b.rotation for b in boxes])).as_quat()  # x, y, z, w
    return rr.Boxes3D(
        centers=np.stack([b.center for b in boxes]),
        half_sizes=np.stack([0.5 * np.asarray(b.size) for b in boxes]),
        quaternions=[rr.Quaternion(xyzw=q) for q in quats],
        colors=color,
        labels=labels,
    )


class SceneRecording:
    """A rerun recording of completed frames (see the module docstring); use as a context manager.

    path : the ``.rrd`` file (written as ``path``'s temporary sibling, renamed on a clean close).
    time_unit_s : seconds per unit of the timestamps given to :meth:`log_frame` (None: no ``time`` timeline).
    voxel : metres; completions and fused points are logged as the centroids of their occupied cells of this
        side (:func:`spotlights.geometry.sampling.voxel_downsample`; None: every point). 0.1 m keeps a car's
        shape and cuts nuScenes scene-0523's recording (40 frames, ``--fuse past:5``) from 150 to 90 MB (72 MB
        completions, 22 MB scans).
    application : the rerun application id.
    """

    def __init__(
        self, path, time_unit_s: float | None = 1.0, voxel: float | None = 0.1, application: str = "spotlights"
    ):
        rr = _rerun()
        self.rr = rr
        self.path = check_rerun_path(path)
        self.tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.part.rrd")
        self.rec = rr.RecordingStream(application, recording_id=self.path.stem)
        try:
            self.rec.save(str(self.tmp))
        except (RuntimeError, OSError) as exc:  # rerun's file sink could not create its file
            self._discard()
            raise OutputFileError(self.path, f"cannot write the recording ({_first_line(exc)})") from None
        self.n_frames = 0
        self.unit = time_unit_s
        self.voxel = voxel
        self.t0: float | None = None

    def log_frame(
        self, result, given_boxes, timestamp: float | None = None, sequence: str = "", extra_points=None
    ) -> None:
        """Log one completed frame.

        result : the frame's scene result (``points`` (N, 3) scan frame, ``objects`` with ``status``,
            ``index``, ``input_indices``, ``used_box`` and ``completion`` (K, 3) metres, scan frame).
        given_boxes : the frame's boxes as the data gives them (:class:`~spotlights.geometry.boxes.Box`).
        timestamp : the frame's time in the recording's ``time_unit_s`` (any origin), or None (only the ``frame``
            timeline).
        sequence : the sequence name (the entity paths' prefix), "" for none.
        extra_points : {box index: (k, 3) metres, scan frame} the fused points of other frames (``--fuse``).
        """
        rr, rec = self.rr, self.rec
        root = f"{sequence.strip('/')}/" if sequence else ""
        rec.set_time("frame", sequence=self.n_frames)
        if timestamp is not None and self.unit is not None:
            t = float(timestamp) * self.unit
            self.t0 = t if self.t0 is None else self.t0
            rec.set_time("time", duration=t - self.t0)
        pts = np.asarray(result.points, dtype=np.float32).reshape(-1, 3)
        done = [o for o in result.objects if o.status == "completed"]
        colors = np.tile(np.array(GREY, np.uint8), (len(pts), 1))
        for o in done:
            colors[np.asarray(o.input_indices, dtype=np.int64)] = BLUE
        rec.log(f"{root}scan", rr.Points3D(pts, colors=colors, radii=0.03))
        labels = [b.track_id or b.label or str(i) for i, b in enumerate(given_boxes)]
        rec.log(f"{root}boxes/given", _boxes(rr, list(given_boxes), WHITE, labels))
        rec.log(
            f"{root}boxes/used",
            _boxes(rr, [o.used_box for o in done], GREEN, [labels[o.index] for o in done] if done else None),
        )
        fused = [np.asarray(v, dtype=np.float32).reshape(-1, 3) for v in (extra_points or {}).values()]
        fused_pts = self._thin(np.concatenate(fused) if fused else np.zeros((0, 3), np.float32))
        rec.log(f"{root}fused", rr.Points3D(fused_pts, colors=ORANGE, radii=0.03))
        comps = [self._thin(np.asarray(o.completion, dtype=np.float32).reshape(-1, 3)) for o in done]
        comp = np.concatenate(comps) if comps else np.zeros((0, 3), np.float32)
        rec.log(f"{root}completion", rr.Points3D(comp, colors=RED, radii=0.02))
        self.n_frames += 1

    def _thin(self, pts: np.ndarray) -> np.ndarray:
        return pts if self.voxel is None or len(pts) == 0 else voxel_downsample(pts, self.voxel)

    def close(self, ok: bool = True) -> None:
        """Finish the file: renamed to ``path`` when ``ok``, removed otherwise. A recording that could not be
        written whole (a full disk: rerun's writer thread stops; the name taken by a folder meanwhile) is removed
        and, when ``ok``, an :class:`~spotlights.errors.OutputFileError` naming ``path`` (one line)."""
        try:
            self.rec.flush()
            self.rec.disconnect()
            if ok:
                if self.path.is_dir():
                    raise IsADirectoryError(21, "is a folder, expected a file name")
                os.replace(self.tmp, self.path)
        except (RuntimeError, OSError) as exc:
            self._discard()
            if ok:
                raise OutputFileError(self.path, f"the recording could not be written ({_first_line(exc)})") from None
            return
        if not ok:
            self._discard()

    def _discard(self) -> None:
        """Stop writing and remove the temporary file, whatever state rerun's writer is in."""
        with contextlib.suppress(Exception):
            self.rec.disconnect()
        with contextlib.suppress(OSError):
            self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> SceneRecording:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(ok=exc_type is None)


def _first_line(exc: BaseException) -> str:
    """An exception's first line (rerun's errors say "Failed to create file: ... (os error 20), path: ...")."""
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:160]


def open_recording(path, time_unit_s: float | None = 1.0):
    """A :class:`SceneRecording` at ``path``, or a context that gives None when ``path`` is None (the CLI's
    pass-through: ``with open_recording(args.rerun, unit) as rec``)."""
    import contextlib

    return contextlib.nullcontext() if path is None else SceneRecording(path, time_unit_s)


def read_recording(path) -> dict:
    """What a ``.rrd`` file holds: {"entities": {path: rows logged on the ``frame`` timeline},
    "frames": sorted distinct ``frame`` values, "timelines": sorted names} (reads it back with rerun-sdk)."""
    _rerun()
    from rerun.chunk import RrdReader

    entities: dict[str, int] = {}
    frames: set[int] = set()
    timelines: set[str] = set()
    for chunk in RrdReader(str(path)).stream():
        if chunk.is_static:
            continue
        timelines.update(chunk.timeline_names)
        if "frame" not in chunk.timeline_names:
            continue
        entities[chunk.entity_path] = entities.get(chunk.entity_path, 0) + chunk.num_rows
        frames.update(int(v) for v in chunk.to_record_batch().column("frame").to_pylist())
    return {"entities": entities, "frames": sorted(frames), "timelines": sorted(timelines)}


__all__ = ["SceneRecording", "check_rerun_path", "open_recording", "read_recording"]
