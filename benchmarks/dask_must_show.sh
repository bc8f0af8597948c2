#!/usr/bin/env bash
# Issue 17's must-show: a real `dask scheduler` and two `dask worker` processes started from
# the project's environment on localhost; `usdbtf compress IN -o OUT --dask tcp://127.0.0.1:PORT`
# on a held-out preset gives a folder byte-identical to the in-process run (plain k and
# --max-bytes).  Prints every command, its wall time and the comparison; exits non-zero on any
# difference.  Usage: bash benchmarks/dask_must_show.sh [PRESET] [SAMPLING] [SIZE]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
preset=${1:-velvet}          # held out of every tuning run (usdbtf.bench.datasets.HELDOUT_PRESETS)
sampling=${2:-ubo81}
size=${3:-64}
bin=.venv/bin
out=benchmarks/out/must_show
data=benchmarks/out/data/heldout-$preset-$sampling-$size-seed7
port=$((20000 + RANDOM % 20000))
mkdir -p "$out"
rm -rf "$out"/{in-process,dask,in-process-maxbytes,dask-maxbytes}

say() { printf '%s\n' "$*"; }
timed() { local t0=$SECONDS; say "\$ $*"; "$@"; say "  $((SECONDS - t0)) s wall"; }

say "# dask must-show ($(date -u +%FT%TZ)); git $(git rev-parse --short HEAD); usdbtf $($bin/usdbtf --version)"
say "# machine: $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"
[ -f "$data/btf.json" ] || timed "$bin/usdbtf" -q synth "$preset" --sampling "$sampling" --size "$size" --seed 7 -o "$data"

pids=()
cleanup() { kill "${pids[@]}" 2>/dev/null || true; wait 2>/dev/null || true; }
trap cleanup EXIT
say "\$ $bin/dask scheduler --host 127.0.0.1 --port $port --no-dashboard &"
"$bin/dask" scheduler --host 127.0.0.1 --port "$port" --no-dashboard >"$out/scheduler.log" 2>&1 &
pids+=($!)
for w in 1 2; do
  say "\$ $bin/dask worker tcp://127.0.0.1:$port --nthreads 1 --host 127.0.0.1 --no-dashboard &"
  "$bin/dask" worker "tcp://127.0.0.1:$port" --nthreads 1 --host 127.0.0.1 --no-dashboard >"$out/worker$w.log" 2>&1 &
  pids+=($!)
done

same() {   # same A B: every file byte-identical
  if diff -r "$1" "$2" >/dev/null; then
    say "  byte-identical: $(find "$1" -type f | wc -l) files ($1 vs $2)"
  else
    say "  DIFFERENT: $1 vs $2"; diff -rq "$1" "$2" | head; exit 1
  fi
}
timed "$bin/usdbtf" compress "$data" -o "$out/in-process"
timed "$bin/usdbtf" compress "$data" -o "$out/dask" --dask "tcp://127.0.0.1:$port"
same "$out/in-process" "$out/dask"
budget=$("$bin/usdbtf" info --json "$out/in-process" | "$bin/python" -c 'import json, sys; print(json.load(sys.stdin)["bytes"]["payload"] * 2 // 3)')
timed "$bin/usdbtf" -q compress "$data" -o "$out/in-process-maxbytes" --max-bytes "$budget"
timed "$bin/usdbtf" -q compress "$data" -o "$out/dask-maxbytes" --max-bytes "$budget" --dask "tcp://127.0.0.1:$port"
same "$out/in-process-maxbytes" "$out/dask-maxbytes"
