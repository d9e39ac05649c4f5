"""The numbers of docs/studies/speed.md are those of the results files it names (docs/results/speed/*.json),
formatted as the study prints them; the files name the CPU they were measured on."""

from __future__ import annotations

import json
import re

import pytest

from helpers import REPO

SPEED = REPO / "docs" / "results" / "speed"
STUDY = REPO / "docs" / "studies" / "speed.md"


def _text() -> str:
    return re.sub(r"\s+", " ", STUDY.read_text())


def _json(name: str) -> dict:
    return json.loads((SPEED / name).read_text())


def _says(*expected: str) -> None:
    text = _text()
    for e in expected:
        assert e in text, f"docs/studies/speed.md should say {e!r} (from docs/results/speed)"


@pytest.mark.parametrize("name", ["runtime.json", "pictures.json", "compression.json"])
def test_every_results_file_names_its_cpu(name):
    cpu = _json(name)["cpu"]
    assert cpu["model"] and {"avx512f", "avx512_bf16", "amx", "cores"} <= cpu.keys()
    assert f"{cpu['model']}, {cpu['cores']} cores" in _text()


def test_one_frame_and_import_numbers():
    d = _json("runtime.json")
    runs = d["cli"]["runs"]
    auto = runs["default (auto: onnxruntime fp32)"]
    old = runs["--runtime torch --precision fp32 (the defaults before auto)"]
    _says(f"**{auto['cpu_s']:.3f}** | **{auto['wall_s']:.3f}**", f"{old['cpu_s']:.3f} | {old['wall_s']:.3f}")
    _says(f"{old['cpu_s'] / auto['cpu_s']:.1f}x less CPU")
    lo, hi = auto["wall_range_s"]
    _says(f"ranged {lo:.2f}-{hi:.2f} s", f"{d['import']['import_spotlights_over_python']['cpu_s']:.3f} s of CPU")


def test_one_scan_numbers():
    m = _json("runtime.json")["model"]
    for threads, batch in (("1_thread", "batch_1"), ("1_thread", "batch_32"), ("2_threads", "batch_32")):
        row = m[threads][batch]
        cells = [f"{row[p]['cpu_ms_per_scan']:.2f}" for p in ("torch fp32", "torch bf16", "onnxruntime fp32")]
        assert all(c in _text() for c in cells), (threads, batch, cells)
    one = m["1_thread"]
    b1 = one["batch_1"]["torch fp32"]["cpu_ms_per_scan"] / one["batch_1"]["torch bf16"]["cpu_ms_per_scan"]
    b32 = one["batch_32"]["torch fp32"]["cpu_ms_per_scan"] / one["batch_32"]["torch bf16"]["cpu_ms_per_scan"]
    _says(f"{b1:.1f}x (batch 1) to {b32:.1f}x (batch 32)")
    peak, frac = m["matmul_peak_gflops_1_thread"], m["fraction_of_peak_1_thread_batch_32"]
    _says(f"{peak['fp32']:.0f} GFLOP/s", f"reaches {peak['torch_fp32']:.0f})", f"{peak['bf16']:.0f} in bfloat16")
    _says(*(f"{frac[p]:.2f} of the" for p in frac), f"{m['forward_flops_per_scan'] / 1e6:.0f} MFLOP")


def test_bf16_and_parity_numbers():
    b = _json("runtime.json")["bf16"]
    cars, kitti = b["test_cars"], b["kitti_002155"]["objects"]
    _says(f"largest depth difference {cars['max_depth_difference']:.3f}", f"{cars['max_p_hit_difference']:.3f}")
    _says(f"{100 * cars['rays_kept_by_one_only_share']:.3f}%")
    mean = [o["mean_distance_bf16_to_fp32_cm"] for o in kitti]
    p99 = [o["p99_distance_bf16_to_fp32_cm"] for o in kitti]
    _says(f"{min(mean):.2f}-{max(mean):.2f} cm", f"{min(p99):.2f}-{max(p99):.2f} cm")
    assert b["kitti_002155"]["statuses_equal"]
    p = _json("pictures.json")["parity"]
    _says(f"{p['default']['depths']:.1e} (default) and {p['classes']['depths']:.1e} (classes)")
    assert p["default"]["kept_rays_differ"] == p["classes"]["kept_rays_differ"] == 0


def test_picture_and_compression_numbers():
    pic = _json("pictures.json")["pictures"]
    _says(
        f"**{pic['cpu_s_per_picture']['raster']:.3f} s for the raster**",
        f"{pic['cpu_s_per_picture']['closeups']:.3f} s",
    )
    for row in pic["real_complete"].values():
        _says(f"{row['frame_loop_wall_s']:.3f} | {row['frames_per_s']:.2f}")
    _says(f"by {pic['frame_loop_pictures_over_none']:.2f}x")
    c = _json("compression.json")["candidates"]
    for row in c.values():
        assert row["arrays_read_back_equal"]
        _says(f"{row['file_mb']:.2f} | yes")
    g, z = c["gzip 4 + shuffle"], c["none"]
    _says(f"{g['write_cpu_s'] / z['write_cpu_s']:.1f}x less CPU to write than gzip")


def test_idle_frame_rates_are_the_results_files():
    fr = _json("frames_runtime.json")["rows"]
    for row in fr.values():
        _says(f"| {row['runtime']} | {row['precision']} | {row['frames_per_s']:.2f} |")
    assert fr["auto (default)"]["runtime"] == "torch" or fr["auto (default)"]["precision"] == "fp32"
    pic = _json("pictures_idle.json")["pictures"]
    _says(f"{pic['real_complete']['pictures (default)']['frames_per_s']:.2f} frames/s with the raster pictures")
    _says(f"slow the frame loop by {pic['frame_loop_pictures_over_none']:.2f}x")
    m = pic["medians"]
    _says(
        f"{pic['cpu_s_per_picture']['raster'] * 1000:.0f} ms of CPU (the drawing thread's own",
        f"{m['payload_pickle_bytes'] / 1e6:.2f} MB pickled against {m['result_pickle_bytes'] / 1e6:.2f} MB",
        f"palette image it is ({m['png_bytes'] / 1e3:.0f} kB",
    )
