#!/usr/bin/env bash
# Create/refresh the project virtual environment in .venv (idempotent).
# Re-installs only when pyproject.toml changed since the last successful install.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# System packages, installed only when missing and running as root with apt; otherwise what
# needs them skips and says why:
# - the Hydra preview checks (issue 7): glslang-tools (GLSL compile check) and Mesa's EGL +
#   llvmpipe (headless OpenGL);
# - the benchmark's H.265 video baseline (issue 29): Debian's ffmpeg, built with libx265.
apt_install() {  # apt_install "what skips without them" package...
    local skips="$1"
    shift
    [ "$#" -gt 0 ] || return 0
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "bootstrap: installing $* (apt)" >&2
        if ! DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null 2>&1; then
            apt-get update -qq >/dev/null 2>&1 || true
            DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null 2>&1 \
                || echo "bootstrap: could not install $*; $skips" >&2
        fi
    else
        echo "bootstrap: missing $* (apt-get install as root); $skips" >&2
    fi
}
gl_missing=()
command -v glslangValidator >/dev/null 2>&1 || gl_missing+=(glslang-tools)
if command -v dpkg-query >/dev/null 2>&1; then
    for pkg in libegl1 libegl-mesa0 libgl1-mesa-dri; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || gl_missing+=("$pkg")
    done
fi
apt_install "the GPU preview tests will skip" ${gl_missing[@]+"${gl_missing[@]}"}
# (Captured, not piped into grep -q: under pipefail, ffmpeg killed by SIGPIPE would read as missing.)
encoders="$(ffmpeg -hide_banner -encoders 2>/dev/null || true)"
case "$encoders" in
    *libx265*) ;;
    *) apt_install "usdbtf bench skips its H.265 video baseline (its row says why)" ffmpeg ;;
esac

VENV=.venv
STAMP="$VENV/.usdbtf-bootstrap.sha256"
PY="$VENV/bin/python"

if [ ! -x "$PY" ] || ! "$PY" -m pip --version >/dev/null 2>&1; then
    echo "bootstrap: creating $VENV" >&2
    rm -rf "$VENV"
    python3 -m venv "$VENV"
    rm -f "$STAMP"
fi

# The dependencies' versions come from scripts/constraints.txt, those the suite last passed
# with, so a run never depends on what PyPI published that day (OpenCV 5.1 once changed bits
# under a green main). USDBTF_LATEST=1 takes the newest releases instead: how to try an update.
constraints=(-c scripts/constraints.txt)
storm_constraints=(-c scripts/constraints-storm.txt)
if [ "${USDBTF_LATEST:-}" = 1 ]; then
    constraints=()
    storm_constraints=()
fi
want="$(cat pyproject.toml scripts/constraints.txt | sha256sum | cut -d' ' -f1)${USDBTF_LATEST:+-latest}"
have="$(cat "$STAMP" 2>/dev/null || true)"
if [ "$want" != "$have" ]; then
    echo "bootstrap: installing usdbtf and dependencies into $VENV (first run downloads wheels)" >&2
    "$PY" -m pip install --quiet --disable-pip-version-check --upgrade pip
    "$PY" -m pip install --quiet --disable-pip-version-check ${constraints[@]+"${constraints[@]}"} -e '.[test]'
    echo "$want" > "$STAMP"
    echo "bootstrap: done" >&2
fi

# btf-extractor: the independent UBO2014 reader tests/test_ubo2014.py compares against.  As
# published it does not pip-install on Python 3.11 (a numpy<1.20 build pin, a poetry build
# backend), but its C++ extension builds from the source distribution with current Cython and
# numpy.  Built once per environment, without its stale pins; a failure never fails the
# bootstrap: those tests then skip and say why.
EXTRACTOR_STAMP="$VENV/.usdbtf-btf-extractor-tried"
if [ ! -e "$EXTRACTOR_STAMP" ] && ! "$PY" -c "import ubo2014_cy" >/dev/null 2>&1; then
    touch "$EXTRACTOR_STAMP"
    if command -v c++ >/dev/null 2>&1 \
        && "$PY" -m pip install --quiet --disable-pip-version-check "Cython>=3" poetry-core >/dev/null 2>&1 \
        && "$PY" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation \
            "btf-extractor==1.7.0" >/dev/null 2>&1 \
        && "$PY" -c "import ubo2014_cy" >/dev/null 2>&1; then
        echo "bootstrap: built btf-extractor 1.7.0 from its source distribution" >&2
    else
        echo "bootstrap: could not build btf-extractor; the UBO2014 cross-reader tests will skip" >&2
    fi
fi

# Real Hydra Storm for tests/test_storm.py (issue 25): the USD inside PyPI's bpy wheels is a
# full build with imaging (bpy 4.5.15: USD 25.02, which needs numpy < 2; bpy 5.0.1: USD
# 25.08). Each goes into its own environment, away from usd-core's pxr; both are CPython 3.11
# wheels of about 370 MB. Tried once per environment (delete .venv-storm-*/.usdbtf-tried to
# retry); a failure never fails the bootstrap: those tests then skip and say why. The bpy 5.0.1
# environment also runs Cycles with OSL for tests/test_cycles.py and tests/test_osl.py (issue 30).
storm_env() {  # storm_env FOLDER REQUIREMENTS...
    local folder="$1" py311=""
    shift
    [ -e "$folder/.usdbtf-tried" ] && return 0
    for candidate in python3.11 python3; do
        if command -v "$candidate" >/dev/null 2>&1 \
            && "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
            py311="$candidate"
            break
        fi
    done
    if [ -z "$py311" ]; then
        echo "bootstrap: no CPython 3.11 for $folder ($*); the Storm tests will skip" >&2
        return 0
    fi
    echo "bootstrap: installing $* into $folder (about 370 MB, first run only)" >&2
    if "$py311" -m venv "$folder" >/dev/null 2>&1 \
        && "$folder/bin/python" -m pip install --quiet --disable-pip-version-check \
            ${storm_constraints[@]+"${storm_constraints[@]}"} "$@" moderngl >/dev/null 2>&1; then
        echo "bootstrap: $folder ready" >&2
    else
        echo "bootstrap: could not install $* into $folder; the Storm tests will skip" >&2
    fi
    mkdir -p "$folder" && touch "$folder/.usdbtf-tried"
}
storm_env .venv-storm-4.5 "bpy==4.5.15" "numpy<2" || true
storm_env .venv-storm-5.0 "bpy==5.0.1" numpy || true
