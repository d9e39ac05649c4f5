"""``spotlights track``: a detector's boxes -> tracks (the generic sequence format, and a nuScenes tracking JSON)."""

from __future__ import annotations

from ..data.real.base import CLASSES as FILTER_CLASSES
from ..errors import ParameterError
from ..tracking.detections import FORMATS, MAX_BOXES_PER_FRAME, MAX_FRAMES, filter_detections, read_detections
from ..tracking.outputs import write_nuscenes_tracking, write_tracks
from ..tracking.tracker import METRICS, TrackerConfig, track_boxes
from ..utils import check_distinct_paths, check_suffix, check_writable
from ._util import add_command, add_quiet, positive_int, unit_interval


def register(sub) -> None:
    p = add_command(
        sub,
        "track",
        "track a detector's 3-D boxes over time (a Kalman filter per track, GIoU matching per class): "
        "writes the boxes with track ids in the generic sequence format, and optionally a nuScenes tracking JSON. "
        f"Caps: {MAX_FRAMES} frames, {MAX_BOXES_PER_FRAME} boxes a frame",
        "spotlights track results_nusc.json --format nuscenes --data ../shared/data/lidar/nuscenes "
        "--out tracks.json --nuscenes-out tracking_result.json --min-score 0.1",
        _track,
    )
    p.add_argument(
        "detections",
        metavar="DETECTIONS",
        help="nuscenes: a detection result JSON; kitti: a folder of per-frame result files (16 fields, score last) "
        "or one file with a frame column (KITTI tracking layout); generic: a sequence JSON, a folder of box files "
        "or one box file (boxes with an optional 'score')",
    )
    p.add_argument("--format", required=True, choices=FORMATS, help="the detections' format")
    p.add_argument(
        "--data",
        metavar="DIR",
        default=None,
        help="nuscenes (required): the nuScenes folder of the samples (poses, times, frames); "
        "kitti: a KITTI folder whose calib/ is used when --calib is not given",
    )
    p.add_argument(
        "--calib",
        metavar="FILE|DIR",
        default=None,
        help="kitti: the calibration file, or a folder of them (FRAME.txt per frame, SEQUENCE.txt per tracking file)",
    )
    p.add_argument(
        "--logit-scores", action="store_true", help="kitti: the score column holds logits (PointRCNN): a sigmoid first"
    )
    p.add_argument("--out", "-o", required=True, metavar="JSON", help="tracks in the generic sequence format (.json)")
    p.add_argument("--nuscenes-out", metavar="JSON", default=None, help="also a nuScenes tracking result JSON")
    p.add_argument(
        "--min-score",
        type=unit_interval,
        default=0.0,
        metavar="S",
        help="drop detections scoring below S, in [0, 1] (default 0: keep all)",
    )
    p.add_argument(
        "--all-classes",
        action="store_true",
        help="track every class (default: the vehicle classes car, truck, caravan, trailer, bus, construction, "
        "emergency; pedestrians, cyclists and cones are dropped)",
    )
    d = TrackerConfig()
    g = p.add_argument_group("tracker")
    g.add_argument("--metric", choices=METRICS, default=d.metric, help=f"association (default {d.metric})")
    g.add_argument(
        "--min-hits", type=positive_int, default=d.min_hits, metavar="N", help=f"hits to confirm a track, 1..1000 "
        f"(default {d.min_hits})"
    )  # fmt: skip
    g.add_argument(
        "--max-misses", type=positive_int, default=d.max_misses, metavar="M",
        help=f"frames in a row without a match that end a track, 1..1000 (default {d.max_misses})",
    )  # fmt: skip
    g.add_argument(
        "--birth-score", type=unit_interval, default=d.birth_score, metavar="S",
        help=f"least score of a detection that starts a track (default {d.birth_score})",
    )  # fmt: skip
    g.add_argument(
        "--confirm-score", type=unit_interval, default=d.confirm_score, metavar="S",
        help=f"a detection scoring at least S confirms its track at once (default {d.confirm_score}; 1: only --min-hits)",
    )  # fmt: skip
    add_quiet(p, "no summary line")


def _track(args) -> int:
    check_suffix(args.out, (".json",), "the tracks file", "--out")
    check_suffix(args.nuscenes_out, (".json",), "the nuScenes tracking file", "--nuscenes-out")
    check_distinct_paths(
        [("DETECTIONS", args.detections)], [("--out", args.out), ("--nuscenes-out", args.nuscenes_out)]
    )
    if args.format == "nuscenes" and args.data is None:
        raise ParameterError("--data: nuScenes detections are read beside their nuScenes folder; name it")
    if args.format != "kitti" and (args.calib is not None or args.logit_scores):
        raise ParameterError("--calib and --logit-scores apply to --format kitti only")
    if args.format == "generic" and args.data is not None:
        raise ParameterError("--data applies to --format nuscenes and kitti only")
    if args.format == "kitti" and args.calib is None and args.data is None:
        raise ParameterError("--calib: KITTI detections are in the camera frame; name their calibration (or --data)")
    for v, flag in ((args.min_hits, "--min-hits"), (args.max_misses, "--max-misses")):
        if v > 1000:
            raise ParameterError(f"{flag}: at most 1000, got {v}")
    check_writable(args.out, args.nuscenes_out)
    config = TrackerConfig(
        metric=args.metric,
        min_hits=args.min_hits,
        max_misses=args.max_misses,
        birth_score=args.birth_score,
        confirm_score=args.confirm_score,
    )
    frames = read_detections(args.detections, args.format, args.data, args.calib, args.logit_scores)
    frames, counts = filter_detections(frames, args.min_score, None if args.all_classes else FILTER_CLASSES)
    tracked = track_boxes(frames, config)
    write_tracks(tracked, args.out)
    if args.nuscenes_out:
        write_nuscenes_tracking(tracked, args.nuscenes_out)
    if not args.quiet:
        ids = {(f.sequence, b.track_id) for f in tracked for b in f.boxes}
        dropped = counts["low_score"] + counts["other_class"]
        print(
            f"{len(frames)} frame(s), {counts['kept']} detection(s) tracked ({dropped} dropped: "
            f"{counts['low_score']} below --min-score, {counts['other_class']} of other classes), "
            f"{len(ids)} track(s) -> {args.out}" + (f", {args.nuscenes_out}" if args.nuscenes_out else "")
        )
    return 0
