#!/usr/bin/env bash
# A/B timing of `usdbtf compress` at two commits, runs interleaved so both see the same
# machine load.  Usage: benchmarks/ab_compress.sh OLD_COMMIT [DATASET] [RUNS] [-- compress args]
# Prints each run's wall time, CPU time (with the decode workers) and peak RSS, whether the
# two output folders are byte-identical, then the medians.  The old commit's code is a
# `git archive` in a temporary folder (the repository is not touched), run from the same
# virtualenv via PYTHONPATH.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
old=${1:?usage: ab_compress.sh OLD_COMMIT [DATASET] [RUNS] [-- args]}
data=${2:-benchmarks/out/data/pebbles-paper-128-seed0-tif}
runs=${3:-5}
shift $(( $# < 3 ? $# : 3 )); [[ "${1:-}" == "--" ]] && shift
tree=$(mktemp -d); out=$(mktemp -d)
trap 'rm -rf "$tree" "$out"' EXIT
git archive "$old" | tar -x -C "$tree"
echo "# ab_compress: $(git rev-parse --short "$old") (old) vs $(git rev-parse --short HEAD) (new, working tree)"
echo "# machine: $(nproc) CPUs, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "# input: $data; args: ${*:-(none)}; $runs runs each"
declare -A times cpus
for i in $(seq "$runs"); do
  for side in old new; do
    rm -rf "$out/$side"
    if [[ $side == old ]]; then env=(env PYTHONPATH="$tree/pipeline"); else env=(env); fi
    /usr/bin/time -o "$out/time" -f "%e %U %S %M" "${env[@]}" .venv/bin/python -m usdbtf.cli compress "$data" \
      -o "$out/$side" "$@" >"$out/log" 2>&1
    read -r wall user sys kb <"$out/time"
    cpu=$(awk -v u="$user" -v s="$sys" 'BEGIN {printf "%.2f", u + s}')
    echo "run $i $side: ${wall} s, CPU ${cpu} s, peak RSS $((kb / 1024)) MB; load $(cut -d' ' -f1 /proc/loadavg);" \
         "$(grep -m1 '^k = ' "$out/log" || true)"
    times[$side]+="$wall "
    cpus[$side]+="$cpu "
  done
  same=$(diff -rq "$out/old" "$out/new" >/dev/null && echo "byte-identical" || echo "DIFFERENT")
  echo "run $i outputs: $same"
done
median() { tr ' ' '\n' <<<"$1" | grep . | sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
for side in old new; do
  echo "median $side: $(median "${times[$side]}") s wall, $(median "${cpus[$side]}") s CPU"
done
