#!/usr/bin/env bash
# A/B timing of `usdbtf compress` at two commits, runs interleaved so both see the same
# machine load.  Usage: benchmarks/ab_compress.sh OLD_COMMIT [DATASET] [RUNS] [-- compress args]
# Prints each run's wall time and peak RSS, then the medians.  The old commit is checked
# out into a temporary git worktree and run from the same virtualenv via PYTHONPATH.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
old=${1:?usage: ab_compress.sh OLD_COMMIT [DATASET] [RUNS] [-- args]}
data=${2:-benchmarks/out/data/pebbles-paper-128-seed0-tif}
runs=${3:-5}
shift $(( $# < 3 ? $# : 3 )); [[ "${1:-}" == "--" ]] && shift
tree=$(mktemp -d); out=$(mktemp -d)
trap 'git worktree remove --force "$tree" >/dev/null 2>&1 || true; rm -rf "$out"' EXIT
git worktree add -f --detach "$tree" "$old" -q
echo "# ab_compress: $(git rev-parse --short "$old") (old) vs $(git rev-parse --short HEAD) (new, working tree)"
echo "# machine: $(nproc) CPUs, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "# input: $data; args: ${*:-(none)}; $runs runs each"
declare -A times
for i in $(seq "$runs"); do
  for side in old new; do
    rm -rf "$out/$side"
    if [[ $side == old ]]; then env=(env PYTHONPATH="$tree/pipeline"); else env=(env); fi
    /usr/bin/time -o "$out/time" -f "%e %M" "${env[@]}" .venv/bin/python -m usdbtf.cli compress "$data" \
      -o "$out/$side" "$@" >"$out/log" 2>&1
    read -r wall kb <"$out/time"
    echo "run $i $side: ${wall} s, peak RSS $((kb / 1024)) MB; $(grep -m1 '^k = ' "$out/log" || true)"
    times[$side]+="$wall "
  done
done
for side in old new; do
  echo "median $side: $(tr ' ' '\n' <<<"${times[$side]}" | grep . | sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}') s"
done
