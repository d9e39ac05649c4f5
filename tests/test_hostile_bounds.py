"""Hostile sizes: counts, steps, seeds and learning rates without an upper bound
ran for ever, died of memory in a worker or failed deep in torch. Each is now one line with exit code 2, naming
the option (or config key) and its range, before any output is written or a worker starts; ``--up -z`` is read as
the axis -z instead of an unknown option."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.options import MAX_BATCH, MAX_CROP_M, MAX_SEED, check_seed, join_axis_values

from helpers import CARS, assert_user_error, run_cli, write_box_scan

BIG_SEED = str(10**23)


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """A scan (.npy) of a car-sized box at x = 10 m and its box file: {root, scan, box}."""
    root = tmp_path_factory.mktemp("bounds41")
    return write_box_scan(root)


def _nothing_in(folder):
    assert sorted(p.name for p in folder.iterdir()) == [], sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------- dataset build


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "option, value, bound",
    [
        ("--views", "1000000000", "1..100000"),
        ("--gt-dense", "2000000000", "1..1048576"),
        ("--gt-points", "2000000000", "1..1048576"),
        ("--points", "2000000000", "1..65536"),
        ("--azimuth-step", "1e-6", "[0.01, 90]"),
    ],
)
def test_dataset_build_sizes_are_bounded_before_any_work(tmp_path, option, value, bound):
    out = tmp_path / "out"
    out.mkdir()
    proc = run_cli(
        "dataset", "build", "--procedural", "1", "--classes", "car", "-j", "1", "-q", "-o", out / "d.h5", option, value
    )
    assert_user_error(proc, bound)
    assert option in proc.stderr or option.lstrip("-").replace("-", " ") in proc.stderr, proc.stderr
    _nothing_in(out)  # neither d.h5 nor d.h5.parts


@pytest.mark.timeout(30)
def test_a_work_unit_of_views_times_points_is_bounded(tmp_path):
    """--block 100000 --points 65536 asked a worker for 78 GB of partial points (each bound alone held); 256 views
    of 65,536 points (2**24) is the most a unit takes."""
    from spotlights.data.synthetic.runner import MAX_UNIT_POINTS

    assert MAX_UNIT_POINTS == 256 * 65536 and 250 * 65536 <= MAX_UNIT_POINTS  # the default block always fits
    out = tmp_path / "out"
    out.mkdir()
    base = ["dataset", "build", "--procedural", "1", "--classes", "car", "-j", "1", "-q", "-o", out / "d.h5"]
    proc = run_cli(*base, "--views", "100000", "--points", "65536", "--block", "257")
    assert_user_error(proc, "--block: at most 256 views a work unit at 65536 points")
    _nothing_in(out)


@pytest.mark.timeout(30)
def test_a_build_yaml_seed_out_of_range_is_refused_before_the_build(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    cfg = tmp_path / "b.yaml"
    cfg.write_text(f"views: 2\nseed: {BIG_SEED}\n")
    proc = run_cli(
        "dataset",
        "build",
        "--procedural",
        "1",
        "--classes",
        "car",
        "-j",
        "1",
        "-q",
        "-o",
        out / "d.h5",
        "--config",
        cfg,
    )
    assert_user_error(proc, "--seed", "0..2**63-1")
    _nothing_in(out)


# ---------------------------------------------------------------------------- seeds


@pytest.mark.timeout(30)
def test_the_seed_range_is_what_numpy_torch_and_hdf5_take():
    import h5py
    import torch

    assert MAX_SEED == 2**63 - 1
    torch.Generator().manual_seed(MAX_SEED)
    np.random.default_rng(MAX_SEED)
    with h5py.File("mem.h5", "w", driver="core", backing_store=False) as f:
        f.attrs["seed"] = MAX_SEED
        assert int(f.attrs["seed"]) == MAX_SEED
    assert check_seed(0) == 0 and check_seed(MAX_SEED) == MAX_SEED and check_seed(np.int64(7)) == 7
    for bad in (-1, MAX_SEED + 1, 10**23, 2.5, True, "3", None):
        with pytest.raises(ParameterError, match=r"0\.\.2\*\*63-1"):
            check_seed(bad)


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "argv",
    [
        ["dataset", "build", "--procedural", "1", "-o", "{root}/d.h5"],
        ["dataset", "sequences", "--meshes", "{root}/m.ply", "-o", "{root}/s"],
        ["analyze", "density", "-o", "{root}/dens"],
        ["complete", "{scan}", "--box", "{box}", "-o", "{root}/c.ply"],
        ["real", "extract", "{root}", "--format", "generic", "-o", "{root}/r.h5"],
        ["train", "--model", "sanet", "--data", "{root}/d.h5", "-o", "{root}/run"],
    ],
    ids=["build", "sequences", "density", "complete", "extract", "train"],
)
def test_every_seed_option_is_bounded(scan, argv):
    before = sorted(p.name for p in scan["root"].iterdir())
    proc = run_cli(*[a.format(root=scan["root"], scan=scan["scan"], box=scan["box"]) for a in argv], "--seed", BIG_SEED)
    assert_user_error(proc, "--seed", "0..2**63-1")
    assert sorted(p.name for p in scan["root"].iterdir()) == before


# ---------------------------------------------------------------------------- training config


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "model, overrides, message",
    [
        ("pcn", {"model": {"args": {"code_size": 0}}}, r"model\.args\.code_size must be a whole number in 1\.\.16384"),
        ("sanet", {"model": {"args": {"hidden": [-5]}}}, r"model\.args\.hidden must be a list .* in 1\.\.16384"),
        ("pcn", {"model": {"args": {"num_coarse": 10**9}}}, r"model\.args\.num_coarse .* 1\.\.262144"),
        ("topnet", {"model": {"args": {"degrees": [64, 64, 64, 64]}}}, r"model\.args\.degrees .*product"),
        ("pcn", {"train": {"lr": 1e300}}, r"train\.lr must be a learning rate in \(0, 10\]"),
        ("pcn", {"train": {"seed": 10**23}}, r"train\.seed must be a whole number in 0\.\.2\*\*63-1"),
        ("pcn", {"train": {"batch_size": 100000}}, rf"train\.batch_size must be a whole number in 1\.\.{MAX_BATCH}"),
    ],
)
def test_train_config_values_out_of_range_name_the_key(model, overrides, message):
    from spotlights.learning.models import load_config

    with pytest.raises(ParameterError, match=message):
        load_config(model, overrides=overrides)


@pytest.mark.timeout(30)
def test_config_bounds_are_inclusive_and_one_step_past_is_refused():
    from spotlights.learning.models import load_config

    at = {"model": {"args": {"code_size": 16384}}, "train": {"lr": 10, "seed": MAX_SEED, "batch_size": MAX_BATCH}}
    cfg = load_config("pcn", overrides=at)
    assert cfg["model"]["args"]["code_size"] == 16384 and cfg["train"]["seed"] == MAX_SEED
    for past in (
        {"model": {"args": {"code_size": 16385}}},
        {"train": {"lr": 10.5}},
        {"train": {"seed": MAX_SEED + 1}},
        {"train": {"batch_size": MAX_BATCH + 1}},
    ):
        with pytest.raises(ParameterError):
            load_config("pcn", overrides=past)


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "option, value, fragment",
    [("--lr", "1e300", "(0, 10]"), ("--batch-size", "100000", f"1..{MAX_BATCH}"), ("--seed", BIG_SEED, "2**63-1")],
)
def test_train_options_out_of_range_leave_no_run_folder(tmp_path, option, value, fragment):
    proc = run_cli("train", "--model", "pcn", "--data", tmp_path / "d.h5", "-o", tmp_path / "run", option, value)
    assert_user_error(proc, option, fragment)
    assert not (tmp_path / "run").exists()


@pytest.mark.timeout(30)
def test_a_yaml_model_width_of_zero_names_the_file_and_key(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: {args: {code_size: 0}}\n")
    proc = run_cli(
        "train", "--model", "pcn", "--data", tmp_path / "d.h5", "--config", cfg, "-o", tmp_path / "run", "-q"
    )
    assert_user_error(proc, "c.yaml", "model.args.code_size", "1..16384")
    assert not (tmp_path / "run").exists()


@pytest.mark.timeout(30)
@pytest.mark.parametrize("batch", ["100000000", str(MAX_BATCH + 1)])
def test_bench_batch_is_bounded(batch):
    proc = run_cli("bench", "models", "--models", "pcn", "--batch", batch, "--threads", "1")
    assert_user_error(proc, "--batch", f"1..{MAX_BATCH}")


@pytest.mark.timeout(30)
def test_bench_models_api_checks_batches():
    from spotlights.learning.bench import bench_models

    with pytest.raises(ParameterError, match=f"1..{MAX_BATCH}"):
        bench_models(["pcn"], [10**8])


# ---------------------------------------------------------------------------- sequences, density


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "option, value, fragment",
    [("--frames", "100000000", "1..10000"), ("--hz", "1e-300", "[0.1, 1000]"), ("--sequences", "10**12", "1..100000")],
)
def test_sequence_frames_and_rate_are_bounded(tmp_path, option, value, fragment):
    mesh = CARS / "sedan" / "aodi-a6.ply"
    if not mesh.exists():
        mesh = tmp_path / "m.ply"  # the check comes before the mesh is read
    value = str(10**12) if value == "10**12" else value
    proc = run_cli("dataset", "sequences", "--meshes", mesh, "--sequences", "1", "-o", tmp_path / "s", option, value)
    assert_user_error(proc, option, fragment)
    assert "Warning" not in proc.stderr, proc.stderr  # no raw NumPy overflow warning first
    assert not (tmp_path / "s").exists()


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "option, values, fragment",
    [
        ("--r-step", ["1e-9"], "[0.001, 0.5]"),
        ("--alpha-step", ["1e-9"], "[0.1, 90]"),
        ("--rotations", ["1000000000000"], "2..10000"),
        ("--mc-rays", ["100000", "100000"], "16777216"),
    ],
)
def test_density_grid_and_monte_carlo_sizes_are_bounded(tmp_path, option, values, fragment):
    proc = run_cli("analyze", "density", "-o", tmp_path / "dens", "-q", option, *values)
    assert_user_error(proc, option, fragment)
    assert not (tmp_path / "dens").exists()


# ---------------------------------------------------------------------------- crop margins


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "option", ["--margin=1e300", "--ground-clearance=-1e300", "--crop=nan", "--margin=inf", "--margin=10.5"]
)
def test_complete_crop_margins_are_bounded(scan, tmp_path, option):
    proc = run_cli("complete", scan["scan"], "--box", scan["box"], "-o", tmp_path / "c.ply", option)
    assert_user_error(proc, option.split("=")[0], f"[-{MAX_CROP_M:g}, {MAX_CROP_M:g}]")
    assert "Warning" not in proc.stderr
    assert not (tmp_path / "c.ply").exists()


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "option, value, fragment", [("--margin", "1e300", "[-10, 10]"), ("--points", "70000", "1..65536")]
)
def test_real_extract_crop_margin_and_points_are_bounded(scan, tmp_path, option, value, fragment):
    proc = run_cli("real", "extract", scan["root"], "--format", "generic", "-o", tmp_path / "r.h5", option, value)
    assert_user_error(proc, option, fragment)
    assert not (tmp_path / "r.h5").exists()


@pytest.mark.timeout(30)
def test_the_library_checks_the_same_bounds():
    from spotlights.data.real.extract import ExtractConfig
    from spotlights.data.synthetic.sequences import MAX_SEQUENCES, SequenceSpec, simulate_sequences, write_sequences_h5

    ExtractConfig(n_points=65536)  # the bound itself is taken
    with pytest.raises(ParameterError, match="1..65536"):
        ExtractConfig(n_points=65537)
    with pytest.raises(ParameterError, match="`sequences`"):
        write_sequences_h5(["m.ply"], "never-written.h5", MAX_SEQUENCES + 1, SequenceSpec())
    with pytest.raises(ParameterError, match="`sequences`"):  # checked before the (missing) mesh is looked for
        simulate_sequences("no-such-mesh.ply", "never-written", MAX_SEQUENCES + 1, SequenceSpec())


# ---------------------------------------------------------------------------- --up -z


@pytest.mark.timeout(30)
def test_axis_values_that_look_like_options_are_joined():
    assert join_axis_values(["x", "--up", "-z", "--forward", "-x"]) == ["x", "--up=-z", "--forward=-x"]
    assert join_axis_values(["--up", "y", "--up", "+Y"]) == ["--up", "y", "--up=+Y"]
    assert join_axis_values(["--", "--up", "-z"]) == ["--", "--up", "-z"]  # after --: untouched
    assert join_axis_values(["--up", "-q"]) == ["--up", "-q"]  # not an axis: argparse says what is wrong


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "argv",
    [
        ["complete", "s.npy", "--box", "b.json", "-o", "c.ply"],
        ["encode", "car.ply", "-o", "car.npz"],
        ["view", "car.ply", "-o", "v.html"],
        ["dataset", "build", "--meshes", "DIR", "-o", "d.h5"],
    ],
    ids=["complete", "encode", "view", "dataset-build"],
)
def test_up_minus_z_parses_as_an_axis(argv):
    from spotlights.cli import build_parser

    args = build_parser().parse_args([*argv, "--up", "-z", "--forward", "-y"])
    assert (args.up, args.forward) == ("-z", "-y")


@pytest.mark.timeout(120)
def test_complete_runs_with_up_minus_z(scan, tmp_path):
    proc = run_cli("complete", scan["scan"], "--box", scan["box"], "-o", tmp_path / "c.ply", "--up", "-z", "-q")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "c.ply").exists()


# ---------------------------------------------------------------------------- the bounds are in --help


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "argv, fragments",
    [
        (
            ["dataset", "build"],
            ["1..100000", "1..65536", "1..1048576", "0.01..90", "0..2**63-1", "-x, -y, -z", "2**24"],
        ),
        (["dataset", "sequences"], ["1..10000", "1..100000", "0.1..1000 Hz", "0..2**63-1"]),
        (["real", "extract"], ["1..65536", "|M| <= 10", "0..2**63-1"]),
        (["analyze", "density"], ["0.001..0.5", "0.1..90", "2..10000", "16777216", "0..2**63-1"]),
        (["train"], ["(0, 10]", f"1..{MAX_BATCH}", "0..2**63-1"]),
        (["bench", "models"], [f"1..{MAX_BATCH}"]),
        (["complete"], ["|M| <= 10", "0..2**63-1"]),
    ],
)
def test_help_states_the_bounds(argv, fragments):
    proc = run_cli(*argv, "--help")
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())  # argparse wraps lines
    for frag in fragments:
        assert frag in text, (frag, argv)
