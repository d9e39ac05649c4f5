#!/usr/bin/env bash
# Prepare, on a machine with PyPI, what scripts/gpu_train.sh needs on a GPU machine without internet
# (docs/training.md, "GPU recipe"): into .whl/ (git-ignored; carry it to the GPU machine)
#   - not the project's own wheel: gpu_train.sh runs the checkout's src/ (the wheel, 16 MB with its
#     pretrained checkpoints, would push the call past the 64 MiB a device call carries),
#   - the wheels of its dependencies that the GPU image may lack (trimesh, embreex, pykdtree, rtree,
#     pypcd4 and its needs: python-neo-lzf, pydantic..., tqdm, pyyaml), at the versions installed here, for the GPU machine's
#     Python (GPU_PYTHON_VERSION, default 3.12) on x86-64 manylinux; never torch;
#   - the ApolloScape car meshes (.whl/meshes/apolloscape-cars, 8.6 MB) from ../shared/data.
# Usage: scripts/gpu_bundle.sh            (or: make gpu-bundle)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
DEST=${GPU_BUNDLE:-.whl}
PYV=${GPU_PYTHON_VERSION:-3.12}
MESHES=${GPU_MESHES:-../shared/data/meshes/apolloscape-cars}
rm -rf "$DEST.tmp" && mkdir -p "$DEST.tmp"
pins=$("$PY" - <<'PY'
from importlib.metadata import version
names = ["trimesh", "embreex", "pykdtree", "rtree", "pypcd4", "python-neo-lzf", "pydantic", "pydantic-core",
         "annotated-types", "typing-inspection", "typing-extensions", "tqdm", "pyyaml"]
print(" ".join(f"{n}=={version(n)}" for n in names))
PY
)
platforms=""
for n in 17 27 28; do platforms="$platforms --platform manylinux_2_${n}_x86_64"; done
# shellcheck disable=SC2086
"$PY" -m pip download --quiet --no-deps --only-binary=:all: --python-version "$PYV" --implementation cp \
    $platforms --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any -d "$DEST.tmp" $pins
if [ -d "$MESHES" ]; then
    mkdir -p "$DEST.tmp/meshes" && cp -r "$MESHES" "$DEST.tmp/meshes/"
else
    echo "gpu_bundle: no meshes at $MESHES (set GPU_MESHES); the bundle has none" >&2
fi
rm -rf "$DEST" && mv "$DEST.tmp" "$DEST"
echo "gpu_bundle: $(ls "$DEST"/*.whl | wc -l) wheels and meshes in $DEST ($(du -sh "$DEST" | cut -f1)); carry it with the checkout"
