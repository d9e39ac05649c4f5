"""Ship ONNX exports of the packaged checkpoints beside them, for the light runtime (``--runtime auto``).

    python scripts/ship_onnx.py                    # default and classes
    python scripts/ship_onnx.py --name default

For each short name, writes ``src/spotlights/learning/pretrained/NAME.onnx``: the ``spotlights export`` of
``NAME.pt`` (class-conditioned models with their ``classes`` input) whose float32 weights are stored as the
float16 numbers they are (``halve_weights``: a float16 initializer and a cast back, no weight changes), then
checks it:

* its size (refused above ``--max-mb``, default 9);
* the largest difference of every graph output, onnxruntime against the torch checkpoint, on 8 seeded random
  scans (every class row of a class model in turn, and no class), refused above ``--tolerance`` (default 1e-4),
  and no ray kept by one and not the other.

The file records ``checkpoint`` as the short name (not where the package lies), so the same checkpoint gives
the same bytes on every machine. Nothing is written when a check fails.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path

PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "src" / "spotlights" / "learning" / "pretrained"
NAMES = ("default", "classes")


def ship(name: str, out_dir: Path, max_mb: float, tolerance: float) -> int:
    import onnx

    from spotlights.learning.export import export_onnx, halve_weights, load_onnx_completer, parity

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.onnx"
        export_onnx(name, path)
        proto = onnx.load(str(path))
        n = halve_weights(proto)
        for entry in proto.metadata_props:
            if entry.key == "checkpoint":
                entry.value = name
        onnx.checker.check_model(proto)
        onnx.save(proto, str(path))
        size_mb = path.stat().st_size / 1e6
        diff = parity(name, load_onnx_completer(path))
        print(
            f"{name}: {size_mb:.2f} MB ({n} weight tensors stored as float16); max |onnxruntime - torch| on 8 "
            "scans: " + ", ".join(f"{k} {v:.1e}" for k, v in diff.items())
        )
        if size_mb > max_mb:
            print(f"refused: {size_mb:.1f} MB is more than --max-mb {max_mb:g}", file=sys.stderr)
            return 2
        worst = max(v for k, v in diff.items() if k != "kept_rays_differ")
        if worst > tolerance or diff.get("kept_rays_differ", 0):
            print(f"refused: onnxruntime differs from torch by more than --tolerance {tolerance:g}", file=sys.stderr)
            return 2
        out = out_dir / f"{name}.onnx"
        out.write_bytes(path.read_bytes())
    print(f"-> {out} (sha256 {hashlib.sha256(out.read_bytes()).hexdigest()[:16]}...)")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--name", nargs="+", default=list(NAMES), choices=NAMES, help="short names (default: both)")
    ap.add_argument("--max-mb", type=float, default=9.0, help="refuse a file larger than this (default 9 MB)")
    ap.add_argument("--tolerance", type=float, default=1e-4, help="largest output difference, onnxruntime vs torch")
    ap.add_argument("--out-dir", default=str(PRETRAINED_DIR), help="where to write NAME.onnx (default: the package)")
    args = ap.parse_args()
    for name in args.name:
        rc = ship(name, Path(args.out_dir), args.max_mb, args.tolerance)
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
