"""``spotlights dataset``: build, inspect, export and render the synthetic completion dataset."""

from __future__ import annotations

from ..data.dataset_report import dataset_info, export_sample, info_lines, read_sample
from ..data.synthetic import BuildRequest, add_rig, build_from_request, build_summary
from ..data.synthetic.consolidate import merge_shards
from ..utils import check_writable
from ..viz import html, render_sample
from ._util import (
    add_command,
    add_group,
    add_quiet,
    check_picture,
    check_suffix,
    non_negative_int,
    positive_int,
    settings_of,
    unit_interval,
)
from .sequences import register as register_sequences
from .view import add_html_argument, write_page


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
    b.add_argument(
        "--meshes",
        default=[],
        metavar="DIR[,KEY=VALUE...]",
        action="append",
        help="folder of meshes; categories = first sub-folder, or DIR/manifest.csv (file,category[,up,forward,"
        "split,scale]). Repeat for several sources (model names get the folder's name as prefix); "
        "per source: manifest=CSV, up=, forward=, scale=, split=A/B/C or train|val|test, name=",
    )
    b.add_argument(
        "--out", "-o", required=True, metavar="FILE", help="dataset file to write (.h5); work folder FILE.parts"
    )
    b.add_argument(
        "--manifest", default=None, metavar="CSV", help="manifest CSV (default: DIR/manifest.csv if present)"
    )
    b.add_argument("--views", type=positive_int, default=2000, help="partial observations per model (default 2000)")
    b.add_argument(
        "--split",
        default="0.81/0.1/0.09",
        metavar="A/B/C",
        help="train/val/test: model counts (64/8/7) or fractions (0.8/0.1/0.1); default 0.81/0.1/0.09 "
        "(= the paper's 64/8/7 for 79 models)",
    )
    b.add_argument("--no-stratify", action="store_true", help="split over all models instead of per category")
    b.add_argument("--seed", type=non_negative_int, default=0, help="root seed (default 0)")
    b.add_argument(
        "--workers",
        "-j",
        type=positive_int,
        default=None,
        help="processes (default: all cores); never changes the result",
    )
    b.add_argument(
        "--rig",
        action="append",
        default=[],
        metavar="RIG",
        help="extra Spotlights rig for the ground truth, repeatable: NxM[@DEG] cap rigs (e.g. --rig 64x32@60 "
        "--rig 256x64@60) or rig names, e.g. box-32x64-ellipsoid-s1 (box-targeted: each model's own box)",
    )
    b.add_argument("--default-rig", default="32x64@60", metavar="RIG", help="the main rig (default 32x64@60)")
    b.add_argument("--points", type=int, default=256, help="points per partial observation (default 256)")
    b.add_argument("--gt-points", type=int, default=2048, help="uniform ground-truth points (default 2048)")
    b.add_argument("--gt-dense", type=int, default=16384, help="dense ground-truth points (default 16384)")
    b.add_argument(
        "--downsample",
        choices=("random", "fps"),
        default="random",
        help="how scans with more points are reduced: random subset (default) or farthest-point sampling",
    )
    b.add_argument("--up", default="z", help="the mesh files' up axis (glTF: y; default z)")
    b.add_argument("--forward", default="x", help="the mesh files' forward axis (default x)")
    b.add_argument(
        "--scale", type=float, default=1.0, help="multiply mesh coordinates by this to get metres (default 1)"
    )
    g = b.add_argument_group("LiDAR (default: Velodyne HDL-64E as in KITTI)")
    g.add_argument("--sensor", default="hdl64e", help="preset: hdl64e (default), hdl32e, vlp16")
    g.add_argument("--azimuth-step", type=float, default=None, metavar="DEG", help="horizontal step (hdl64e: 0.17)")
    g.add_argument(
        "--mount-height",
        default=None,
        metavar="M|MIN:MAX",
        help="sensor height above ground (hdl64e: 1.73); MIN:MAX draws each view's height uniformly "
        "(e.g. 1.5:2.1, from low roof mounts to tall SUVs and robotaxis)",
    )
    g.add_argument("--range-noise", type=float, default=None, metavar="M", help="range noise sigma (hdl64e: 0.02)")
    g.add_argument(
        "--dropout", type=float, default=None, metavar="P", help="probability that a return is lost (default 0)"
    )
    g.add_argument(
        "--beam-dropout",
        type=float,
        default=None,
        metavar="P",
        help="probability that a whole beam is dead during a scan (default 0)",
    )
    g.add_argument("--max-range", type=float, default=None, metavar="M", help="range limit (hdl64e: 120)")
    g.add_argument(
        "--distance", default="4:40", metavar="MIN:MAX", help="vehicle distance range in metres (default 4:40)"
    )
    g.add_argument(
        "--min-points", type=int, default=50, help="fewer returns than this and the pose is redrawn (default 50)"
    )
    pg = b.add_argument_group("procedural vehicles (every class a real frame holds; docs/dataset.md)")
    pg.add_argument(
        "--procedural",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="add N generated vehicles per class of --classes (models procedural/CLASS/BODY-IIII; with or "
        "without --meshes); stores every model's detector class",
    )
    pg.add_argument(
        "--classes",
        default=None,
        metavar="LIST",
        help="classes of --procedural (the real readers' names): car (sedan, hatchback, SUV, pickup), van "
        "(stored as caravan), truck (box truck, semi-tractor, pickup), bus, trailer (box, flatbed); default all",
    )
    pg.add_argument(
        "--procedural-split",
        default=None,
        metavar="A/B/C|SPLIT",
        help="split of the procedural vehicles alone (counts, fractions or train|val|test); default: "
        "pooled with the sources without split= and dealt by --split",
    )
    sp = b.add_argument_group("splits by category")
    sp.add_argument(
        "--category-split",
        action="append",
        default=[],
        metavar="CAT=SPLIT",
        help="every model of category CAT goes to SPLIT (held-out body types, e.g. suv=test); the rest "
        "are split by --split; repeatable",
    )
    sp.add_argument(
        "--exclude-category",
        action="append",
        default=[],
        metavar="CAT",
        help="leave the models of category CAT out; repeatable",
    )
    au = b.add_argument_group(
        "augmentation (augmented copies of the meshes become extra models, in their mesh's split)"
    )
    au.add_argument("--mirror", action="store_true", help="add a copy mirrored across the car's x-z plane (y -> -y)")
    au.add_argument(
        "--scale-copies",
        type=non_negative_int,
        default=0,
        metavar="K",
        help="add K anisotropically scaled copies per mesh (with --mirror, each mirrored too)",
    )
    au.add_argument("--length-range", default=None, metavar="MIN:MAX", help="box length of scaled copies, m (2.6:5.8)")
    au.add_argument("--width-range", default=None, metavar="MIN:MAX", help="box width (mirrors included), m (1.5:2.45)")
    au.add_argument("--height-range", default=None, metavar="MIN:MAX", help="box height, m (1.3:2.0)")
    au.add_argument("--scale-factor-range", default=None, metavar="MIN:MAX", help="per-axis factor (0.7:1.3)")
    au.add_argument(
        "--augment-splits",
        default="train",
        metavar="SPLITS",
        help="splits whose meshes get copies, comma-separated (default train: val/test stay real meshes)",
    )
    r = b.add_argument_group("run")
    r.add_argument("--overwrite", action="store_true", help="replace an existing FILE and discard unfinished parts")
    r.add_argument(
        "--resume", action="store_true", help="accept an existing complete FILE (unfinished parts resume anyway)"
    )
    r.add_argument(
        "--block", type=positive_int, default=None, help="views per work unit (default ~views/8, at most 250)"
    )
    r.add_argument("--keep-parts", action="store_true", help="keep FILE.parts after writing FILE")
    add_quiet(r, "no progress bars")
    _add_backend_options(r)
    r.add_argument(
        "--shard-size",
        type=positive_int,
        default=None,
        metavar="N",
        help="write shards of at most N samples (whole models) plus an index: give --out NAME.json; "
        "every reader takes the index like a file; 'dataset merge' makes one file of them",
    )

    register_sequences(dsub)

    a = add_command(
        dsub,
        "add-rig",
        "add one more rig's ground-truth depths to an existing dataset file (no rebuild; atomic)",
        "spotlights dataset add-rig cars.h5 --rig box-32x64-ellipsoid-s1",
        _add_rig,
    )
    a.add_argument("file", metavar="FILE", help="dataset file (.h5) to extend in place")
    a.add_argument(
        "--rig",
        required=True,
        metavar="RIG",
        help="NxM[@DEG] or a rig name (cap-32x64-60, box-32x64-ellipsoid-s1, box-32x64-volume-s0.9, ...)",
    )
    a.add_argument(
        "--meshes",
        default=None,
        metavar="DIR",
        action="append",
        help="the meshes folder the dataset was built from (default: the one its config records); "
        "repeat once per source, in the build's order, for a multi-source dataset",
    )
    a.add_argument(
        "--workers",
        "-j",
        type=positive_int,
        default=None,
        help="processes (default: all cores); never changes the result",
    )
    add_quiet(a)
    _add_backend_options(a)

    mg = add_command(
        dsub,
        "merge",
        "turn a sharded dataset (its index) into one HDF5 file (the same bytes as an unsharded build)",
        "spotlights dataset merge cars.json --out cars.h5",
        _merge,
    )
    mg.add_argument("file", metavar="INDEX", help="the shard index (.json) of a sharded dataset")
    mg.add_argument("--out", "-o", required=True, metavar="FILE", help="the single dataset file to write (.h5)")
    mg.add_argument("--overwrite", action="store_true", help="replace an existing FILE")
    add_quiet(mg)

    i = add_command(
        dsub,
        "info",
        "print a dataset's splits, categories, counts and array shapes",
        "spotlights dataset info cars.h5 --json",
        _info,
    )
    i.add_argument("file", metavar="FILE", help="dataset file (.h5)")
    i.add_argument("--json", action="store_true", help="machine-readable output")

    e = add_command(
        dsub,
        "export",
        "write one sample (partial scan + ground truth) to an .npz",
        "spotlights dataset export cars.h5 --split test --index 0 --out sample.npz",
        _export,
    )
    e.add_argument("file", metavar="FILE", help="dataset file (.h5)")
    e.add_argument("--split", required=True, choices=("train", "val", "test"), help="split of the sample")
    e.add_argument("--index", type=int, required=True, help="sample index within the split")
    e.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="SAMPLE.npz",
        help="output .npz: partial, gt_points, gt_dense, gt_depths and the sample's metadata",
    )
    e.add_argument("--rig", default=None, help="rig of gt_depths (default: the dataset's default rig)")

    s = add_command(
        dsub,
        "show",
        "render a sample: partial (purple), ground truth (grey), Spotlights points (green)",
        "spotlights dataset show cars.h5 --split test --index 0 --out sample.png",
        _show,
    )
    s.add_argument("file", metavar="FILE", help="dataset file (.h5)")
    s.add_argument(
        "--split", default="test", choices=("train", "val", "test"), help="split of the sample (default test)"
    )
    s.add_argument("--index", type=int, default=0, help="sample index within the split (default 0)")
    s.add_argument(
        "--out",
        "-o",
        default=None,
        metavar="PNG",
        help="output picture (default: ./SPLIT-INDEX.png; with --html alone, no picture)",
    )
    s.add_argument("--rig", default=None, help="rig whose points are drawn (default: the default rig)")
    s.add_argument("--clip", type=unit_interval, default=None, metavar="T", help="depths below T count as misses")
    add_html_argument(s)


def _add_backend_options(group) -> None:
    group.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="local: a process pool on this machine (default); ray: tasks on a Ray cluster (pip install "
        "'spotlights[distributed]'); the bytes are the same",
    )
    group.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="with --backend ray: 'auto' joins the running cluster (ray start), HOST:PORT a given one; "
        "default: start a local instance with --workers CPUs",
    )
    group.add_argument(
        "--task-retries",
        type=non_negative_int,
        default=2,
        metavar="N",
        help="with --backend ray: retries of a task that crashes or loses its node (default 2); bad input "
        "stops at once",
    )


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
