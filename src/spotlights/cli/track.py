"""``spotlights track``: a detector's boxes -> tracks (the generic sequence format, and a nuScenes tracking JSON)."""

from __future__ import annotations

from ..tracking.command import TrackSettings, run_track
from ..tracking.detections import MAX_BOXES_PER_FRAME, MAX_FRAMES
from ._util import add_command, add_options, settings_of


def register(sub) -> None:
    p = add_command(
        sub,
        "track",
        "track a detector's 3-D boxes over time (a Kalman filter per track, GIoU matching per class) and write them "
        f"with track ids; caps: {MAX_FRAMES} frames, {MAX_BOXES_PER_FRAME} boxes a frame",
        "spotlights track results_nusc.json --format nuscenes --data ../shared/data/lidar/nuscenes "
        "--out tracks.json --nuscenes-out tracking_result.json --min-score 0.1",
        _track,
    )
    add_options(p, TrackSettings)


def _track(args) -> int:
    r = run_track(settings_of(TrackSettings, args))
    if not args.quiet:
        print(
            f"{r['frames']} frame(s), {r['kept']} detection(s) tracked ({r['low_score']} below --min-score and "
            f"{r['other_class']} of other classes dropped), {r['tracks']} track(s) -> {args.out}"
        )
    return 0
