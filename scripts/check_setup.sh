#!/usr/bin/env bash
# Check the README's two commands end to end: clone this repository's HEAD (commit first) into a
# temporary folder and run `make demo` (or the target given) there with a given python3 first on the
# PATH and no virtual environment active. It must create the project environment .venv, install
# into it (torch==2.13.0 first), leave that python3's packages untouched and run the demo.
#
#   scripts/check_setup.sh                      # the python3 first on the PATH
#   SYSTEM_PYTHON=/usr/bin/python3 scripts/check_setup.sh demo   # e.g. Debian's externally managed one
#
# Elsewhere, run it in a container of such a system, e.g.
#   docker run --rm -v "$PWD:/src:ro" debian:12 bash -c \
#     'apt-get update -qq && apt-get install -y -qq git make python3 python3-venv >/dev/null && /src/scripts/check_setup.sh'
# Needs the package registries (or a local wheel cache that pip is configured to use); the clone
# reads the shared data from ../shared/data beside it only for `make test`.
set -euo pipefail
TARGET="${1:-demo}"
REPO="$(cd "$(dirname "$0")/.." && pwd)"
# the interpreter itself, not a pyenv shim (the shim needs pyenv on the PATH)
PY="$(env -u VIRTUAL_ENV "${SYSTEM_PYTHON:-python3}" -c 'import sys; print(sys.executable)')"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
git clone --quiet "$REPO" "$WORK/spotlights"
BIN="$WORK/bin"
mkdir -p "$BIN"
ln -s "$PY" "$BIN/python3"
before="$("$PY" -m pip list --format=freeze 2>/dev/null | sort | md5sum)"
cd "$WORK/spotlights"
echo "check_setup: make $TARGET in $WORK/spotlights with python3 = $PY ($("$PY" --version))"
t0=$(date +%s)
env -u VIRTUAL_ENV -u CONDA_PREFIX PATH="$BIN:/usr/bin:/bin" make "$TARGET"
t1=$(date +%s)
test -x .venv/bin/python || { echo "check_setup: FAILED: no .venv was created" >&2; exit 1; }
.venv/bin/python -c "import torch, spotlights; assert torch.__version__.startswith('2.13.0'), torch.__version__; print('check_setup: .venv has torch', torch.__version__, 'and spotlights', spotlights.__version__)"
after="$("$PY" -m pip list --format=freeze 2>/dev/null | sort | md5sum)"
[ "$before" = "$after" ] || { echo "check_setup: FAILED: the system Python's packages changed" >&2; exit 1; }
if [ "$TARGET" = demo ]; then
    ls out/demo >/dev/null && echo "check_setup: demo outputs: $(ls out/demo | tr '\n' ' ')"
fi
# a second command reuses the environment (nothing to create)
env -u VIRTUAL_ENV -u CONDA_PREFIX PATH="$BIN:/usr/bin:/bin" make -s where
echo "check_setup: OK: make $TARGET with $PY in $((t1 - t0)) s"
