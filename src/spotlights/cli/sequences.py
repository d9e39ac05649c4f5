"""``spotlights dataset sequences``: simulated drive-past sequences with true and noisy boxes (generic format)."""

from __future__ import annotations

from dataclasses import dataclass

from ..data.lidar import SENSOR_PRESETS
from ..data.synthetic.sequences import HZ_RANGE, MAX_FRAMES, MAX_SEQUENCES, BoxNoise, SequenceSpec, simulate_sequences
from ..options import option
from ._util import SEED_HELP, add_command, add_options, add_quiet, positive_int, seed_number

NOISE_GROUP = "noisy boxes (independent per frame)"


@dataclass(kw_only=True)
class SequencesOptions:
    """The options of ``spotlights dataset sequences`` (then ``-q``)."""

    meshes: str = option(metavar="PATH", help="a mesh file or a folder of them (z up, x forward, metres)")
    out: str = option(
        "--out",
        "-o",
        metavar="DIR|FILE.h5",
        help="output folder (DIR/seqNNNN/ per sequence) or one HDF5 file (.h5: track ids, both boxes, sensor origins)",
    )
    workers: int = option(
        default=1, type=positive_int, help="processes simulating (.h5 output; same bytes for any number)"
    )
    sequences: int = option(
        default=4, type=positive_int, metavar="N", help=f"sequences, 1..{MAX_SEQUENCES} (default 4)"
    )
    frames: int = option(
        default=20, type=positive_int, metavar="F", help=f"frames a sequence, 1..{MAX_FRAMES} (default 20)"
    )
    hz: float = option(default=10.0, type=float, help=f"frame rate, {HZ_RANGE[0]:g}..{HZ_RANGE[1]:g} Hz (default 10)")
    sensor: str = option(default="hdl64e", choices=tuple(SENSOR_PRESETS), help="LiDAR (default hdl64e)")
    seed: int = option(
        default=0, type=seed_number, help=f"seed, {SEED_HELP} (default 0): the same seed, the same bytes"
    )
    translation_sigma: float = option(
        default=0.10, type=float, metavar="M", group=NOISE_GROUP, help="per horizontal axis (0.10 m)"
    )
    yaw_sigma: float = option(default=2.0, type=float, metavar="DEG", group=NOISE_GROUP, help="heading (2 degrees)")
    size_sigma: float = option(
        default=0.03, type=float, metavar="REL", group=NOISE_GROUP, help="relative, per dimension (0.03)"
    )


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
    add_options(p, SequencesOptions)
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
