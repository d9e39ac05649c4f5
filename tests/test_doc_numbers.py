"""Measured numbers quoted in the README and the docs agree with the committed results JSON they come from.

A number written by hand into prose drifts when the result is measured again (the docs
said 4,439 completion points for KITTI 002155 long after the default model changed; the count is
124,695). Each check below formats the JSON's value the way the doc prints it and looks for it in
the doc's text (whitespace and line breaks collapsed). When a result is re-measured, the JSON and
the sentence change together, or this fails naming both.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from helpers import REPO

RESULTS = REPO / "docs" / "results"


def _text(path: Path) -> str:
    return re.sub(r"\s+", " ", path.read_text())


def _json(relpath: str) -> dict:
    return json.loads((RESULTS / relpath).read_text())


def _says(doc: str, expected: str) -> None:
    assert expected in _text(REPO / doc), f"{doc} should say {expected!r} (from docs/results)"


def _summary(report: dict, model: str, checkpoint: str | None = None, variant: int = 0) -> dict:
    """Mean-over-samples metrics of one row of a `spotlights evaluate` report."""
    (res,) = [r for r in report["results"] if r["model"] == model and checkpoint in (None, r["checkpoint"])]
    return res["rows"][variant]["summary"]["mean_over_samples"]


def test_kitti_002155_completion_count():
    frame = _json("complete_frame_default.json")
    assert frame["checkpoint"] == "default" and frame["every_completion_point_inside_its_sphere"]
    n = f"{frame['completion_points']:,}"
    assert frame["fallback"] == "classes" and frame["completed_by_fallback"] == 1  # the van, by the class model
    _says(
        "docs/completion.md", f"{frame['completed']} vehicles completed, {n} completion points: 7 cars by the default"
    )
    _says("docs/studies/frame-speed.md", f"the van by the class model in a batch of its own ({n} completion points")
    for threads in ("1", "2"):
        ms = f"{1000 * frame['end_to_end_no_picture'][threads]['wall_s']:.0f} ms"
        _says(
            "docs/studies/frame-speed.md",
            f"| end to end without the picture | {ms}" if threads == "1" else f"**{ms}** |",
        )
    paper = _json("complete_frame.json")
    assert paper["checkpoint"] == "paper"
    _says("docs/completion.md", f"({paper['completion_points']:,} with `--checkpoint paper`)")


def test_readme_default_model_against_the_paper_sanet():
    rep = _json("fair/default_vs_paper.json")
    d = _summary(rep, "sanet-hit", "default")
    p = _summary(rep, "sanet", "paper", variant=1)  # the clipped row (clip 0.2)
    _says(
        "docs/studies/README.md",
        f"accuracy {d['accuracy']:.4f}, completeness {d['completeness']:.4f}, "
        f"**{d['n_points']:,.0f} points per completion**",
    )
    _says(
        "docs/studies/README.md",
        f"the paper-faithful SA-Net's {p['accuracy']:.4f}, {p['completeness']:.4f} and {p['n_points']:.0f} points",
    )


def test_readme_fair_table1_rows():
    t1 = _json("fair/table1.json")
    fold, atlas, top = (_summary(t1, m) for m in ("foldingnet", "atlasnet", "topnet"))
    _says("docs/studies/README.md", f"(FoldingNet {fold['accuracy']:.4f}, AtlasNet {atlas['accuracy']:.4f})")
    _says("docs/studies/README.md", f"(best baseline: TopNet {top['completeness']:.4f})")
    sanet = _summary(t1, "sanet", variant=1)  # clip 0.2
    _says("docs/studies/README.md", f"gets {sanet['accuracy']:.4f} / {sanet['completeness']:.4f}")


def test_readme_reproduction_headline():
    t1 = _json("reproduction/tables/table1.json")
    ours, paper = t1["ours"], t1["paper"]
    _says(
        "docs/studies/README.md",
        f"({ours['sanet (clip 0.2)']['average']:.4f} vs TopNet's {ours['topnet']['average']:.4f}; "
        f"the paper: {paper['sanet (clip 0.2)']['average']:.4f} vs {paper['topnet']['average']:.4f})",
    )
    t4 = _json("reproduction/tables/table4.json")
    ours4, paper4 = t4["ours"], t4["paper"]
    angles = ("30", "60", "83")
    _says("docs/studies/README.md", "hit ratios " + " / ".join(f"{ours4[a]['average']:.1f}" for a in angles))
    paper_ratios = " / ".join(f"{paper4[a]['average']:.1f}" for a in sorted(paper4, key=int))
    _says("docs/studies/README.md", f"(paper {paper_ratios} %)")


@pytest.mark.parametrize(
    "data, sentence",
    [
        (
            "av2",
            "on AV2 the default model's completions are the most consistent across frames ({default}; TopNet {topnet})",
        ),
        ("nuscenes", "on nuScenes FoldingNet's and TopNet's are ({foldingnet}, {topnet}; default {default})"),
    ],
)
def test_readme_table2_headline(data, sentence):
    """Table 2 at equal density (the README's headline), the default model = the shipped float32-head retrain."""
    rep = _json(f"real/table2_fair/{data}.json")
    models = {m["name"]: m for m in rep["models"]}
    cd = {
        k: f"{models[n]['equal_density']['average']['cd']:.3f}"
        for k, n in (("default", "sanet-hit-dense-f32"), ("topnet", "topnet"), ("foldingnet", "foldingnet"))
    }
    _says("docs/studies/README.md", sentence.format(**cd))


def test_readme_table2_fidelity():
    fid = []
    baselines = []
    for data in ("av2", "nuscenes"):
        models = {m["name"]: m for m in _json(f"real/table2_fair/{data}.json")["models"]}
        fid.append(f"{models['sanet-hit-dense-f32']['average']['fidelity']:.3f}")
        baselines += [models[b]["average"]["fidelity"] for b in ("atlasnet", "pcn", "foldingnet", "topnet")]
    _says("docs/studies/README.md", f"(fidelity {fid[0]} / {fid[1]}; baselines {min(baselines):.3f} or more)")


def test_suv_hold_out_of_the_ray_local_model():
    gen = _json("fair/ray_local/generalisation_suv.json")
    (local,) = [k for k in gen["rows"] if k.startswith("sanet-local-nosuv")]
    row, ratio = gen["rows"][local], gen["ratio_held_out_over_in_distribution"][local]
    _says(
        "docs/studies/ray-local.md",
        f"| ray-local, trained without SUVs (p(hit) >= 0.5) | {row['in_distribution']['accuracy']:.4f} "
        f"({row['in_distribution']['completeness']:.4f}) | {row['held_out']['accuracy']:.4f} "
        f"({row['held_out']['completeness']:.4f}) | **{ratio['accuracy']:.2f}x** ({ratio['completeness']:.2f}x) |",
    )
    default = gen["rows"]["default (p(hit) >= 0.4)"]["held_out"]["accuracy"]
    _says("docs/studies/ray-local.md", f"the one of the generalisation study ({default:.6f} on the SUVs)")


def _real_cell(name: str, where: str, cls: str) -> str:
    """One cell of the class study's real-data tables: inside / fidelity / consistency at equal density of class ``cls``
    in ``docs/results/classes/{name}-{where}.json``, as the docs print it."""
    m = _json(f"classes/{name}-{where}.json")["models"][0]
    ins, fid = m["inside_box"][cls], m["classes"][cls]["fidelity"]
    cd = m["equal_density"]["classes"][cls]["cd"]
    return f"{100 * ins:.1f}% / {fid:.4f} / {cd:.4f}"


def test_classes_box_term_rows():
    """docs/studies/classes-real.md's box-term table: each class's inside / fidelity / consistency of the three models."""

    def cell(name: str, cls: str) -> str:
        return _real_cell(name, "nuscenes", cls)

    for cls, objects in (("trailer", 12), ("car", 23)):
        row = " | ".join(cell(n, cls) for n in ("classes", "classes-box", "classes-box30"))
        _says("docs/studies/classes-real.md", f"| nuScenes {cls} ({objects}) | {row} |")


def test_classes_weight0_control():
    """docs/studies/classes.md's weight-0 control table: nuScenes inside per class of the three fine-tunes, from their JSONs."""

    def inside(name: str) -> str:
        m = _json(f"classes/{name}-nuscenes.json")["models"][0]
        return " / ".join(f"{100 * m['inside_box'][c]:.1f}" for c in ("trailer", "bus", "truck", "car")) + "%"

    row = " | ".join(inside(n) for n in ("classes", "classes-w0", "classes-box30"))
    _says("docs/studies/classes.md", f"| nuScenes inside: trailer / bus / truck / car | {row} |")


def test_classes_wider_coverage_candidate():
    """docs/studies/classes-real.md's wider-coverage table: the trailers' and AV2 truck's rows from the two models' JSONs."""

    cell = _real_cell

    old, new = cell("classes-box30", "nuscenes", "trailer"), cell("classes-v2", "nuscenes", "trailer")
    _says(
        "docs/studies/classes-real.md",
        f"| nuScenes trailer (12) | {old} | **{new.split(' / ')[0]}** / {new.split(' / ', 1)[1]} |",
    )
    old, new = cell("classes-box30", "av2", "truck"), cell("classes-v2", "av2", "truck")
    ins, fid, cd = new.split(" / ")
    _says("docs/studies/classes-real.md", f"| AV2 truck (1) | {old} | {ins} / **{fid}** / {cd} |")


def test_track_worker_speed_on_a_quiet_machine():
    for threads, row in ((1, "**with the worker, 1 torch thread**"), (2, "with the worker, 2 torch threads")):
        med = _json(f"real/track_fusion_speed_worker_quiet_{threads}thread_bf16.json")["worker_and_one_process"]
        w, one = med["median"]["worker"], med["median"]["one_process"]
        fps = f"**{w['fps_wall']:.1f}**" if threads == 1 else f"{w['fps_wall']:.1f}"
        _says(
            "docs/studies/frame-speed.md",
            f"| {row} | {w['cpu_ms_per_frame']:.0f} | {w['worker_cpu_ms_per_frame']:.0f} | {fps} (",
        )
        _says(
            "docs/studies/frame-speed.md",
            f"| one process, {threads} torch thread{'s' if threads == 2 else ''} | "
            f"{one['cpu_ms_per_frame']:.0f} | - | {one['fps_wall']:.2f} (",
        )


def test_track_sequences_truth_floor():
    """The representation's floor under the fused-window targets , as docs/studies/fusion.md says."""
    rep = _json("real/track_sequences_floor_2hz.json")
    floor, one = rep["truth_floor"], rep["completion"]["default"]["true past:1"]
    acc, comp = f"{floor['accuracy_m']:.4f}", f"{floor['completeness_m']:.4f}"
    _says("docs/studies/fusion.md", f"**accuracy {acc} m, completeness {comp} m**")
    _says("docs/studies/fusion.md", f"score {comp} m completeness (accuracy {acc} m)")
    target = 0.6 * one["completeness_m"]
    assert target < floor["completeness_m"]  # 40% better than one true-box frame lies below the floor
    _says("docs/studies/fusion.md", f"better than one true-box frame ({one['completeness_m']:.4f} m) is {target:.4f} m")


def test_classes_weight60_rows():
    """docs/studies/classes-real.md's weight-60 table: each class's inside / fidelity / consistency of both models, from the JSONs."""

    cell = _real_cell

    rows = (
        ("nuscenes", "nuScenes", "car", 23),
        ("nuscenes", "nuScenes", "truck", 7),
        ("nuscenes", "nuScenes", "bus", 1),
    )
    rows += (("av2", "AV2", "car", 20), ("av2", "AV2", "truck", 1))
    for where, label, cls, n in rows:
        _says(
            "docs/studies/classes-real.md",
            f"| {label} {cls} ({n}) | {cell('classes-box30', where, cls)} | {cell('classes-w60', where, cls)} |",
        )
    new = cell("classes-w60", "nuscenes", "trailer")
    ins, rest = new.split(" / ", 1)
    _says(
        "docs/studies/classes-real.md",
        f"| nuScenes trailer (12) | {cell('classes-box30', 'nuscenes', 'trailer')} | **{ins}** / {rest} |",
    )
    acc = _summary(_json("classes/cars-test_classes-w60.json"), "sanet-hit")["accuracy"]
    _says("docs/studies/classes-real.md", f"cars are slightly more accurate ({acc:.5f} against 0.01738")


def test_classes_class_template_rows():
    """docs/studies/classes-real.md's class-template table (four models, six rows) and the test cars, from their JSONs."""
    names = ("classes-w60", "classes-ctl", "classes-tmpl", "classes-tmpl100")

    cell = _real_cell

    rows = [("nuscenes", "nuScenes", c, n) for c, n in (("car", 23), ("truck", 7), ("trailer", 12), ("bus", 1))]
    for where, label, cls, n in rows + [("av2", "AV2", "car", 20)]:
        _says(
            "docs/studies/classes-real.md",
            f"| {label} {cls} ({n}) | " + " | ".join(cell(m, where, cls) for m in names) + " |",
        )
    truck = []
    for k, m in enumerate(names):  # the two template models' fidelity in bold: the issue's target met
        ins, fid, cd = cell(m, "av2", "truck").split(" / ")
        truck.append(f"{ins} / {'**' + fid + '**' if k >= 2 else fid} / {cd}")
    _says("docs/studies/classes-real.md", "| AV2 truck (1) | " + " | ".join(truck) + " |")
    acc = [_summary(_json(f"classes/cars-test_{m}.json"), "sanet-hit")["accuracy"] for m in names]
    _says("docs/studies/classes-real.md", f"{acc[0]:.5f}, {acc[1]:.5f}, {acc[2]:.5f}, **{acc[3]:.5f}**")
    fid = _json("classes/classes-tmpl100-av2.json")["models"][0]["classes"]["truck"]["fidelity"]
    assert fid <= 0.04  # the issue's target, met by the shipped fallback on AV2's truck


def test_classes_family_model_rows():
    """docs/studies/classes-real.md's class-family table: both models' held-out trailers and scene-0523 trailers, from the JSONs."""

    def synth(name: str) -> str:
        g = _json(f"classes/synthetic_{name}.json")["results"][0]["groups"]["procedural/trailer"]
        return f"{g['accuracy']:.4f} / {g['completeness']:.4f}"

    cls, fam = synth("classes-tmpl100"), synth("family-trailer")
    bold = " / ".join(f"**{v}**" for v in cls.split(" / "))
    _says("docs/studies/classes-real.md", f"| held-out procedural trailers, accuracy / completeness | {bold} | {fam} |")
    ins, fid, cd = _real_cell("family-trailer", "nuscenes", "trailer").split(" / ")
    c_ins, c_fid, c_cd = _real_cell("classes-tmpl100", "nuscenes", "trailer").split(" / ")
    _says(
        "docs/studies/classes-real.md",
        f"| nuScenes scene-0523 trailers (12): inside / fidelity / consistency | {c_ins} / **{c_fid}** / {c_cd} | "
        f"**{ins}** / {fid} / **{cd}** |",
    )


def test_frame_loop_speed_side_by_side():
    """The frame loop's side-by-side: the frame loop's medians and the per-round ratios the docs quote."""
    d = _json("real/track_fusion_speed.json")["summary"]["threads_1"]
    new, old = d["median"]["this"]["fps_loop"], d["median"]["other"]["fps_loop"]
    _says("docs/studies/frame-speed.md", f"**{new:.2f} frames/s against {old:.2f}**")
    a, b, c = (f"{r:.2f}" for r in d["loop_ratio_this_over_other"])
    _says("docs/studies/frame-speed.md", f"per round {a}, {b} and {c} of the")
    assert new < 10  # the docs say the target is not met
    runs = _json("real/track_fusion_speed.json")["runs"]
    assert {r["completed"] for r in runs} == {631} and {r["completed_by"]["classes"] for r in runs} == {320}
    _says("docs/studies/frame-speed.md", "631 objects completed by both (320 by the class model)")
    cpu = {k: d["median"][k]["cpu_ms_per_frame"] for k in ("this", "other")}
    work = {k: d["median"][k]["worker_cpu_ms_per_frame"] for k in ("this", "other")}
    _says("docs/studies/frame-speed.md", f"the main process {cpu['this']:.0f} against {cpu['other']:.0f} ms a frame")
    _says("docs/studies/frame-speed.md", f"the worker {work['this']:.0f} against {work['other']:.0f} ms")


def test_fused_consistency_with_every_vehicle():
    """The per-class fused/single consistency with the class model as fallback, as docs/studies/frame-speed.md quotes it."""
    d = _json("real/track_fusion_fallback.json")
    assert d["fallback"] == "classes"
    q = d["quality_on_common_observations"]
    single, fused = q["single"]["consistency_voxel_per_class"], q["fused"]["consistency_voxel_per_class"]
    names = {"car": "cars", "truck": "trucks", "trailer": "trailers"}
    for cls, name in names.items():
        f, s = fused[cls][0], single[cls][0]
        _says("docs/studies/frame-speed.md", f"{name} {f:.4f} against {s:.4f} ({f / s:.2f}x)")
    a, b = q["fused"]["consistency_voxel_all_objects"], q["single"]["consistency_voxel_all_objects"]
    _says("docs/studies/frame-speed.md", f"all objects {a:.4f} against {b:.4f} ({a / b:.2f}x)")
    _says("docs/studies/frame-speed.md", f"the {q['n_observations']} observations of Table 2's")


def test_snap_rows():
    """The --snap 0.05 table of docs/studies/snap.md: test cars, Kenney vehicles and the real sets, from their reports."""
    _says_snap_test_and_real_rows("table1_snap.json", "snap")
    g = _json("fair/snap/generalisation_snap.json")
    rows, ratio = g["scores"]["held_out"]["rows"], g["ratio_held_out_over_in_distribution"]
    plain, snap = "default (p(hit) >= 0.4)", "default (p(hit) >= 0.4, snap 0.05)"
    assert g["snap"] == [0.05]
    _says("docs/studies/snap.md", f"{rows[plain]['accuracy']:.4f} ({ratio[plain]['accuracy']:.2f}x the test cars')")
    _says("docs/studies/snap.md", f"{rows[snap]['accuracy']:.4f} ({ratio[snap]['accuracy']:.2f}x)")
    _says("docs/studies/snap.md", f"{1 - rows[snap]['accuracy'] / rows[plain]['accuracy']:.0%} better")


def _says_snap_test_and_real_rows(table: str, real: str) -> None:
    """A snap table's test-car row (docs/results/fair/snap/TABLE) and its real-set rows (real/snap/SET_REAL.json)."""
    t = _summary(_json(f"fair/snap/{table}"), "sanet-hit")
    _says(
        "docs/studies/snap.md",
        f"{t['accuracy']:.5f} / {t['completeness']:.5f} / {t['chamfer_l1']:.5f} / {t['fscore']:.3f}",
    )
    for name in ("av2", "nuscenes"):
        (m,) = _json(f"real/snap/{name}_{real}.json")["models"]
        _says("docs/studies/snap.md", f"{m['equal_density']['average']['cd']:.4f} / {m['average']['fidelity']:.4f}")


def _says_frame_pictures(report: str, headline: str, rounds: str) -> None:
    """docs/studies/frame-speed.md cites a benchmarks/frame_pictures.py report: ``headline`` and ``rounds`` are formats of
    this/other frames per second, the median speed-up, and the per-round speed-ups' range (lo, hi)."""
    d = _json(report)
    m = d["median_frames_per_second"]
    _says("docs/studies/frame-speed.md", headline.format(this=m["this"], other=m["other"], x=d["speedup_median"]))
    lo, hi = min(d["time_ratio_this_over_other_per_round"]), max(d["time_ratio_this_over_other_per_round"])
    _says("docs/studies/frame-speed.md", rounds.format(lo=1 / hi, hi=1 / lo))


def test_frame_pictures_side_by_side():
    """The pictures' speed-up of docs/studies/frame-speed.md, from benchmarks/frame_pictures.py's report."""
    _says_frame_pictures(
        "real/frame_pictures.json",
        "{this:.2f} against {other:.2f} frames/s ({x:.2f}x)",
        "each of the three rounds {lo:.1f}-{hi:.1f}x",
    )


def test_snap_with_track_fusion():
    """Consistency and fidelity with and without --snap under past:5 fusion, as docs/studies/snap.md quotes them."""
    q = {
        s: _json(f"real/track_fusion_{f}.json")["quality_on_common_observations"]
        for s, f in (("nosnap", "nosnap"), ("snap", "snap_no_rule"))
    }
    assert _json("real/track_fusion_snap_no_rule.json")["snap"] == 0.05
    assert q["snap"]["n_observations"] == q["nosnap"]["n_observations"]
    c = {
        s: (v["single"]["consistency_voxel_all_objects"], v["fused"]["consistency_voxel_all_objects"])
        for s, v in q.items()
    }
    f = {s: (v["single"]["fidelity_own_points"], v["fused"]["fidelity_own_points"]) for s, v in q.items()}
    _says(
        "docs/studies/snap.md",
        f"is {c['nosnap'][0]:.4f} / {c['nosnap'][1]:.4f} without the snap and {c['snap'][0]:.4f} / {c['snap'][1]:.4f}",
    )
    _says(
        "docs/studies/snap.md",
        f"{f['nosnap'][0]:.4f} / {f['nosnap'][1]:.4f} without and {f['snap'][0]:.4f} / {f['snap'][1]:.4f} with",
    )
    _says("docs/studies/snap.md", f"still {c['snap'][1] / c['nosnap'][0]:.2f}x as inconsistent")


def test_mirrored_snap_rows():
    """The --snap 0.08 --snap-mirror table of docs/studies/snap.md, from its reports."""
    _says_snap_test_and_real_rows("table1_snap0.08_mirror.json", "snap0.08_mirror")
    g = _json("fair/snap/generalisation_snap0.08_mirror.json")
    assert g["snap"] == [0.08] and g["snap_mirror"]
    rows, ratio = g["scores"]["held_out"]["rows"], g["ratio_held_out_over_in_distribution"]
    plain, snap = "default (p(hit) >= 0.4)", "default (p(hit) >= 0.4, snap 0.08 mirrored)"
    _says("docs/studies/snap.md", f"**{rows[snap]['accuracy']:.4f} ({ratio[snap]['accuracy']:.2f}x)**")
    _says("docs/studies/snap.md", f"**{1 - rows[snap]['accuracy'] / rows[plain]['accuracy']:.0%} better**")
    _says("docs/studies/snap.md", f"{rows[snap]['subset_accuracy']:.4f} ({ratio[snap]['subset_accuracy']:.2f}x)")
    q = _json("real/track_fusion_snap0.08_mirror_no_rule.json")["quality_on_common_observations"]
    c = (q["single"]["consistency_voxel_all_objects"], q["fused"]["consistency_voxel_all_objects"])
    _says("docs/studies/snap.md", f"| 0.0469 / 0.0225 | {c[0]:.4f} / {c[1]:.4f} |")


def test_gpu_trained_rows():
    """The GPU-trained rows of docs/studies/gpu.md (H100 runs of scripts/gpu_train.sh), from their plans and reports."""
    rep = _json("fair/gpu/table1_gpu.json")
    gen = _json("fair/gpu/generalisation_gpu.json")["ratio_held_out_over_in_distribution"]
    for model, run, gen_row in (
        ("sanet-local", "sanet-local", "local/best.pt (p(hit) >= 0.4)"),
        ("snowflakenet", "snowflakenet", "snow/best.pt"),
    ):
        plan = _json(f"fair/gpu/{run}-h100.plan.json")
        assert plan["device"].startswith("NVIDIA H100") and plan["precision"] == "bf16"
        t = _summary(rep, model)
        row = f"{t['accuracy']:.5f} | {t['completeness']:.5f} | {t['chamfer_l1']:.5f} | {t['fscore']:.3f} |"
        _says("docs/studies/gpu.md", f"{plan['steps_done']:,} | {row}")
        _says("docs/studies/gpu.md", f"({gen[gen_row]['accuracy']:.2f}x)")
        _says("docs/studies/gpu.md", f"{plan['step_seconds'] * 1e3:.1f} ms | 10 x {plan['steps_per_interval']:,}")


def test_gpu_trained_real_rows():
    """The GPU-trained rows of the real-set table (docs/studies/ray-local.md), from the Table 2 reports they were added to."""
    for name in ("av2", "nuscenes"):
        models = {m["name"]: m for m in _json(f"real/table2_ray_local/{name}.json")["models"]}
        for run, label in (("sanet-local-gpu", "ray-local SA-Net"), ("snowflakenet-gpu", "SnowflakeNet")):
            m = models[run]
            row = (
                f"| {label}, **GPU-trained** (H100) | {m['equal_density']['average']['cd']:.4f} | "
                f"{m['average']['cd']:.4f} | {m['equal_density']['diversity']:.4f} | {m['average']['fidelity']:.4f} | "
                f"{m['average']['mmd']:.4f} | {m['heading']['rate']:.1%} |"
            )
            _says("docs/studies/ray-local.md", row)


def test_snap_with_the_occlusion_rule():
    """The occlusion-rule table of docs/studies/snap.md (the package's snap with the occlusion rule), from its reports."""
    for variant, key, real in (
        ("snap", "snap 0.05", "snap"),
        ("snap0.08_mirror", "snap 0.08 mirrored", "snap0.08_mirror"),
    ):
        t = _summary(_json(f"fair/snap/occlusion_rule/table1_{variant}.json"), "sanet-hit")
        test_row = f"{t['accuracy']:.5f} / {t['completeness']:.5f} / {t['chamfer_l1']:.5f} / {t['fscore']:.3f}"
        g = _json(f"fair/snap/occlusion_rule/generalisation_{variant}.json")
        rows, ratio = g["scores"]["held_out"]["rows"], g["ratio_held_out_over_in_distribution"]
        plain, snap = "default (p(hit) >= 0.4)", f"default (p(hit) >= 0.4, {key})"
        better = 1 - rows[snap]["accuracy"] / rows[plain]["accuracy"]
        kenney = f"{rows[snap]['accuracy']:.4f} ({ratio[snap]['accuracy']:.2f}x), {better:.0%} better"
        reals = []
        for name in ("av2", "nuscenes"):
            (m,) = _json(f"real/snap/occlusion_rule/{name}_{real}.json")["models"]
            assert m["snapped"]
            reals.append(f"{m['equal_density']['average']['cd']:.4f} / {m['average']['fidelity']:.4f}")
        q = _json(f"real/track_fusion_{variant}.json")["quality_on_common_observations"]
        fused = (
            f"{q['single']['consistency_voxel_all_objects']:.4f} / {q['fused']['consistency_voxel_all_objects']:.4f}"
        )
        for expected in (test_row, kenney, *reals, fused):
            _says("docs/studies/snap.md", expected)
    speed = _json("fair/snap/occlusion_rule/snap_speed.json")
    m = speed["median_ms_per_box"]
    _says(
        "docs/studies/snap.md",
        f"{m['this']['no sensor']:.1f} ms of CPU a box plain, {m['this']['sensor (occlusion rule)']:.1f} ms",
    )
    _says("docs/studies/snap.md", f"was {m['other']['no sensor']:.1f} ms before")
    _says("docs/studies/snap.md", f"{speed['speedup_no_sensor']:.2f}x; `python benchmarks/snap_speed.py")


def test_snapped_track_windows():
    """The snapped drive-past windows' table of docs/studies/fusion.md, from benchmarks/track_sequences.py's reports."""
    for name in ("track_sequences_snap_2hz", "track_sequences_snap0.08_mirror_2hz"):
        rows = _json(f"real/{name}.json")["completion"]["default"]
        for boxes in ("true", "refined"):
            one, five = rows[f"{boxes} past:1"], rows[f"{boxes} past:5"]
            _says(
                "docs/studies/fusion.md",
                f"{one['accuracy_m']:.4f} / {one['completeness_m']:.4f} -> {five['accuracy_m']:.4f} / "
                f"{five['completeness_m']:.4f} ({five['accuracy_gain']:.0%} / {five['completeness_gain']:.0%})",
            )


def test_mirror_fine_tune_rows():
    """The trained mirror's table of docs/studies/generalisation.md, from benchmarks/generalisation.py's report."""
    g = _json("fair/mirror/generalisation_mirror.json")
    rows_in, rows_out = g["scores"]["in_distribution"]["rows"], g["scores"]["held_out"]["rows"]
    ratios = g["ratio_held_out_over_in_distribution"]
    for key, thr in (("default", 0.4), ("ft_false/best.pt", 0.3), ("ft_true/best.pt", 0.3)):
        name = f"{key} (p(hit) >= {thr})"
        a, h, r = rows_in[name], rows_out[name], ratios[name]
        cells = f"{a['accuracy']:.5f} / {a['completeness']:.5f} / {a['fscore']:.3f} | {h['accuracy']:.5f}"
        _says("docs/studies/generalisation.md", f"{cells} ({r['accuracy']:.2f}x) | {r['subset_accuracy']:.2f}x |")


def test_picture_processes_side_by_side():
    """The picture processes' speed-up of docs/studies/frame-speed.md, from benchmarks/frame_pictures.py's report."""
    _says_frame_pictures(
        "real/frame_pictures_processes.json",
        "**{this:.2f} against {other:.2f} frames/s ({x:.2f}x)**",
        "each round {lo:.1f}-{hi:.1f}x",
    )
    _says_frame_pictures(
        "real/frame_pictures_processes_fused.json",
        "**{this:.2f} against {other:.2f} frames/s ({x:.2f}x)**",
        "each round {lo:.1f}-{hi:.1f}x",
    )


def test_fallback_speed_side_by_side():
    """The speed of `real complete --fuse past:5 --refine-boxes` with every vehicle completed
    (docs/studies/frame-speed.md), from benchmarks/track_fusion.py's side-by-side report."""
    report = _json("real/track_fusion_speed_fallback.json")
    med = report["summary"]["threads_1"]["median"]
    this = [r for r in report["runs"] if r["code"] == "this"]
    other = [r for r in report["runs"] if r["code"] == "other"]
    assert len(this) == len(other) == 5 and all(r["completed"] == 631 for r in this + other)
    _says(
        "docs/studies/frame-speed.md",
        f"**{med['this']['fps_loop']:.2f} against {med['other']['fps_loop']:.2f} frames/s**",
    )
    fps_this = sorted(r["fps_loop"] for r in this)
    fps_other = sorted(r["fps_loop"] for r in other)
    _says(
        "docs/studies/frame-speed.md",
        f"every round {fps_this[0]:.2f}-{fps_this[-1]:.2f} against {fps_other[0]:.2f}-{fps_other[-1]:.2f}",
    )
    ratios = report["summary"]["threads_1"]["loop_ratio_this_over_other"]
    _says("docs/studies/frame-speed.md", f"{min(ratios):.2f}-{max(ratios):.2f} of the old time")
    _says(
        "docs/studies/frame-speed.md",
        f"{med['this']['cpu_ms_per_frame']:.0f} against {med['other']['cpu_ms_per_frame']:.0f} ms of CPU a frame",
    )
    assert fps_this[0] >= 10.0  # the claim "met": every round at 10 frames/s or more


def test_fused_window_input_points():
    """1,024 against 256 input points for fused windows (docs/studies/fusion.md), from benchmarks/track_sequences.py."""
    big = _json("real/track_sequences_input1024_bf16_2hz.json")["completion"]["default"]
    small = _json("real/track_sequences_input256_bf16_2hz.json")["completion"]["default"]
    for key, label in (
        ("refined past:5", "refined `past:5`"),
        ("refined all", "refined `all`"),
        ("true past:5", "true `past:5`"),
    ):
        a, b = big[key], small[key]
        _says(
            "docs/studies/fusion.md",
            f"{label} {a['accuracy_m']:.4f} / {a['completeness_m']:.4f} against "
            f"{b['accuracy_m']:.4f} / {b['completeness_m']:.4f}",
        )


def test_car_model_candidates():
    """The car-model candidates (docs/studies/car-model.md), from `real evaluate`, `evaluate` and
    benchmarks/generalisation.py's reports in docs/results/car_model/ (bold marks dropped before comparing)."""
    import numpy as np

    base = "car_model"
    held = _json(f"{base}/generalisation_cands.json")["scores"]["held_out"]["rows"]
    kenney = {k.split(" ")[0]: v["accuracy"] for k, v in held.items()}
    doc = _text(REPO / "docs/studies/car-model.md").replace("**", "")

    def real_cells(report, name):
        (m,) = [m for m in report["models"] if m["name"] == name]
        fid = np.mean([o["fidelity"] for o in m["objects"] if o["cls"] == "car"])
        return f"{fid:.4f} / {m['inside_box']['car']:.1%} / {m['equal_density']['classes']['car']['cd']:.4f}"

    for name, ckpt, label in (
        ("default", "default", "default (incumbent)"),
        ("mix60", "run_mix60/best.pt", "mix60"),
        ("mix20", "run_mix20/best.pt", "mix20"),
    ):
        test = _summary(_json(f"{base}/cars-test_{name}.json"), "sanet-hit")
        cells = [f"{test['accuracy']:.5f} / {test['chamfer_l1']:.5f}"]
        cells += [real_cells(_json(f"{base}/cand-{set_}.json"), name) for set_ in ("av2", "nuscenes")]
        row = f"| {label} | " + " | ".join(cells) + f" | {kenney[ckpt]:.4f} |"
        assert row in doc, f"docs/studies/car-model.md should hold the row {row!r} (from docs/results/{base})"
    # the cars-only control: its in-distribution accuracy and Kenney's from the mirror study's run, AV2 measured here
    gen39 = _json("fair/mirror/generalisation_mirror.json")["scores"]
    ((k_in, in39),) = [(k, v) for k, v in gen39["in_distribution"]["rows"].items() if k.startswith("ft_false/")]
    kenney39 = gen39["held_out"]["rows"][k_in]["accuracy"]
    cells = [f"({in39['accuracy']:.4f} on {gen39['in_distribution']['n_samples']} scans)"]
    cells += [real_cells(_json(f"{base}/av2_cars_only.json"), "cars_only"), "-"]
    row = "| cars-only control | " + " | ".join(cells) + f" | {kenney39:.4f} |"
    assert row in doc, f"docs/studies/car-model.md should hold the row {row!r}"
    # the prose's numbers, each built from the result files
    para = " ".join(doc.split())  # the study page, lines joined
    misses = (RESULTS / base / "fidelity_misses.txt").read_text()
    interior = re.search(r"observed points in the interior: (\d+%)", misses).group(1)
    share = dict(re.findall(r"(\w+): missed points \d+ of \d+; (\d+%) of them in the interior", misses))
    dist = {
        m[0]: m[1:]
        for m in re.findall(
            r"(\w+): mean distance ([\d.]+) \(interior points left out: ([\d.]+)\); "
            r"the interior points hold (\d+%)",
            misses,
        )
    }
    frags = [
        f"{interior} of the observed points of AV2's cars",
        f"{share['default']} of the default's missed points",
        f"(the class model: {share['classes']})",
        f"they hold {dist['default'][2]} of the default's summed distance (its mean distance {dist['default'][0]}, "
        f"{dist['default'][1]} without them; the class model {dist['classes'][0]} and {dist['classes'][1]})",
    ]
    runs = {}
    for name in ("mix60", "mix20"):
        lines = (RESULTS / base / f"{name}_train_log.csv").read_text().splitlines()
        head, first, last = lines[0].split(","), lines[1].split(","), lines[-1].split(",")
        col = {k: head.index(k) for k in ("val_chamfer_l1", "wall_seconds", "global_step")}
        runs[name] = (
            float(last[col["wall_seconds"]]) / 60,
            float(first[col["val_chamfer_l1"]]),
            float(last[col["val_chamfer_l1"]]),
        )
        assert int(last[col["global_step"]]) == 2000
    frags += [
        f"one thread each, {runs['mix60'][0]:.0f} and {runs['mix20'][0]:.0f} wall minutes",
        f"mix60's validation CD-L1 still falling at the end, {runs['mix60'][1]:.4f} -> {runs['mix60'][2]:.4f}",
        f"mix20's flat, {runs['mix20'][1]:.4f} -> {runs['mix20'][2]:.4f}",
    ]
    cons = {
        (set_, m["name"]): m["equal_density"]["classes"]["car"]["cd"]
        for set_ in ("av2", "nuscenes")
        for m in _json(f"{base}/cand-{set_}.json")["models"]
    }
    worse = [cons[(s_, n)] / cons[(s_, "default")] - 1 for s_ in ("av2", "nuscenes") for n in ("mix60", "mix20")]
    frags.append(f"(+{min(worse):.0%} to +{max(worse):.0%})")
    (m60,) = [m for m in _json(f"{base}/cand-av2.json")["models"] if m["name"] == "mix60"]
    fid60 = np.mean([o["fidelity"] for o in m60["objects"] if o["cls"] == "car"])
    acc60 = _summary(_json(f"{base}/cars-test_mix60.json"), "sanet-hit")["accuracy"]
    frags.append(f"(mix60: {acc60:.4f} and {fid60:.4f})")
    probe = (RESULTS / "car_model/pick_per_object.txt").read_text()
    acc = dict(re.findall(r"^(\w+) accuracy ([\d.]+)", probe, re.MULTILINE))
    picked, chosen, oracle = re.search(
        r"accuracy ([\d.]+); class model chosen for (\d+%); oracle ([\d.]+)", probe
    ).groups()
    frags += [
        f"accuracies, {acc['default']} and {acc['classes']}",
        f"the pick takes the class model for {chosen} of the scans and is {picked} accurate",
        f"reach only {oracle}",
    ]
    assert acc["default"] == f"{_summary(_json(f'{base}/cars-test_default.json'), 'sanet-hit')['accuracy']:.5f}"
    for frag in frags:
        assert frag in para, frag


def test_track_shapes_study_tables():
    rep = _json("tracking/track_shapes.json")
    doc = "docs/studies/track-shapes.md"
    for source in ("labels", "detections"):
        for mode, v in rep["nuscenes"][source]["modes"].items():
            _says(
                doc,
                f"| {mode} | {v['consistency_cd']:.4f} | {v['consistency_cd_m']:.4f} | "
                f"{v['consistency_over_frame']:.2f} | {v['fidelity']:.4f} | {v['fidelity_over_frame']:.3f} | "
                f"{v['cpu_s']:.1f} |",
            )
    mean = rep["sequences"]["mean"]
    for name, key in (("one frame", "frame"), ("the track's shape (`all`)", "shape all"), ("floor", "floor")):
        _says(doc, f"{name}")
        _says(doc, f"| {mean[key]['accuracy_m']:.4f} | {mean[key]['completeness_m']:.4f} |")
    _says(doc, f"(`gap_closed_accuracy` {rep['sequences']['gap_closed_accuracy']:.3f})")
    _says(doc, f"of the completeness gap ({rep['sequences']['gap_closed_completeness']:.3f})")
    fit = _json("tracking/track_shapes_fit_sequences.json")["sequences"]
    fm = fit["mean"]
    _says(doc, f"one frame {fm['frame']['accuracy_m']:.4f} / {fm['frame']['completeness_m']:.4f} m")
    _says(doc, f"the track's shape {fm['shape all']['accuracy_m']:.4f} / {fm['shape all']['completeness_m']:.4f} m")
    _says(doc, f"(`gap_closed_accuracy` {fit['gap_closed_accuracy']:.3f} with `--fit`)")
    _says(doc, f"{fit['gap_closed_completeness'] * 100:.0f}% of the completeness gap")
    assert fm["shape all"]["accuracy_m"] > rep["sequences"]["mean"]["shape all"]["accuracy_m"]  # "less accurate"
    own = _json("tracking/track_shapes_own_box.json")["nuscenes"]["detections"]["modes"]
    med = rep["nuscenes"]["detections"]["modes"]
    _says(
        doc,
        f"{own['shape all']['fidelity_over_frame']:.3f}x for `shape all` and "
        f"{own['shape all refined']['fidelity_over_frame']:.3f}x refined (median: "
        f"{med['shape all']['fidelity_over_frame']:.3f}x and {med['shape all refined']['fidelity_over_frame']:.3f}x)",
    )
    _says(
        "docs/fusion.md",
        f"fidelity {med['shape all']['fidelity_over_frame']:.3f}x that of frame-by-frame with `all` "
        f"({med['shape all refined']['fidelity_over_frame']:.3f}x with `--refine-boxes`) and "
        f"{med['shape past:5']['fidelity_over_frame']:.3f}x with `past:5`",
    )


def test_same_outputs_study_table():
    """docs/studies/same-outputs.md says of every job what the two results files say: same, or differs."""
    doc = "docs/studies/same-outputs.md"
    old = _json("same_outputs_restructure.json")
    new = _json("same_outputs_module_split.json")
    for job in (k for k in old if not k.startswith("_")):
        cells = ["same" if r[job]["same"] else "**differs**" for r in (old, new)]
        _says(doc, f"| {job} | {cells[0]} | {cells[1]} |")
    _says(doc, f"module split ({new['_refs']['old']} -> {new['_refs']['new']})")


ONE_MODEL_GROUPS = (
    ("apolloscape-cars", "ApolloScape test cars"),
    ("kenney-test", "Kenney test vehicles"),
    ("procedural/car", "procedural car"),
    ("procedural/caravan", "procedural caravan"),
    ("procedural/truck", "procedural truck"),
    ("procedural/bus", "procedural bus"),
    ("procedural/trailer", "procedural trailer"),
)


def _one_model_rows(rep: dict, cell) -> list[str]:
    """The study's table rows of a ``benchmarks/one_model.py`` report: per test group of :data:`ONE_MODEL_GROUPS`,
    its name, (models, scans) and ``cell(scores)`` of every checkpoint in the report's order."""
    labels = rep["checkpoints"]
    rows = []
    for group, name in ONE_MODEL_GROUPS:
        first = rep["test"][labels[0]][group]
        cells = [cell(rep["test"][label][group]) for label in labels]
        rows.append(f"| {name} ({first['models']}, {first['n']}) | " + " | ".join(cells) + " |")
    return rows


def test_one_model_second_run_tables():
    """docs/studies/one-model.md's second run: every test row and the real-set rows from their results files."""
    doc = "docs/studies/one-model.md"
    rep = _json("models/one_model_second.json")
    for row in _one_model_rows(
        rep, lambda v: f"{v['accuracy']:.5f} / {v['completeness']:.5f} / {100 * v['inside']:.1f}%"
    ):
        _says(doc, row)
    real = _json("models/one_model_real.json")
    for set_name, models in real.items():
        for cls in models["second-run"]:
            cells = [
                f"{100 * m[cls]['inside_box']:.1f}% / {m[cls]['fidelity']:.4f} / {m[cls]['consistency_voxel']:.4f}"
                for m in models.values()
            ]
            _says(doc, f"| {set_name} {cls} ({models['second-run'][cls]['objects']}) | " + " | ".join(cells) + " |")


def test_one_model_second_run_prose():
    """The verdict's numbers of docs/studies/one-model.md's second run, computed from its results files."""
    doc = "docs/studies/one-model.md"
    rep = _json("models/one_model_second.json")
    t = rep["test"]
    cars, dflt, kenney = (
        t["second-run"]["apolloscape-cars"],
        t["default"]["apolloscape-cars"],
        t["second-run"]["kenney-test"],
    )
    _says(doc, f"accuracy is **{cars['accuracy']:.5f}**")
    _says(doc, f"**{100 * (cars['completeness'] / dflt['completeness'] - 1):.1f}% worse than the default's**")
    _says(doc, f"**not met: {kenney['accuracy'] / cars['accuracy']:.2f}x**")
    _says(doc, f"completeness within 1.4x not met ({kenney['completeness'] / cars['completeness']:.2f}x)")
    trailer = rep["domains"]["second-run"]["trailer"]
    _says(doc, f"**trailers {trailer[0]:.1f}-{trailer[1]:.1f} m**")
    curve = rep["learning_curve"]
    _says(
        doc, f"**{int(curve[-1]['global_step']):,} steps in {curve[-1]['wall_seconds'] / 60:.1f} minutes of training**"
    )
    shown = [r for r in curve if int(r["epoch"]) % 4 == 0 or int(r["epoch"]) in (1, len(curve))]
    _says(doc, "| val CD-L1 | " + " | ".join(f"{r['val_chamfer_l1']:.5f}" for r in shown) + " |")
    assert all(r["status"] == "completed" and r["inside_box"] >= 0.99 for r in rep["trucks"]["results"]["second-run"])
    assert all(r["status"] == "completed" and r["inside_box"] >= 0.99 for r in rep["trailers"]["results"]["second-run"])


def test_one_model_first_run_table():
    """docs/studies/one-model.md's first-run table (bold marks aside) from results/models/one_model.json."""
    rep = _json("models/one_model.json")
    text = _text(REPO / "docs/studies/one-model.md").replace("**", "")

    def share(x: float) -> str:
        return "100%" if round(100 * x, 1) == 100.0 else f"{100 * x:.1f}%"

    for group, name in ONE_MODEL_GROUPS:
        first = rep["test"]["default"][group]
        cells = [
            f"{v['accuracy']:.5f} / {v['completeness']:.5f} / {share(v['inside'])}"
            for v in (rep["test"][label][group] for label in rep["checkpoints"])
        ]
        row = f"| {name} ({first['models']}, {first['n']}) | " + " | ".join(cells) + " |"
        assert row in text, row


def test_one_model_fallback_swap_table_and_latency():
    """docs/studies/one-model.md's fresh scores of the class-fallback swap, from their results files; the rule's
    points that the files decide hold."""
    doc = "docs/studies/one-model.md"
    rep = _json("models/fallback_fresh_set.json")
    old, new = rep["test"]["classes"], rep["test"]["one-model"]
    for cls in ("car", "caravan", "truck", "bus", "trailer"):
        a, b = old[f"procedural/{cls}"], new[f"procedural/{cls}"]
        cells = [f"{v['accuracy']:.5f} / {v['completeness']:.5f} / {100 * v['inside']:.1f}%" for v in (a, b)]
        _says(doc, f"| procedural {cls} ({a['models']}, {a['n']}) | " + " | ".join(cells) + " |")
        assert b["accuracy"] <= a["accuracy"] and b["inside"] >= a["inside"] - 0.005  # rule points 1 and 2
    for key in ("trucks", "trailers"):  # rule point 3
        assert all(r["status"] == "completed" and r["inside_box"] >= 0.95 for r in rep[key]["results"]["one-model"])
    lat = _json("models/fallback_onnx_latency.json")
    ms = lat["cpu_ms_per_scan"]["32"]
    _says(
        doc,
        f"{ms['one-model']:.2f} against {ms['classes']:.2f} ms a scan at batch 32 (**{lat['ratio_to_first']['32']['one-model']:.2f}x**)",
    )
    assert lat["ratio_to_first"]["32"]["one-model"] <= 1.5  # rule point 4


def test_one_model_car_weighted_tables():
    """docs/studies/one-model.md's car-weighted candidate: its test table, verdict and real-set car rows from their
    results files; the verdict's direction holds."""
    doc = "docs/studies/one-model.md"
    rep = _json("models/one_model_car_weighted.json")
    for row in _one_model_rows(rep, lambda v: f"{v['accuracy']:.5f} / {v['completeness']:.5f}"):
        _says(doc, row)
    cars, dflt = rep["test"]["car-weighted"]["apolloscape-cars"], rep["test"]["default"]["apolloscape-cars"]
    worse = 100 * (cars["completeness"] / dflt["completeness"] - 1)
    assert worse > 2.0  # "it does not become the single default"
    _says(doc, f"**{worse:.1f}% worse than the default's** (2% allowed)")
    for cls in ("car", "caravan", "truck", "bus", "trailer"):  # "a little less accurate than the second run"
        g = f"procedural/{cls}"
        assert rep["test"]["car-weighted"][g]["accuracy"] > rep["test"]["second-run"][g]["accuracy"]
    curve = " / ".join(f"{r['val_chamfer_l1']:.5f}" for r in rep["learning_curve"])
    _says(doc, f"the union's val split {curve} after each 1,000 steps")
    real = _json("models/one_model_car_weighted_real.json")
    for set_name, models in real.items():
        cells = [f"{m['car']['fidelity']:.4f} / {m['car']['consistency_voxel']:.4f}" for m in models.values()]
        _says(doc, f"| {set_name} car ({models['car-weighted']['car']['objects']}) | " + " | ".join(cells) + " |")


def test_one_model_decoder_control_table():
    """docs/studies/one-model.md's decoder control: its table and curves from its results file, and the claim that
    the two decoders stay within 3% of each other on every group."""
    doc = "docs/studies/one-model.md"
    rep = _json("models/decoder_control.json")
    for row in _one_model_rows(rep, lambda v: f"{v['accuracy']:.5f} / {v['completeness']:.5f}"):
        _says(doc, row)
    for label, name in (("plain-decoder", "plain"), ("viewpoint-decoder", "viewpoint")):
        curve = " / ".join(f"{r['val_chamfer_l1']:.5f}" for r in rep["learning_curves"][label])
        _says(doc, f"{name} {curve}")
    plain, view = rep["test"]["plain-decoder"], rep["test"]["viewpoint-decoder"]
    for group, _ in ONE_MODEL_GROUPS:
        for metric in ("accuracy", "completeness"):
            assert abs(view[group][metric] / plain[group][metric] - 1) < 0.03, (group, metric)
        assert view[group]["completeness"] <= plain[group]["completeness"]  # "a little more complete everywhere"
