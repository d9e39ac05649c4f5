"""``spotlights dataset sequences``: simulated drive-past sequences with true and noisy boxes (generic format)."""

from __future__ import annotations

from ..data.lidar import SENSOR_PRESETS
from ..data.synthetic.sequences import HZ_RANGE, MAX_FRAMES, MAX_SEQUENCES, BoxNoise, SequenceSpec, simulate_sequences
from ._util import SEED_HELP, add_command, add_quiet, positive_int, seed_number


def register(dsub) -> None:
    """Add ``sequences`` to the ``dataset`` group ``dsub``."""
    p = add_command(
        dsub,
        "sequences",
        "simulate vehicles driving past the sensor at 10 Hz: scans, true boxes and detector-like noisy boxes, "
        "in the generic multi-frame format ('real complete --format generic --fuse ...' reads them)",
        "spotlights dataset sequences --meshes ../shared/data/meshes/apolloscape-cars/sedan --sequences 4 "
        "--frames 20 --out seqs",
        _sequences,
    )
    p.add_argument(
        "--meshes", required=True, metavar="PATH", help="a mesh file or a folder of them (z up, x forward, metres)"
    )
    p.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="DIR|FILE.h5",
        help="output folder (DIR/seqNNNN/ per sequence) or one HDF5 file (.h5: track ids, both boxes, sensor origins)",
    )
    p.add_argument(
        "--workers", type=positive_int, default=1, help="processes simulating (.h5 output; same bytes for any number)"
    )
    p.add_argument(
        "--sequences", type=positive_int, default=4, metavar="N", help=f"sequences, 1..{MAX_SEQUENCES} (default 4)"
    )
    p.add_argument(
        "--frames", type=positive_int, default=20, metavar="F", help=f"frames a sequence, 1..{MAX_FRAMES} (default 20)"
    )
    p.add_argument(
        "--hz", type=float, default=10.0, help=f"frame rate, {HZ_RANGE[0]:g}..{HZ_RANGE[1]:g} Hz (default 10)"
    )
    p.add_argument("--sensor", default="hdl64e", choices=tuple(SENSOR_PRESETS), help="LiDAR (default hdl64e)")
    p.add_argument(
        "--seed", type=seed_number, default=0, help=f"seed, {SEED_HELP} (default 0): the same seed, the same bytes"
    )
    g = p.add_argument_group("noisy boxes (independent per frame)")
    g.add_argument("--translation-sigma", type=float, default=0.10, metavar="M", help="per horizontal axis (0.10 m)")
    g.add_argument("--yaw-sigma", type=float, default=2.0, metavar="DEG", help="heading (2 degrees)")
    g.add_argument("--size-sigma", type=float, default=0.03, metavar="REL", help="relative, per dimension (0.03)")
    add_quiet(p)


def _sequences(args) -> int:
    spec = SequenceSpec(
        n_frames=args.frames,
        hz=args.hz,
        noise=BoxNoise(args.translation_sigma, args.yaw_sigma, args.size_sigma),
    )
    simulate_sequences(args.meshes, args.out, args.sequences, spec, args.seed, args.sensor, args.workers)
    if not args.quiet:
        print(f"{args.sequences} sequence(s) of {args.frames} frames -> {args.out}")
    return 0
