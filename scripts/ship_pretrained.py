"""Ship a trained checkpoint inside the package as a short name (``default`` or ``paper``).

    python scripts/ship_pretrained.py runs/sanet-hit-dense/best.pt --name default
    python scripts/ship_pretrained.py runs/sanet/best.pt --name paper --data cars.h5

Writes ``src/spotlights/learning/pretrained/NAME.pt``: the inference-only checkpoint
(no optimizer, schedule or scaler state) with float16 weights
(``spotlights.learning.checkpoint.export_weights(half=True)``), then checks it:

* its size (a few MB: refused above ``--max-mb``, default 10);
* it loads by path and completes like the float32 checkpoint: the largest difference of the
  raw outputs (depths, hit probabilities or points) on ``--scans`` scans (the test split of
  ``--data`` when given, else seeded random clouds), reported and refused above ``--tolerance``;
* the number of kept points per completion, float16 against float32.

A checkpoint trained before training recorded its domain (the classes and box sizes it
learned, ``checkpoint["domain"]``, read by ``LearnedDomain``) gets it here from the train split
of the dataset it was trained on (``--domain-data``, default the path the checkpoint records).

It prints the line of ``PRETRAINED`` (``spotlights/learning/checkpoint.py``) that makes the
short name resolve to the new file and the facts for ``pretrained/README.md`` (model, rig,
parameters, steps, best epoch, threshold, sha256, size). Nothing is written when a check fails.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path

import numpy as np

PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "src" / "spotlights" / "learning" / "pretrained"


def _scans(data: str | None, n: int):
    """(n, 256, 3) float32 unit-frame partial scans and (n, 3) box half-extents (test split of ``data``, else random)."""
    if data:
        from spotlights.learning.data import TorchCompletionDataset

        ds = TorchCompletionDataset(data, "test", rig=False, partials_in_memory=False)
        idx = np.linspace(0, len(ds) - 1, n).astype(int)
        items = [ds[int(i)] for i in idx]
        x = np.stack([it["partial"].numpy() for it in items]).astype(np.float32)
        e = ds.extents[[int(it["model"]) for it in items]] if ds.extents is not None else None
        return x, e
    x = (np.random.default_rng(0).normal(size=(n, 256, 3)) * 0.3).astype(np.float32)
    from spotlights.geometry.boxes import unit_extents
    from spotlights.learning.rays import TIMING_BOX_SIZE

    return x, np.tile(unit_extents(TIMING_BOX_SIZE), (n, 1))


def _raw(completer, x, e):
    import torch

    with torch.inference_mode():
        out = completer.model(torch.from_numpy(x))
    if "hit_logits" in out:
        return {"depths": out["depths"].numpy(), "p_hit": torch.sigmoid(out["hit_logits"]).numpy()}
    return {k: v.numpy() for k, v in out.items()}


def main() -> int:
    from spotlights.learning.checkpoint import PRETRAINED, export_weights, load_checkpoint, save_checkpoint
    from spotlights.learning.domain import LearnedDomain
    from spotlights.learning.inference import load_completer

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint", help="trained checkpoint (RUN/best.pt)")
    ap.add_argument("--name", required=True, choices=sorted(PRETRAINED), help="short name to ship it as")
    ap.add_argument(
        "--data", default=None, help="dataset whose test scans check the float16 copy (default: random clouds)"
    )
    ap.add_argument("--scans", type=int, default=64, help="scans for the check (default 64)")
    ap.add_argument("--max-mb", type=float, default=10.0, help="refuse a file larger than this (default 10 MB)")
    ap.add_argument("--tolerance", type=float, default=2e-2, help="largest raw output difference float16 vs float32")
    ap.add_argument(
        "--domain-data",
        default=None,
        help="dataset the checkpoint was trained on, for a checkpoint without a domain record "
        "(default: the path recorded in the checkpoint)",
    )
    ap.add_argument("--out-dir", default=str(PRETRAINED_DIR), help="where to write NAME.pt (default: the package)")
    args = ap.parse_args()

    src = load_checkpoint(args.checkpoint)
    with tempfile.TemporaryDirectory() as tmp:
        half = Path(tmp) / f"{args.name}.pt"
        export_weights(args.checkpoint, half, half=True)
        if not isinstance(src.get("domain"), dict):
            ddata = args.domain_data or (src.get("dataset") or {}).get("path")
            if not ddata or not Path(ddata).exists():
                print(
                    f"refused: {args.checkpoint} records no domain and its training data {ddata!r} is not here "
                    "(pass --domain-data)",
                    file=sys.stderr,
                )
                return 2
            shipped = load_checkpoint(half)
            shipped["domain"] = LearnedDomain.from_dataset(ddata).to_dict()
            save_checkpoint(half, {k: v for k, v in shipped.items() if k != "path"})
            print(f"domain from {ddata}: {shipped['domain']}")
        size_mb = half.stat().st_size / 1e6
        ref, new = load_completer(args.checkpoint, device="cpu"), load_completer(half, device="cpu")
        x, e = _scans(args.data, args.scans)
        a, b = _raw(ref, x, e), _raw(new, x, e)
        diffs = {k: float(np.abs(a[k] - b[k]).max()) for k in a}
        kw = {"extents": e} if ref.needs_box else {}
        n_ref = [len(c) for c in ref.complete(x, **kw)]
        n_new = [len(c) for c in new.complete(x, **kw)]
        print(
            f"{args.checkpoint} -> {args.name}.pt: {size_mb:.2f} MB (float16), {ref.model_name}, "
            f"{ref.n_params:,} parameters; max |float16 - float32| on {len(x)} scans: "
            + ", ".join(f"{k} {v:.2e}" for k, v in diffs.items())
            + f"; points per completion {np.mean(n_ref):.1f} (float32) vs {np.mean(n_new):.1f} (float16)"
        )
        if size_mb > args.max_mb:
            print(
                f"refused: {size_mb:.1f} MB is more than --max-mb {args.max_mb:g} (a smaller decoder, e.g. "
                "model.args.hidden [256, 64], shrinks a dense rig's last layer)",
                file=sys.stderr,
            )
            return 2
        if max(diffs.values()) > args.tolerance:
            print(f"refused: the float16 copy differs by more than --tolerance {args.tolerance:g}", file=sys.stderr)
            return 2
        out = Path(args.out_dir) / f"{args.name}.pt"
        out.write_bytes(half.read_bytes())
    sha = hashlib.sha256(out.read_bytes()).hexdigest()
    best = src.get("best") or {}
    thr = (src.get("hit_threshold") or {}).get("value")
    print(f"-> {out} (sha256 {sha[:16]}...)")
    print(f"PRETRAINED[{args.name!r}] = {out.name!r}   # in src/spotlights/learning/checkpoint.py")
    print(
        f"README facts: model {src['model_name']}, rig {(src.get('dataset') or {}).get('rig')}, "
        f"{src.get('param_counts', {}).get('total', 0):,} parameters, {src.get('global_step')} steps, "
        f"{src.get('epoch')} epochs, best epoch {best.get('epoch')} ({best.get('select_by')} {best.get('value')})"
        + (f", p(hit) threshold {thr:g}" if thr is not None else "")
        + f", precision {src.get('precision', 'fp32')}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
