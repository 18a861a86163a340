#!/usr/bin/env bash
# The figures of benchmarks/README.md "Accelerators", on a machine with a GPU (or any JAX backend), from a source
# checkout without installing (the machine's own jax / equinox / optax / optimistix / numba):
#   bash benchmarks/accelerator.sh [OUT_DIR] [simulate|compare|all]
# writes parallel_scan.jsonl (benchmarks/parallel_scan.py) and, with compare/all, the wall time of a default
# `fricjax compare` on the accelerator and on the host CPU (JAX_PLATFORMS=cpu) into compare.txt.
set -u
out="${1:-${OUT:-/tmp/fricjax-accelerator}}"
what="${2:-simulate}"
mkdir -p "$out"
root="$(cd "$(dirname "$0")/.." && pwd)"
export PYTHONPATH="$root/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
python3 -c "import jax; print(jax.__version__, jax.devices())"
if [ "$what" = simulate ] || [ "$what" = all ]; then
  (cd "$root/benchmarks" && timeout 420 python3 parallel_scan.py --lengths ${LENGTHS:-1000 10000 100000 1000000} \
    --fit-length "${FIT_LENGTH:-1000000}" --sequential-max "${SEQUENTIAL_MAX:-100000}" --budget 2 --repeats 10 \
    ${PREFIX:+--prefix $PREFIX} | tee "$out/parallel_scan.jsonl")
fi
if [ "$what" = compare ] || [ "$what" = all ]; then
  export FRICJAX_NO_CACHE=1  # first runs, compiled from scratch on both
  for platform in default cpu; do
    start=$(date +%s.%N)
    if [ "$platform" = cpu ]; then env JAX_PLATFORMS=cpu timeout 200 python3 -m fricjax compare --no-progress \
      --out "/tmp/compare-$platform" > "$out/compare-$platform.log" 2>&1
    else timeout 200 python3 -m fricjax compare --no-progress --out "/tmp/compare-$platform" \
      > "$out/compare-$platform.log" 2>&1; fi
    status=$?
    echo "compare on $platform: exit $status, $(python3 -c "import time; print(round(time.time() - $start, 1))") s" \
      | tee -a "$out/compare.txt"
  done
fi
