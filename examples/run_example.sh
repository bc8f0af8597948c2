#!/usr/bin/env bash
# End-to-end example: set up .venv, then run each pipeline stage into examples/out/.
# To add a stage, append another `step` call at the end.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH"

OUT=examples/out
mkdir -p "$OUT"

# Every step passes --force, so running this script again replaces its own previous outputs
# (only those: --force never replaces anything usdbtf did not write).
step() {  # step "heading" command args...
    echo
    echo "== $1"
    shift
    echo "\$ $*"
    "$@"
}

step "synth: synthetic pebbles BTF" \
    usdbtf synth --force pebbles -o "$OUT/pebbles_raw" --sampling small --size 64 --seed 1
step "compress" \
    usdbtf compress --force "$OUT/pebbles_raw" -o "$OUT/pebbles_c" --k 32
step "decompress" \
    usdbtf decompress --force "$OUT/pebbles_c" -o "$OUT/pebbles_recon"
step "info: sizes and errors" \
    usdbtf info "$OUT/pebbles_c"
step "error: full-data metrics of the reconstruction" \
    usdbtf error "$OUT/pebbles_raw" "$OUT/pebbles_recon"
step "paper solver, same data (the 2003 baseline)" \
    usdbtf compress --force "$OUT/pebbles_raw" -o "$OUT/pebbles_paper" --solver paper --k 32
step "figure: originals vs reconstructions" \
    .venv/bin/python examples/figure.py "$OUT/pebbles_raw" "$OUT/pebbles_c" -o "$OUT/pebbles_sheet.png"

# -- capture -> rectify -> compress on the simulated rig (issue 4) --
# A simulated rig controller serves the rig protocol on a pseudo-terminal (losing or garbling
# 2% of its replies); capture drives it through the 'tiny' plan (4 views x 6 lights), rectify
# finds the ArUco board in every frame, compress takes the rectified BTF.  The default plan is
# the paper's 90 x 120 samples (hours on a real rig).
rm -rf "$OUT/rig"
mkdir -p "$OUT/rig"
step "board: printable fiducial board + layout JSON" \
    usdbtf board --force -o "$OUT/rig/board.png" --json "$OUT/rig/board.json"
usdbtf rig-sim --link "$OUT/rig/tty" --port-file "$OUT/rig/port" --frames "$OUT/rig/sim_frames" \
    --frame-size 480x360 --texture-size 32 --board "$OUT/rig/board.json" --fault-rate 0.02 -q > /dev/null &
SIM_PID=$!
trap 'kill "$SIM_PID" 2>/dev/null || true' EXIT
for _ in $(seq 100); do [ -s "$OUT/rig/port" ] && break; sleep 0.1; done
step "capture over the simulated serial link ($(cat "$OUT/rig/port"))" \
    usdbtf capture --port "$OUT/rig/tty" -o "$OUT/rig/RAW" --sampling tiny \
    --camera-cmd "mv $OUT/rig/sim_frames/{tag}.tif {out}" --board "$OUT/rig/board.json" \
    --timeout 0.5 --move-timeout 0.5
kill "$SIM_PID" 2>/dev/null || true
trap - EXIT
step "rectify: ArUco homographies -> 32x32 scene-linear samples" \
    usdbtf rectify --force "$OUT/rig/RAW" -o "$OUT/rig/RECT" --size 32
step "compress the rectified capture" \
    usdbtf compress --force "$OUT/rig/RECT" -o "$OUT/rig/C" --k 12

# -- package as a USD asset (issue 3) --
step "package: USD asset (swatch, fitted fallback, LOD variants, thumbnail, usdz, AR usdz) checked by every UsdValidation validator" \
    usdbtf package --force "$OUT/pebbles_c" -o "$OUT/asset/pebbles.usda" --usdz --usdz-ar
step "env: the launcher lines that make any USD process know the plugin (issue 15)" \
    usdbtf env
step "inspect the asset" \
    usdbtf inspect "$OUT/asset/pebbles.usda" --validate
step "decompress from the asset (equals decompress of the folder, bit for bit)" \
    usdbtf decompress --force "$OUT/asset/pebbles.usdz" -o "$OUT/pebbles_from_asset" --lod full

# -- quilt / unwrap / render (issue 5) --
step "quilt: a tileable 256² texture from the 64² sample, matching in coefficient space" \
    usdbtf quilt --force "$OUT/pebbles_c" -o "$OUT/pebbles_q256" --size 256 256 --tileable --seed 1
step "render: the measured swatch at a measured (view, light) (equals decompress of that sample)" \
    usdbtf render --force "$OUT/pebbles_c" --swatch --view 30,0 --light 60,90 -o "$OUT/swatch.exr"
step "mesh: a generated torus knot (OBJ with normals)" \
    .venv/bin/python examples/shapes.py torus_knot -o "$OUT/knot.obj" --scale 0.6
step "unwrap: xatlas charts at the sample's texel density, tangent frames, USD geometry layer" \
    usdbtf unwrap --force "$OUT/knot.obj" -o "$OUT/knot_uv" --btf "$OUT/pebbles_c"
step "quilt into the knot's atlas (every chart filled, borders matched, gutters padded)" \
    usdbtf quilt --force "$OUT/pebbles_c" --atlas "$OUT/knot_uv/mesh.usda" -o "$OUT/knot_btf" --seed 1
step "render: the knot under a near point light with cast shadows (EXR + sRGB PNG)" \
    usdbtf render --force "$OUT/knot_btf" --mesh "$OUT/knot_uv/mesh.usda" --light point:-0.05,0.07,0.06:0.01 \
    --size 320 320 -o "$OUT/knot.exr"
step "figure: three materials on a sphere, a cylinder and a torus knot, two lights (small; full: docs/meshes-quilting-and-rendering.md)" \
    .venv/bin/python examples/fig5.py -o "$OUT/fig5_small.png" --workdir "$OUT/fig5" --size 64 --k 24 --tile 160

# -- Hydra preview: Storm shader / MaterialX, checked headless (issue 7) --
step "preview: the asset's real-time shader on headless OpenGL vs the CPU renderer (PSNR)" \
    usdbtf preview --force "$OUT/asset/pebbles.usda" --swatch --view 40,60 --light 50,200 -o "$OUT/preview_swatch.exr" --compare
step "preview at a level of detail (loads only that level's coefficient packs)" \
    usdbtf preview --force "$OUT/asset/pebbles.usda" --lod k16 --light dir:0.3,0.5,1 --size 256 256 -o "$OUT/preview_k16.exr" --compare
step "figure: headless GL next to the CPU reference (swatch and sphere)" \
    .venv/bin/python examples/preview_figure.py "$OUT/asset/pebbles.usda" -o "$OUT/preview_sheet.png"

echo
echo "done: outputs in $OUT/"
