#!/usr/bin/env bash
# The GPU recipe (docs/training.md, "GPU recipe"):
#   scripts/gpu_train.sh MODEL_CONFIG [MINUTES] [options of scripts/gpu_train.py]
# MODEL_CONFIG: 'default' (the default model's configuration), a registered model name (snowflakenet, foldingnet, ...)
# or a YAML config; MINUTES: the time budget of the whole run (default 7, or $GPU_MINUTES).
# On a machine without internet it first installs the Python packages it lacks from the wheels carried in .whl/
# (made here by scripts/gpu_bundle.sh = make gpu-bundle; never torch) and unpacks the carried meshes
# (.whl/meshes.tar.xz into $GPU_MESH_DIR, default $TMPDIR/spotlights-meshes: apolloscape-cars/ is the default --meshes,
# kenney-vehicles/ for --source), then builds the training set from the
# carried meshes, measures the step time and trains what fits, on CUDA with bf16 autocast; checkpoint, log,
# config and plan.json go to $OUT (or --out). The checkout's own code (src/) is used before any installed copy.
set -uo pipefail
cd "$(dirname "$0")/.." || exit 2
if [ $# -lt 1 ] || [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
    echo "usage: scripts/gpu_train.sh MODEL_CONFIG [MINUTES] [--cpu] [--out DIR] [--views N] ... (scripts/gpu_train.py --help)" >&2
    [ $# -ge 1 ] && exit 0
    exit 2
fi
PY=${PYTHON:-python3}
BUNDLE=${GPU_BUNDLE:-.whl}
SITE=${GPU_SITE:-${TMPDIR:-/tmp}/spotlights-site}
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
NEEDED="import numpy, h5py, yaml, tqdm, trimesh, embreex, pykdtree, scipy"  # torch: the machine's own
if ! "$PY" -c "$NEEDED" 2>/dev/null; then
    if ! ls "$BUNDLE"/*.whl >/dev/null 2>&1; then
        echo "gpu_train.sh: error: packages are missing ($NEEDED failed) and $BUNDLE holds no wheels (run scripts/gpu_bundle.sh where PyPI is reachable and carry $BUNDLE)" >&2
        exit 2
    fi
    echo "gpu_train.sh: installing the carried wheels of $BUNDLE into $SITE"
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$BUNDLE"/*.whl \
        || { echo "gpu_train.sh: error: installing the wheels of $BUNDLE failed" >&2; exit 2; }
    export PYTHONPATH="$PWD/src:$SITE${PYTHONPATH#"$PWD/src"}"
    "$PY" -c "$NEEDED" || { echo "gpu_train.sh: error: still missing after installing $BUNDLE: $NEEDED" >&2; exit 2; }
fi
MESH_DIR=${GPU_MESH_DIR:-${TMPDIR:-/tmp}/spotlights-meshes}  # the carried meshes, packed by gpu_bundle.sh, unpacked
if [ -f "$BUNDLE/meshes.tar.xz" ] && [ ! -d "$MESH_DIR" ]; then  # here, outside the checkout (it travels: keep it small)
    mkdir -p "$MESH_DIR.tmp" && tar -C "$MESH_DIR.tmp" -xJf "$BUNDLE/meshes.tar.xz" && mv "$MESH_DIR.tmp" "$MESH_DIR" \
        || { echo "gpu_train.sh: error: unpacking $BUNDLE/meshes.tar.xz into $MESH_DIR failed" >&2; rm -rf "$MESH_DIR.tmp"; exit 2; }
fi
export GPU_MESH_DIR="$MESH_DIR"  # gpu_train.py finds --source kenney-vehicles,... there
if [ -z "${GPU_MESHES:-}" ] && [ -d "$MESH_DIR/apolloscape-cars" ]; then
    export GPU_MESHES="$MESH_DIR/apolloscape-cars"
fi
exec "$PY" scripts/gpu_train.py "$@"
