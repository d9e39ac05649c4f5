"""``spotlights dataset``: build, inspect, export and render the synthetic completion dataset."""

from __future__ import annotations

from dataclasses import dataclass

from ..data.dataset_report import dataset_info, export_sample, info_lines, read_sample
from ..data.synthetic import BuildRequest, add_rig, build_from_request, build_summary
from ..data.synthetic.consolidate import merge_shards
from ..data.synthetic.request import read_request_yaml
from ..options import option
from ..outputs import check_writable
from ..viz import html, render_sample
from ._util import (
    add_command,
    add_group,
    add_options,
    add_quiet,
    check_picture,
    check_suffix,
    settings_of,
    unit_interval,
)
from .sequences import register as register_sequences
from .view import add_html_argument, write_page

SPLITS = ("train", "val", "test")
DATASET_FILE_HELP = "dataset file (.h5)"


@dataclass(kw_only=True)
class AddRigOptions:
    """The own options of ``spotlights dataset add-rig`` (then ``--workers``, ``-q`` and the backend's of
    :class:`~spotlights.data.synthetic.BuildRequest`)."""

    file: str = option("file", metavar="FILE", help="dataset file (.h5) to extend in place")
    rig: str = option(
        metavar="RIG",
        help="NxM[@DEG] or a rig name (cap-32x64-60, box-32x64-ellipsoid-s1, box-32x64-volume-s0.9, ...)",
    )
    meshes: list[str] | None = option(
        default=None,
        metavar="DIR",
        action="append",
        help="the meshes folder the dataset was built from (default: the one its config records); "
        "repeat once per source, in the build's order, for a multi-source dataset",
    )


@dataclass(kw_only=True)
class MergeOptions:
    """The options of ``spotlights dataset merge`` (then ``-q``)."""

    file: str = option("file", metavar="INDEX", help="the shard index (.json) of a sharded dataset")
    out: str = option("--out", "-o", metavar="FILE", help="the single dataset file to write (.h5)")
    overwrite: bool = option(default=False, action="store_true", help="replace an existing FILE")


@dataclass(kw_only=True)
class InfoOptions:
    """The options of ``spotlights dataset info``."""

    file: str = option("file", metavar="FILE", help=DATASET_FILE_HELP)
    json: bool = option(default=False, action="store_true", help="machine-readable output")


@dataclass(kw_only=True)
class DatasetExportOptions:
    """The options of ``spotlights dataset export``."""

    file: str = option("file", metavar="FILE", help=DATASET_FILE_HELP)
    split: str = option(choices=SPLITS, help="split of the sample")
    index: int = option(type=int, help="sample index within the split")
    out: str = option(
        "--out",
        "-o",
        metavar="SAMPLE.npz",
        help="output .npz: partial, gt_points, gt_dense, gt_depths and the sample's metadata",
    )
    rig: str | None = option(default=None, help="rig of gt_depths (default: the dataset's default rig)")


@dataclass(kw_only=True)
class DatasetShowOptions:
    """The own options of ``spotlights dataset show`` (then ``--html``)."""

    file: str = option("file", metavar="FILE", help=DATASET_FILE_HELP)
    split: str = option(default="test", choices=SPLITS, help="split of the sample (default test)")
    index: int = option(default=0, type=int, help="sample index within the split (default 0)")
    out: str | None = option(
        "--out",
        "-o",
        default=None,
        metavar="PNG",
        help="output picture (default: ./SPLIT-INDEX.png; with --html alone, no picture)",
    )
    rig: str | None = option(default=None, help="rig whose points are drawn (default: the default rig)")
    clip: float | None = option(default=None, type=unit_interval, metavar="T", help="depths below T count as misses")


def register(sub) -> None:
    dsub = add_group(
        sub,
        "dataset",
        "synthetic LiDAR completion dataset (paper Section 5.1): build, add-rig, info, export, show, merge",
        "spotlights dataset build --meshes ../shared/data/meshes/apolloscape-cars --out cars.h5",
    )

    b = add_command(
        dsub,
        "build",
        "simulate LiDAR scans of every mesh of a folder and write the dataset (resumable)",
        "spotlights dataset build --meshes ../shared/data/meshes/apolloscape-cars --out cars.h5 "
        "--views 2000 --split 64/8/7 --rig 64x32@60 --rig 256x64@60",
        _build,
    )
    add_options(b, BuildRequest)
    b.set_defaults(config_reader=read_request_yaml, command_parser=b)

    register_sequences(dsub)

    a = add_command(
        dsub,
        "add-rig",
        "add one more rig's ground-truth depths to an existing dataset file (no rebuild; atomic)",
        "spotlights dataset add-rig cars.h5 --rig box-32x64-ellipsoid-s1",
        _add_rig,
    )
    add_options(a, AddRigOptions)
    add_options(a, BuildRequest, only=("workers",), grouped=False)
    add_quiet(a)
    add_options(a, BuildRequest, only=("backend", "ray_address", "task_retries"), grouped=False)

    mg = add_command(
        dsub,
        "merge",
        "turn a sharded dataset (its index) into one HDF5 file (the same bytes as an unsharded build)",
        "spotlights dataset merge cars.json --out cars.h5",
        _merge,
    )
    add_options(mg, MergeOptions)
    add_quiet(mg)

    i = add_command(
        dsub,
        "info",
        "print a dataset's splits, categories, counts and array shapes",
        "spotlights dataset info cars.h5 --json",
        _info,
    )
    add_options(i, InfoOptions)

    e = add_command(
        dsub,
        "export",
        "write one sample (partial scan + ground truth) to an .npz",
        "spotlights dataset export cars.h5 --split test --index 0 --out sample.npz",
        _export,
    )
    add_options(e, DatasetExportOptions)

    s = add_command(
        dsub,
        "show",
        "render a sample: partial (purple), ground truth (grey), Spotlights points (green)",
        "spotlights dataset show cars.h5 --split test --index 0 --out sample.png",
        _show,
    )
    add_options(s, DatasetShowOptions)
    add_html_argument(s)


def _merge(args) -> int:
    check_suffix(args.out, (".h5", ".hdf5"), "the merged dataset (HDF5)")
    rep = merge_shards(args.file, args.out, progress=not args.quiet, overwrite=args.overwrite)
    print(
        f"{args.out}: {rep['n_models']} models, {rep['n_samples']} samples from {rep['n_shards']} shards, "
        f"{rep['file_size'] / 2**20:.1f} MiB"
    )
    return 0


def _build(args) -> int:
    # SIGTERM unwinds like Ctrl-C (spotlights.cli.main): the workers stop, finished units are kept
    if args.shard_size:
        check_suffix(args.out, (".json",), "the shard index of a sharded dataset (--shard-size)")
    else:
        check_suffix(args.out, (".h5", ".hdf5"), "the dataset (HDF5)")
    check_writable(args.out)
    report = build_from_request(settings_of(BuildRequest, args))
    print("\n".join(build_summary(report, args.out)))
    return 0


def _add_rig(args) -> int:

    # SIGTERM unwinds like Ctrl-C (spotlights.cli.main): the file is left untouched
    rep = add_rig(
        args.file,
        args.rig,
        meshes=args.meshes,
        workers=args.workers,
        progress=not args.quiet,
        backend=args.backend,
        ray_address=args.ray_address,
        retries=args.task_retries,
    )
    if rep.already_present:
        print(f"{args.file}: already holds rig {rep.rig}; nothing to do")
        return 0
    print(
        f"{args.file}: added rig {rep.rig} ({rep.n_models} models x {rep.n_rays} rays, hit ratio {rep.hit_ratio:.3f}); "
        f"depths {rep.seconds_depths:.1f} s, file written in {rep.seconds_write:.1f} s, {rep.file_size / 2**20:.1f} MiB"
    )
    return 0


def _info(args) -> int:
    import json

    info = dataset_info(args.file)
    print(json.dumps(info, indent=1) if args.json else "\n".join(info_lines(info)))
    return 0


def _export(args) -> int:
    i, s = export_sample(args.file, args.split, args.index, args.out, args.rig)
    print(f"{args.file}: {args.split}[{args.index}] = sample {i} ({s['model']}, view {s['view']}) -> {args.out}")
    return 0


def _show(args) -> int:
    from pathlib import Path

    check_picture(args.out)
    check_suffix(args.html, (".html", ".htm"), "the page (HTML)", "--html")
    out = Path(args.out) if args.out else Path.cwd() / f"{args.split}-{args.index}.png"
    check_writable(args.out or (None if args.html else out), args.html)
    i, s, rig = read_sample(args.file, args.split, args.index, args.rig)
    what = f"{args.file}: {args.split}[{args.index}] = sample {i} ({s['model']}, view {s['view']})"
    if args.html:
        write_page(
            args.html,
            [("sample", html.sample_traces(s, rig, clip=args.clip))],
            f"{s['model']} ({s['category']}, {s['split']}), view {s['view']}, unit frame",
            quiet=True,
        )
        print(f"{what} -> {args.html}")
        if not args.out:
            return 0
    render_sample(out, s, rig, clip=args.clip)
    print(f"{what} -> {out}")
    return 0
