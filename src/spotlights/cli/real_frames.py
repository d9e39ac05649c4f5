"""``spotlights real complete``: the per-frame loop (resumable), its files and its summary."""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import asdict
from pathlib import Path

from tqdm import tqdm

from ..experiments.scene import complete_scene, render_result, render_result_html, write_scene
from ..utils import atomic_output
from ..viz.html import write_plotlyjs
from .complete import warn


def safe_name(text: str) -> str:
    """``text`` as a file name: runs of characters other than letters, digits, ``.``, ``_`` and ``-`` become ``_``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("._") or "frame"


def complete_frames(args, reader, keys, config, completer, out, tracks=None) -> int:
    """Complete the frames ``keys`` of ``reader`` into the folder ``out`` (the options of ``real complete`` in
    ``args``): per frame a PLY (+ PNG, HTML, per-object files) and, written last, its JSON summary (``--resume``
    skips frames whose JSON says the same model and options); then ``summary.json`` and one line on stdout.
    ``tracks``: a built :class:`spotlights.experiments.tracks.TrackPlan` (``--fuse``): its boxes and fused
    inputs are completed, and its per-track files written."""
    checkpoint = args.checkpoint or "default"
    out = Path(out)
    frames, warnings = [], []
    totals = {"boxes": 0, "completed": 0, "flipped": 0, "completion_points": 0, "skipped": {}, "resumed": 0}
    t_model = 0.0
    t0 = time.perf_counter()
    for key in tqdm(keys, desc="complete", unit="frame", disable=args.quiet):
        seq, fid = key
        stem = (out / safe_name(seq) if seq else out) / safe_name(fid)
        summ = done_frame(stem.with_suffix(".json"), config, completer.model_name, checkpoint) if args.resume else None
        if summ is not None:
            totals["resumed"] += 1
        else:
            frame = reader.load(key)
            info = dict(
                sequence=frame.sequence,
                frame_id=frame.frame_id,
                timestamp=frame.timestamp,
                scan=frame.scan_path,
                labels=frame.label_path,
            )
            if len(frame.points) < config.min_points:
                frames.append(
                    {**info, "status": f"scan holds {len(frame.points)} points (< {config.min_points}): not completed"}
                )
                continue
            boxes, extra = (frame.boxes, None) if tracks is None else tracks.frame_inputs(key, frame.boxes)
            result = complete_scene(frame.points, boxes, completer, config, checkpoint=checkpoint, extra_points=extra)
            if tracks is not None:
                tracks.record(key, result)
            write_scene(
                result,
                stem.with_suffix(".ply"),
                per_object=stem.parent / (stem.name + "_objects") if args.per_object else None,
                scan_name=Path(frame.scan_path).name,
            )
            prefix = f"{frame.sequence}/" if frame.sequence else ""
            if not args.no_pictures and result.completed:
                render_result(
                    result, stem.with_suffix(".png"), f"{reader.format} {prefix}{frame.frame_id}: {result.model}"
                )
            if args.html:
                js = os.path.relpath(write_plotlyjs(out), stem.parent).replace(os.sep, "/")
                render_result_html(
                    result, stem.with_suffix(".html"), f"{reader.format} {prefix}{frame.frame_id}: {result.model}", js
                )
            summ = {**info, "ply": str(stem.with_suffix(".ply")), **result.summary()}
            if frame.sensor_to_world is not None:
                summ["sensor_to_world"] = [[float(v) for v in row] for row in frame.sensor_to_world]
            with atomic_output(
                stem.with_suffix(".json")
            ) as tmp:  # written last: a frame with its JSON is done (--resume)
                tmp.write_text(json.dumps(summ, indent=2, default=float) + "\n", encoding="utf-8")
        done = [o for o in summ["objects"] if o["status"] == "completed"]
        totals["boxes"] += summ["n_boxes"]
        totals["completed"] += summ["n_completed"]
        totals["flipped"] += summ["n_flipped"]
        totals["completion_points"] += sum(o["n_completion"] for o in done)
        for k, v in summ["skipped"].items():
            totals["skipped"][k] = totals["skipped"].get(k, 0) + v
        t_model += summ["timings"].get("total_s", 0.0)
        warnings += [f"{seq + '/' if seq else ''}{fid} {w}" for w in summ["warnings"]]
        frames.append(
            {
                k: summ.get(k)
                for k in (
                    "sequence",
                    "frame_id",
                    "timestamp",
                    "scan",
                    "ply",
                    "n_boxes",
                    "n_completed",
                    "n_flipped",
                    "skipped",
                )
            }
            | {"n_warnings": len(summ["warnings"])}
        )
    summary = dict(
        source=[str(s) for s in args.source],
        format=reader.format,
        model=completer.model_name,
        checkpoint=checkpoint,
        n_frames=len(keys),
        totals=totals,
        heading_check=config.heading_check,
        completion_seconds=t_model,
        wall_seconds=time.perf_counter() - t0,
        warnings=warnings,
        frames=frames,
    )
    if tracks is not None:
        tracks.write(out, completer.model_name)
        summary["tracks"] = {k: v for k, v in tracks.summary().items() if k != "tracks"}
    with atomic_output(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2, default=float) + "\n", encoding="utf-8")
    if len(warnings) > 10:
        warn(warnings[:5] + [f"... and {len(warnings) - 5} more out-of-domain boxes (see {out / 'summary.json'})"])
    else:
        warn(warnings)
    flips = f", {totals['flipped']} heading flip(s)" if config.heading_check else ""
    sk = ", ".join(f"{k} {v}" for k, v in sorted(totals["skipped"].items()))
    resumed = f"; {totals['resumed']} frame(s) already done" if totals["resumed"] else ""
    print(
        f"{len(keys)} frame(s), {totals['boxes']} boxes: {totals['completed']} completed{flips}"
        + (f", skipped {sk}" if sk else "")
        + f" ({completer.model_name}, {t_model:.1f} s of completion{resumed}) -> {out}/"
    )
    return 0


def done_frame(path, config, model: str, checkpoint: str):
    """The summary of a frame finished by an earlier run with the same model and options, else None."""
    try:
        summ = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    cfg = asdict(config)
    cfg["clip"] = str(cfg["clip"]) if cfg["clip"] is not None and not isinstance(cfg["clip"], float) else cfg["clip"]
    same = (
        summ.get("model") == model
        and summ.get("checkpoint") == checkpoint
        and json.loads(json.dumps(cfg)) == summ.get("config")
    )
    return summ if same else None
