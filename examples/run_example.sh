#!/usr/bin/env bash
# End-to-end example: set up .venv, then run each pipeline stage into examples/out/.
# To add a stage, append another `step` call at the end.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH"

OUT=examples/out
mkdir -p "$OUT"

step() {  # step "heading" command args...
    echo
    echo "== $1"
    shift
    echo "\$ $*"
    "$@"
}

step "synth: synthetic pebbles BTF" \
    usdbtf synth pebbles -o "$OUT/pebbles_raw" --sampling small --size 64 --seed 1
step "compress" \
    usdbtf compress "$OUT/pebbles_raw" -o "$OUT/pebbles_c" --k 32
step "decompress" \
    usdbtf decompress "$OUT/pebbles_c" -o "$OUT/pebbles_recon"
step "info: sizes and errors" \
    usdbtf info "$OUT/pebbles_c"
step "error: full-data metrics of the reconstruction" \
    usdbtf error "$OUT/pebbles_raw" "$OUT/pebbles_recon"
step "paper solver, same data (the 2003 baseline)" \
    usdbtf compress "$OUT/pebbles_raw" -o "$OUT/pebbles_paper" --solver paper --k 32
step "figure: originals vs reconstructions" \
    .venv/bin/python examples/figure.py "$OUT/pebbles_raw" "$OUT/pebbles_c" -o "$OUT/pebbles_sheet.png"

# -- capture -> rectify -> compress on the simulated rig (issue 4) --

# -- package as a USD asset (issue 3) --
step "package: USD asset (swatch, LOD variants, usdz) checked by every UsdValidation validator" \
    usdbtf package "$OUT/pebbles_c" -o "$OUT/asset/pebbles.usda" --usdz
step "inspect the asset" \
    usdbtf inspect "$OUT/asset/pebbles.usda" --validate
step "decompress from the asset (equals decompress of the folder, bit for bit)" \
    usdbtf decompress "$OUT/asset/pebbles.usdz" -o "$OUT/pebbles_from_asset" --lod full

# -- quilt / unwrap / render (issue 5) --


echo
echo "done: outputs in $OUT/"
