"""``spotlights real complete``: the per-frame loop (resumable), its files and its summary."""

from __future__ import annotations

import hashlib
import json
import os
import re
import time
from collections import Counter
from dataclasses import asdict
from pathlib import Path

from tqdm import tqdm

from ..errors import SpotlightsError
from ..experiments.scene import complete_scene, render_result, render_result_html, write_scene
from ..utils import atomic_output, sweep_folder_temporaries
from ..viz.html import write_plotlyjs
from .complete import warn


def safe_name(text: str) -> str:
    """``text`` as a file name: runs of characters other than letters, digits, ``.``, ``_`` and ``-`` become ``_``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("._") or "frame"


#: Files of the run itself in the output folder, and what each frame adds to its stem.
RUN_FILES = ("summary.json", "plotly.min.js")
FRAME_SUFFIXES = (".ply", ".png", ".html", ".json", "_objects")


def _digest(text) -> str:
    return hashlib.sha256(str(text).encode("utf-8", "surrogatepass")).hexdigest()[:8]


def file_stem(text) -> str:
    """``text`` (a frame id, a sequence name) as a file name that no other text maps to: :func:`safe_name`,
    plus ``-`` and 8 hex digits of the SHA-256 of ``text`` when sanitising changed it (``../a`` -> ``a-3b1d...``,
    ``汽车`` -> ``frame-...``, a name of over 100 characters cut there); a safe name is kept as it is
    (``000123``, ``scene-0523``)."""
    name = safe_name(text)[:100]
    return name if name == str(text) else f"{name}-{_digest(text)}"


def _unique(texts, reserved=()) -> dict[str, str]:
    """{text: file name}: :func:`file_stem` of each, with the digest added as well to names that would
    coincide with another or with ``reserved`` when letter case is ignored (macOS, Windows)."""
    names = {t: file_stem(t) for t in texts}
    count = Counter(n.casefold() for n in names.values())
    taken = {r.casefold() for r in reserved}
    out = {
        t: f"{safe_name(t)[:100]}-{_digest(t)}" if count[n.casefold()] > 1 or n.casefold() in taken else n
        for t, n in names.items()
    }
    if len({n.casefold() for n in out.values()} | taken) != len(out) + len(taken):
        raise SpotlightsError("frame or sequence names map to one output file; rename them")  # needs a SHA-256 clash
    return out


def frame_stems(keys) -> dict[tuple, Path]:
    """The output stem of each frame key ``(sequence, frame_id)``, relative to the output folder:
    ``SEQUENCE/FRAME`` (``FRAME`` without a sequence). Distinct frames never share a file, none is a file of
    the run (``summary.json``); a frame's name depends on the other frames only when two names differ in
    letter case alone (``A`` and ``a`` both take the digest)."""
    seqs = _unique(sorted({str(s) for s, _ in keys if s}), reserved=RUN_FILES)
    # a frame beside the sequence folders must not take a folder's name with one of its suffixes
    beside = [d[: -len(x)] for d in seqs.values() for x in FRAME_SUFFIXES if d.endswith(x)]
    by_seq: dict[str, list[str]] = {}
    for s, f in keys:
        by_seq.setdefault(str(s) if s else "", []).append(str(f))
    stems = {}
    for s, fids in by_seq.items():
        names = _unique(fids, reserved=() if s else ["summary", *beside])
        stems.update({(s, f): Path(seqs[s]) / names[f] if s else Path(names[f]) for f in fids})
    return {(s, f): stems[(str(s) if s else "", str(f))] for s, f in keys}


def _with(stem: Path, suffix: str) -> Path:
    """``stem`` + ``suffix`` (not ``with_suffix``: a frame id ``x.1`` keeps its ``.1``)."""
    return stem.parent / (stem.name + suffix)


def complete_frames(args, reader, keys, config, completer, out, tracks=None) -> int:
    """Complete the frames ``keys`` of ``reader`` into the folder ``out`` (the options of ``real complete`` in
    ``args``): per frame a PLY (+ PNG, HTML, per-object files) and, written last, its JSON summary (``--resume``
    skips frames whose JSON says the same model and options); then ``summary.json`` and one line on stdout.
    ``tracks``: a built :class:`spotlights.experiments.tracks.TrackPlan` (``--fuse``): its boxes and fused
    inputs are completed, and its per-track files written."""
    checkpoint = args.checkpoint or "default"
    out = Path(out)
    sweep_folder_temporaries(out)  # what a killed run was writing (a 0-byte .FRAME.png.PID-X.part.png)
    frames, warnings = [], []
    totals = {"boxes": 0, "completed": 0, "flipped": 0, "completion_points": 0, "skipped": {}, "resumed": 0}
    t_model = 0.0
    t0 = time.perf_counter()
    stems = frame_stems(keys)
    for key in tqdm(keys, desc="complete", unit="frame", disable=args.quiet):
        seq, fid = key
        stem = out / stems[key]
        summ = done_frame(_with(stem, ".json"), config, completer.model_name, checkpoint) if args.resume else None
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
            result = complete_scene(
                frame.points,
                boxes,
                completer,
                config,
                checkpoint=checkpoint,
                sensor=frame.lidar_origin(),
                extra_points=extra,
            )
            if tracks is not None:
                tracks.record(key, result)
            write_scene(
                result,
                _with(stem, ".ply"),
                per_object=_with(stem, "_objects") if args.per_object else None,
                scan_name=Path(frame.scan_path).name,
            )
            prefix = f"{frame.sequence}/" if frame.sequence else ""
            if not args.no_pictures and result.completed:
                render_result(result, _with(stem, ".png"), f"{reader.format} {prefix}{frame.frame_id}: {result.model}")
            if args.html:
                js = os.path.relpath(write_plotlyjs(out), stem.parent).replace(os.sep, "/")
                render_result_html(
                    result, _with(stem, ".html"), f"{reader.format} {prefix}{frame.frame_id}: {result.model}", js
                )
            summ = {**info, "ply": str(_with(stem, ".ply")), **result.summary()}
            if frame.sensor_to_world is not None:
                summ["sensor_to_world"] = [[float(v) for v in row] for row in frame.sensor_to_world]
            with atomic_output(_with(stem, ".json")) as tmp:  # written last: a frame with its JSON is done (--resume)
                tmp.write_text(json.dumps(summ, indent=2, default=float) + "\n", encoding="utf-8")
        done = [o for o in summ["objects"] if o["status"] == "completed"]
        totals["boxes"] += summ["n_boxes"]
        totals["completed"] += summ["n_completed"]
        totals["flipped"] += summ["n_flipped"]
        totals["completion_points"] += sum(o["n_completion"] for o in done)
        for k, v in summ["skipped"].items():
            totals["skipped"][k] = totals["skipped"].get(k, 0) + v
        for k, v in summ.get("not_completed", {}).items():  # boxes the model did not learn, per class
            totals.setdefault("not_completed", {})[k] = totals.get("not_completed", {}).get(k, 0) + v
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
        + (" (not_learned: left as observed points; --complete-unknown completes them)" if "not_learned" in sk else "")
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
