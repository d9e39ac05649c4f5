#!/usr/bin/env bash
# Prepare, on a machine with PyPI, what scripts/gpu_train.sh needs on a GPU machine without internet
# (docs/training.md, "GPU recipe"): into .whl/ (git-ignored; carry it to the GPU machine)
#   - not the project's own wheel: gpu_train.sh runs the checkout's src/ (the wheel, with its pretrained
#     checkpoints, would push the call past the 64 MiB a device call carries),
#   - the wheels of the dependencies of the recipe that the GPU image lacks (trimesh, embreex, pykdtree; its image
#     has numpy, scipy, h5py, pyyaml, tqdm and torch), at the versions installed here, for the GPU machine's Python
#     (GPU_PYTHON_VERSION, default 3.12) on x86-64 manylinux; never torch,
#   - the ApolloScape car meshes and the Kenney vehicles (the one model's union takes their training split) from
#     ../shared/data, as one xz archive .whl/meshes.tar.xz (4 MB; gpu_train.sh unpacks it outside the checkout).
# Then it checks that the checkout's tracked and untracked files and .whl/ together stay under the 64 MiB a device
# call carries (exit 1, saying by how much, when they do not).
# Usage: scripts/gpu_bundle.sh            (or: make gpu-bundle): for scripts/gpu_train.sh
#        scripts/gpu_bundle.sh --tests    for scripts/gpu_check.sh (the test suite there): the wheels of the
#                                          packages the tests import too (rtree, pypcd4 and its needs), no meshes
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
DEST=${GPU_BUNDLE:-.whl}
PYV=${GPU_PYTHON_VERSION:-3.12}
MESHES=${GPU_MESHES:-../shared/data/meshes/apolloscape-cars}
KENNEY=${GPU_KENNEY:-../shared/data/meshes/kenney-vehicles}
LIMIT=$((64 * 1024 * 1024))
TESTS=0
[ "${1:-}" = "--tests" ] && TESTS=1
STAGE=$(mktemp -d "${TMPDIR:-/tmp}/gpu-bundle.XXXXXX")  # outside the checkout: it would count as travelling
trap 'rm -rf "$STAGE"' EXIT
pins=$(TESTS=$TESTS "$PY" - <<'PY'
import os
from importlib.metadata import version
names = ["trimesh", "embreex", "pykdtree"]
if os.environ["TESTS"] == "1":
    names += ["rtree", "pypcd4", "python-neo-lzf", "pydantic", "pydantic-core", "annotated-types", "typing-inspection"]
print(" ".join(f"{n}=={version(n)}" for n in names))
PY
)
platforms=""
for n in 17 27 28; do platforms="$platforms --platform manylinux_2_${n}_x86_64"; done
# shellcheck disable=SC2086
"$PY" -m pip download --quiet --no-deps --only-binary=:all: --python-version "$PYV" --implementation cp \
    $platforms --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any -d "$STAGE" $pins
mkdir -p "$STAGE/stage"
if [ "$TESTS" = 1 ]; then :  # the suite skips what needs the shared data
elif [ -d "$MESHES" ]; then cp -r "$MESHES" "$STAGE/stage/apolloscape-cars"
else echo "gpu_bundle: no meshes at $MESHES (set GPU_MESHES)" >&2; fi
if [ "$TESTS" = 1 ]; then :
elif [ -d "$KENNEY" ]; then cp -r "$KENNEY" "$STAGE/stage/kenney-vehicles"
else echo "gpu_bundle: no Kenney vehicles at $KENNEY (set GPU_KENNEY)" >&2; fi
if [ -n "$(ls -A "$STAGE/stage")" ]; then
    tar -C "$STAGE/stage" -cf - . | xz -9 -T0 > "$STAGE/meshes.tar.xz"
fi
rm -rf "$STAGE/stage"
travels=$(
    { git ls-files -z; git ls-files -z --others --exclude-standard; } \
        | { xargs -0 stat -c %s 2>/dev/null || true; } | awk '{s += $1} END {print s + 0}'
)  # tracked files deleted here do not travel: stat skips them
bundle=$(du -sb "$STAGE" | cut -f1)
total=$((travels + bundle))
if [ "$total" -gt "$LIMIT" ]; then
    echo "gpu_bundle: error: the checkout ($((travels / 1048576)) MiB) and the bundle ($((bundle / 1048576)) MiB) are" \
        "$((total - LIMIT)) bytes over the 64 MiB a device call carries: carry less ($DEST is left as it was)" >&2
    exit 1
fi
rm -rf "$DEST" && mkdir -p "$DEST" && mv "$STAGE"/* "$DEST"/
echo "gpu_bundle: $(ls "$DEST"/*.whl | wc -l) wheels (and the meshes, unless --tests) in $DEST ($((bundle / 1048576)) MiB);" \
    "with the checkout ($((travels / 1048576)) MiB) $((total / 1048576)) MiB of the 64 MiB a device call carries"
