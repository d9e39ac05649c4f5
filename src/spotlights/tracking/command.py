"""``spotlights track`` as a library call: :class:`TrackSettings` (each field declares its option) and
:func:`run_track` (read, filter, track, write)."""

from __future__ import annotations

from dataclasses import dataclass

from ..data.real.base import CLASSES
from ..errors import ParameterError
from ..options import non_negative_float, option, positive_int, unit_interval
from ..outputs import check_distinct_paths, check_suffix, check_writable
from .detections import FORMATS, filter_detections, read_detections
from .outputs import write_nuscenes_tracking, write_tracks
from .tracker import METRICS, TrackerConfig, track_boxes

_D = TrackerConfig()


@dataclass
class TrackSettings:
    """What ``spotlights track`` is asked to do (its options; ``detections`` is the command's positional)."""

    detections: str = option(
        "detections",
        metavar="DETECTIONS",
        help="nuscenes: a detection result JSON; kitti: a folder of per-frame result files (16 fields, score last) "
        "or one file with a frame column (tracking layout); generic: a sequence JSON, a folder of box files or one "
        "box file (boxes with an optional 'score')",
    )
    format: str = option(choices=FORMATS, help="the detections' format")
    out: str = option("--out", "-o", metavar="JSON", help="tracks in the generic sequence format (.json)")
    data: str | None = option(
        default=None,
        metavar="DIR",
        help="nuscenes (required): the nuScenes folder of the samples (frames, times, poses); "
        "kitti: a KITTI folder whose calib/ is used when --calib is not given",
    )
    calib: str | None = option(
        default=None,
        metavar="FILE|DIR",
        help="kitti: the calibration file, or a folder of them (FRAME.txt per frame, SEQUENCE.txt per tracking file)",
    )
    logit_scores: bool = option(
        default=False, action="store_true", help="kitti: the score column holds logits (PointRCNN): a sigmoid first"
    )
    nuscenes_out: str | None = option(default=None, metavar="JSON", help="also a nuScenes tracking result JSON")
    min_score: float = option(
        default=0.0, type=unit_interval, metavar="S", help="drop detections scoring below S (default 0: keep all)"
    )
    all_classes: bool = option(
        default=False,
        action="store_true",
        help=f"track every class (default: the vehicle classes {', '.join(CLASSES)}; pedestrians, cyclists, cones "
        "are dropped)",
    )
    metric: str = option(default=_D.metric, choices=METRICS, group="tracker", help=f"association ({_D.metric})")
    min_hits: int = option(
        default=_D.min_hits, type=positive_int, metavar="N", group="tracker", help=f"hits that confirm a track, "
        f"1..1000 (default {_D.min_hits})",
    )  # fmt: skip
    max_misses: int = option(
        default=_D.max_misses, type=positive_int, metavar="M", group="tracker",
        help=f"frames in a row without a match that end a track, 1..1000 (default {_D.max_misses})",
    )  # fmt: skip
    birth_score: float = option(
        default=_D.birth_score, type=unit_interval, metavar="S", group="tracker",
        help=f"least score of a detection that starts a track (default {_D.birth_score})",
    )  # fmt: skip
    confirm_score: float = option(
        default=_D.confirm_score, type=unit_interval, metavar="S", group="tracker",
        help=f"a detection scoring S or more confirms its track at once (default {_D.confirm_score}; 1: --min-hits)",
    )  # fmt: skip
    detection_velocity_sigma: float = option(
        default=_D.detection_velocity_sigma, type=non_negative_float, metavar="MPS", group="tracker",
        help="a detection's reported velocity (a nuScenes result's 'velocity') starts its new track and corrects the "
        f"track it matches, give or take MPS m/s (default {_D.detection_velocity_sigma}; 0: reported velocities are "
        "not used)",
    )  # fmt: skip
    quiet: bool = option("--quiet", "-q", default=False, action="store_true", quiet=True, help="nothing on stdout")


def run_track(s: TrackSettings) -> dict:
    """Read ``s.detections``, keep those scoring ``s.min_score`` or more (of the vehicle classes unless
    ``s.all_classes``), track them and write ``s.out`` (and ``s.nuscenes_out``), each atomically; every check on
    the options is made before anything is read. Returns ``{"frames", "kept", "low_score", "other_class",
    "tracks"}``. Errors are one line naming the option (:class:`ParameterError`) or the file."""
    check_suffix(s.out, (".json",), "the tracks file", "out")
    check_suffix(s.nuscenes_out, (".json",), "the nuScenes tracking file", "nuscenes_out")
    check_distinct_paths([("DETECTIONS", s.detections)], [("--out", s.out), ("--nuscenes-out", s.nuscenes_out)])
    if s.format == "nuscenes" and s.data is None:
        raise ParameterError("`data`: nuScenes detections are read beside their nuScenes folder; name it", "data")
    if s.format != "kitti" and (s.calib is not None or s.logit_scores):
        raise ParameterError(
            "`calib` and `logit_scores` apply to `format` kitti only", "calib", "logit_scores", "format"
        )
    if s.format == "generic" and s.data is not None:
        raise ParameterError("`data` applies to `format` nuscenes and kitti only", "data", "format")
    if s.format == "kitti" and s.calib is None and s.data is None:
        raise ParameterError(
            "`calib`: KITTI detections are in the camera frame; name their calibration (or `data`)", "calib", "data"
        )
    for value, name in ((s.min_hits, "min_hits"), (s.max_misses, "max_misses")):
        if not 1 <= value <= 1000:
            raise ParameterError(f"`{name}`: a whole number in 1..1000, got {value}", name)
    check_writable(s.out, s.nuscenes_out)
    config = TrackerConfig(
        metric=s.metric,
        min_hits=s.min_hits,
        max_misses=s.max_misses,
        birth_score=s.birth_score,
        confirm_score=s.confirm_score,
        detection_velocity_sigma=s.detection_velocity_sigma,
    )
    frames = read_detections(s.detections, s.format, s.data, s.calib, s.logit_scores)
    frames, counts = filter_detections(frames, s.min_score, None if s.all_classes else CLASSES)
    tracked = track_boxes(frames, config)
    write_tracks(tracked, s.out)
    if s.nuscenes_out:
        write_nuscenes_tracking(tracked, s.nuscenes_out)
    tracks = len({(f.sequence, b.track_id) for f in tracked for b in f.boxes})
    return {"frames": len(frames), **counts, "tracks": tracks}
