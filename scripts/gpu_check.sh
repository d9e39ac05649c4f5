#!/usr/bin/env bash
# The test suite where CUDA is (docs/studies/gpu.md, "The inference paths on CUDA"): CI never has a GPU, and every
# completion path defaults to CUDA when it is there, so run this once whenever a GPU machine is lent:
#   scripts/gpu_bundle.sh --tests           # here, with PyPI: the wheels the GPU image lacks, into .whl/
#   scripts/gpu_check.sh [PYTEST ARGS]      # there, from the checkout's root, .whl/ carried beside it
# Default PYTEST ARGS: the whole suite on 12 processes by file (-n 12 --dist loadfile, as make test: the README
# commands' test shares one folder), 300 s a test. It installs the carried wheels the
# machine lacks (as scripts/gpu_train.sh does), puts the checkout's src/ first, prints the device, runs pytest
# with CUDA visible and writes the log and a JUnit XML to $OUT (or ./gpu-check). Tests that need the shared data
# or an optional extra the image lacks skip with their reason. Exit status: pytest's.
set -uo pipefail
cd "$(dirname "$0")/.." || exit 2
PY=${PYTHON:-python3}
BUNDLE=${GPU_BUNDLE:-.whl}
SITE=${GPU_SITE:-${TMPDIR:-/tmp}/spotlights-site}
DEST=${OUT:-gpu-check}
mkdir -p "$DEST" || exit 2
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
NEEDED="import numpy, h5py, yaml, tqdm, trimesh, pykdtree, rtree, pypcd4, scipy, pytest, xdist, pytest_timeout"
if ! "$PY" -c "$NEEDED" 2>/dev/null; then
    if ! ls "$BUNDLE"/*.whl >/dev/null 2>&1; then
        echo "gpu_check.sh: error: packages are missing ($NEEDED failed) and $BUNDLE holds no wheels (scripts/gpu_bundle.sh --tests)" >&2
        exit 2
    fi
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$BUNDLE"/*.whl \
        || { echo "gpu_check.sh: error: installing the wheels of $BUNDLE failed" >&2; exit 2; }
    export PYTHONPATH="$PWD/src:$SITE${PYTHONPATH#"$PWD/src"}"
    "$PY" -c "$NEEDED" || { echo "gpu_check.sh: error: still missing after installing $BUNDLE: $NEEDED" >&2; exit 2; }
fi
"$PY" -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')" \
    | tee "$DEST/gpu_check.log"
if [ $# -eq 0 ]; then set -- tests -n 12 --dist loadfile --timeout 300; fi
"$PY" -m pytest -q -p no:cacheprovider -rfs --junitxml "$DEST/gpu_check.xml" "$@" 2>&1 | tee -a "$DEST/gpu_check.log"
exit "${PIPESTATUS[0]}"
