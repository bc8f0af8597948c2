#!/usr/bin/env bash
# Do two runs of the example pipeline produce the same output bytes?
#
#   bash scripts/same_outputs.sh REF [--keep]                  # git ref REF vs the working tree
#   bash scripts/same_outputs.sh --env 'A=1 B=2' 'A=3' [--keep]  # the working tree in two environments
#
# Runs a representative subset of the example pipeline (examples/run_example.sh) twice and
# compares the SHA-256 of every output file (a .usdz by its members' names and bytes: USD
# stamps them with the packing time).  With REF: once with the code of REF (a `git archive` of
# it in a temporary folder), once with the working tree (uncommitted changes included).  With
# --env: the working tree twice, each run with its own NAME=VALUE assignments added to the
# environment (for example OPENBLAS_NUM_THREADS=1 against =4: no byte may differ).
# Covered: board; synth (8-bit PNG and half EXR); compress with both solvers, every codec,
# --k, --max-bytes (of the folder and of the asset), --target-error, in memory and streamed (--memory-budget 0); decompress;
# info and error reports; quilt (tileable and into an atlas); unwrap; package (+ usdz; a
# mesh with a usda payload, asset metadata and --usdz-ar; tx and exr textures); render
# (swatch and mesh).  Not covered: capture and rectify (they need a rig).  Prints each
# differing file and exits 1 on any difference, 0 when every file is identical, 2 when a stage
# fails.
#
# The numeric platform (the BLAS kernel and numpy's SIMD level: docs/conventions.md, "Same bytes
# on any machine") decides the bits.  Both runs start from this checkout's pin (exported first, so a
# REF from before the pin computes on the same platform); each run's platform is printed, and
# when an --env changes it (OPENBLAS_CORETYPE=Nehalem, say) differing bytes are expected: the
# script says so and exits 0 (3 if the two platforms' bytes are all equal, which proves nothing).
#
# Both runs use this checkout's .venv (REF's code goes first on PYTHONPATH), OCIO's built-in
# default config, and the same absolute output path (each run happens in the same
# temporary folder, one after the other), so recorded paths compare equal.  A REF whose
# dependencies differ from this .venv's may fail to run: that is reported, not hidden.
# Takes about a minute or two on two cores; --keep leaves the outputs in the printed folder.
set -euo pipefail

usage() {
    echo "usage: bash scripts/same_outputs.sh REF [--keep]" >&2
    echo "       bash scripts/same_outputs.sh --env 'NAME=VALUE ...' 'NAME=VALUE ...' [--keep]" >&2
    exit 2
}
[ $# -ge 1 ] || usage
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PY="$ROOT/.venv/bin/python"
[ -x "$PY" ] || { echo "same_outputs: no $PY (run scripts/bootstrap.sh)" >&2; exit 2; }

# assignments TEXT: NAME=VALUE words -> one per line, each checked (never evaluated).
assignments() {
    local word
    for word in $1; do
        [[ "$word" =~ ^[A-Z_][A-Z0-9_]*=[A-Za-z0-9_.,:-]*$ ]] || { echo "same_outputs: not NAME=VALUE: $word" >&2; exit 2; }
        printf '%s\n' "$word"
    done
}

if [ "$1" = "--env" ]; then
    [ $# -ge 3 ] || usage
    MODE=env
    mapfile -t ENV_A < <(assignments "$2")
    mapfile -t ENV_B < <(assignments "$3")
    LABEL_A="env [${2}]"
    LABEL_B="env [${3}]"
    KEEP=${4:-}
else
    MODE=ref
    REF=$1
    KEEP=${2:-}
    COMMIT=$(git -C "$ROOT" rev-parse --verify --quiet "$REF^{commit}") \
        || { echo "same_outputs: $REF is not a commit" >&2; exit 2; }
    ENV_A=()
    ENV_B=()
    LABEL_A="$REF"
    LABEL_B="working tree"
fi
[ -z "$KEEP" ] || [ "$KEEP" = "--keep" ] || usage

WORK=$(mktemp -d "${TMPDIR:-/tmp}/usdbtf-same-outputs.XXXXXX")
cleanup() {
    if [ "$KEEP" = "--keep" ]; then echo "outputs kept in $WORK"; else rm -rf "$WORK"; fi
}
trap cleanup EXIT
mkdir -p "$WORK/ref-code" "$WORK/logs"
[ "$MODE" = env ] || git -C "$ROOT" archive "$COMMIT" | tar -x -C "$WORK/ref-code"
export OCIO=ocio://default
# Both runs on one numeric platform (the BLAS kernel and numpy's SIMD level decide the bits;
# docs/conventions.md, "Same bytes on any machine"): this checkout's pin, exported before either run, so a
# REF from before the pin computes on the same platform.  The platform is printed.
eval "$(PYTHONPATH="$ROOT/pipeline" "$PY" -c 'import sys; from usdbtf.commands.env import numeric_lines; print("\n".join(numeric_lines()))')"

# platform ASSIGNMENTS...: the numeric platform of the working tree's usdbtf with them.
platform() { env "$@" PYTHONPATH="$ROOT/pipeline" "$PY" -c 'from usdbtf import numeric; print(numeric.platform_label())'; }
PLATFORM_A=$(platform "${ENV_A[@]}")
PLATFORM_B=$(platform "${ENV_B[@]}")
echo "same_outputs: numeric platform of $LABEL_A: $PLATFORM_A"
echo "same_outputs: numeric platform of $LABEL_B: $PLATFORM_B"

# pipeline CODE_ROOT: every stage, in $WORK/run, with the usdbtf package of CODE_ROOT.
pipeline() {
    local code=$1 run="$WORK/run"
    rm -rf "$run"
    mkdir -p "$run"
    cd "$run"
    usdbtf() { env "${RUN_ENV[@]}" PYTHONPATH="$code/pipeline" "$PY" -c 'import sys; from usdbtf.cli import main; sys.exit(main(sys.argv[1:]))' "$@"; }
    stage() {  # stage NAME command args...: run quietly, log to $WORK/logs, fail loudly
        local name=$1
        shift
        if ! "$@" > "$WORK/logs/$name.out" 2> "$WORK/logs/$name.err"; then
            echo "same_outputs: stage '$name' failed with the code of $code:" >&2
            tail -n 20 "$WORK/logs/$name.err" >&2
            exit 2
        fi
    }
    stage board usdbtf board -o board.png --json board.json --grid 6 --window 2 --cell-px 40
    stage synth usdbtf synth pebbles -o raw --sampling small --size 64 --seed 1
    stage synth-exr usdbtf synth ridged_fabric -o raw_exr --sampling tiny --size 16 --seed 3 --format exr \
        --bit-depth half
    stage compress usdbtf compress raw -o c --k 32
    stage compress-paper usdbtf compress raw -o c_paper --solver paper --k 32
    stage compress-png usdbtf compress raw -o c_png --codec png --k 12
    stage compress-exr usdbtf compress raw -o c_exr --codec exr --k 12
    stage compress-rsvd-jpeg usdbtf compress raw -o c_rsvd_jpeg --codec jpeg --k 12
    stage compress-paper-png usdbtf compress raw -o c_paper_png --solver paper --codec png --k 8 --region 24
    stage compress-max-bytes usdbtf compress raw -o c_max_bytes --max-bytes 15000 --budget-for folder
    stage compress-asset-max-bytes usdbtf compress raw -o c_asset_max_bytes --max-bytes 260000
    stage compress-paper-max-bytes usdbtf compress raw -o c_paper_max_bytes --solver paper --k 32 --max-bytes 40000 \
        --budget-for folder
    stage compress-target usdbtf compress raw -o c_target --target-error 4
    stage compress-exr-target usdbtf compress raw -o c_exr_target --codec exr --target-error 10
    stage compress-jpeg-max-bytes usdbtf compress raw -o c_jpeg_max_bytes --codec jpeg --k 12 --max-bytes 30000 \
        --budget-for folder
    stage compress-paper-target usdbtf compress raw -o c_paper_target --solver paper --k 32 --target-error 13
    stage compress-streamed usdbtf compress raw -o c_streamed --k 32 --memory-budget 0
    stage compress-streamed-target usdbtf compress raw -o c_streamed_target --target-error 4 --memory-budget 0
    stage compress-seed usdbtf compress raw -o c_seed --k 20 --seed 7 --fit-texels 1024 --power-iterations 2
    stage decompress usdbtf decompress c -o recon
    stage decompress-k usdbtf decompress c_paper -o recon_paper_k8 --k 8 --samples 0-20,100
    usdbtf info c > info.txt 2> "$WORK/logs/info.err" || { echo "same_outputs: info failed" >&2; exit 2; }
    usdbtf error raw recon > error.txt 2> "$WORK/logs/error.err" || { echo "same_outputs: error failed" >&2; exit 2; }
    stage package usdbtf package c -o asset/pebbles.usda --usdz
    stage quilt usdbtf quilt c -o q128 --size 128 128 --tileable --seed 1
    stage render-swatch usdbtf render c --swatch --view 30,0 --light 60,90 -o swatch.exr
    stage mesh "$PY" "$ROOT/examples/shapes.py" torus_knot -o knot.obj --scale 0.6
    stage unwrap usdbtf unwrap knot.obj -o knot_uv --btf c
    stage quilt-atlas usdbtf quilt c --atlas knot_uv/mesh.usda -o knot_btf --seed 1
    stage render-mesh usdbtf render knot_btf --mesh knot_uv/mesh.usda --light point:-0.05,0.07,0.06:0.01 \
        --size 96 96 -o knot.exr
    stage package-mesh usdbtf package c -o asset_mesh/knot.usdc --mesh knot_uv/mesh.usda --payload-format usda \
        --usdz-ar --asset-name knot --asset-version 2 --creator same_outputs --lod 8
    stage package-tx usdbtf package c_rsvd_jpeg -o asset_tx/j.usda --texture-format tx --no-thumbnail
    stage package-exr usdbtf package c_exr -o asset_exr/e.usda --texture-format exr --usdz --no-thumbnail
    cd "$WORK"
}

hashes() {  # hashes FOLDER > list: "sha256  relative/path", sorted by path
    # A .usdz is a zip whose members carry the time they were packed (USD's writer stamps
    # them), so it is compared member by member: names, order and bytes, not the stamps.
    "$PY" - "$1" <<'PYEOF'
import hashlib, os, sys, zipfile
root = sys.argv[1]
paths = sorted(os.path.relpath(os.path.join(d, f), root) for d, _, fs in os.walk(root) for f in fs)
for rel in paths:
    full = os.path.join(root, rel)
    h = hashlib.sha256()
    if rel.endswith(".usdz"):
        with zipfile.ZipFile(full) as z:
            for info in z.infolist():
                h.update(info.filename.encode() + b"\0" + hashlib.sha256(z.read(info)).digest())
    else:
        with open(full, "rb") as fh:
            h.update(fh.read())
    print(f"{h.hexdigest()}  ./{rel}")
PYEOF
}

if [ "$MODE" = env ]; then
    echo "same_outputs: running the pipeline with the working tree, $LABEL_A"
    RUN_ENV=("${ENV_A[@]}"); pipeline "$ROOT"
else
    echo "same_outputs: running the pipeline with $REF ($COMMIT)"
    RUN_ENV=(); pipeline "$WORK/ref-code"
fi
mv "$WORK/run" "$WORK/ref"
echo "same_outputs: running the pipeline with the working tree${ENV_B:+, $LABEL_B}"
RUN_ENV=("${ENV_B[@]}"); pipeline "$ROOT"
mv "$WORK/run" "$WORK/tree"

hashes "$WORK/ref" > "$WORK/ref.sha256"
hashes "$WORK/tree" > "$WORK/tree.sha256"
total=$(wc -l < "$WORK/tree.sha256")
if diff -q "$WORK/ref.sha256" "$WORK/tree.sha256" > /dev/null; then
    echo "same_outputs: all $total output files are byte-identical ($LABEL_A vs $LABEL_B)"
    if [ "$PLATFORM_A" != "$PLATFORM_B" ]; then
        echo "same_outputs: (on two numeric platforms: equal bytes there are luck, not a property)"
        exit 3
    fi
    exit 0
fi
differing=$(join -j 2 -a 1 -a 2 -e MISSING -o 0,1.1,2.1 <(sort -k 2 "$WORK/ref.sha256") <(sort -k 2 "$WORK/tree.sha256") \
    | awk '$2 != $3 { if ($2 == "MISSING") s = "only in " b; else if ($3 == "MISSING") s = "only in " a; else s = "content differs"; print "  " $1 "  (" s ")" }' a="$LABEL_A" b="$LABEL_B")
echo "same_outputs: $(printf '%s\n' "$differing" | wc -l) of $total output files differ ($LABEL_A vs $LABEL_B):"
printf '%s\n' "$differing"
if [ "$PLATFORM_A" != "$PLATFORM_B" ]; then
    echo "same_outputs: expected: the two runs compute on different numeric platforms"
    exit 0
fi
exit 1
