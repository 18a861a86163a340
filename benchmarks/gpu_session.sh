#!/usr/bin/env bash
# One prepared run of the accelerator figures of issue 33 on a lent GPU machine, from a source checkout (the
# machine's own jax / equinox / optax / optimistix / numba):   bash benchmarks/gpu_session.sh OUT_DIR
# 1. every prefix form of the time-parallel free run, forward only, at LENGTH (10^6) samples, LuGre and Maxwell-slip
#    NLR(7) against numba on the host (prefix_forms.jsonl), and the default form with its doubling rounds in a loop
#    (rounds_loop.jsonl);
# 2. per model, the fastest form of step 1 again with its gradient, at 10^5 and 10^6 samples (best_forms.jsonl);
# 3. Maxwell-slip's gradient with the adjoint transpose of the tangent scan (adjoint.jsonl);
# 4. a Levenberg-Marquardt fit of LuGre on FIT_LENGTH samples with LuGre's fastest form (fit.jsonl);
# 5. with COMPARE=1, a default `fricjax compare` with the GPU as JAX's default device, then with JAX_PLATFORMS=cpu.
set -u
out="${1:-${OUT:-/tmp/fricjax-gpu}}"
mkdir -p "$out"
root="$(cd "$(dirname "$0")/.." && pwd)"
export PYTHONPATH="$root/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
python3 -c "import jax; print(jax.__version__, jax.devices())"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null || true
cd "$root/benchmarks"
forms="${PREFIXES:-blocked:8:sequential:doubling blocked:16:sequential:doubling blocked:64:doubling:doubling
  blocked:256:doubling:doubling doubling}"
timeout "${SWEEP_S:-150}" python3 parallel_scan.py --lengths "${LENGTH:-1000000}" --sequential-max 0 --budget 1 \
  --repeats 10 --forward-only --prefix $forms | tee "$out/prefix_forms.jsonl"
# the default form with its doubling rounds in a fori_loop (what CPU devices run) instead of unrolled
timeout "${LOOP_S:-60}" python3 parallel_scan.py --lengths "${LENGTH:-1000000}" --sequential-max 0 --budget 1 \
  --repeats 10 --forward-only --rounds loop | tee "$out/rounds_loop.jsonl"
best() {  # the fastest form of model $1 in step 1
  python3 -c "
import json, sys
rows = [json.loads(l) for l in open('$out/prefix_forms.jsonl') if l.startswith('{')]
rows = [r for r in rows if r['model'] == '$1']
print(min(rows, key=lambda r: r['seconds']['parallel'])['prefix'] if rows else 'auto')"
}
for model in lugre maxwell_nlr7; do
  timeout "${BEST_S:-100}" python3 parallel_scan.py --lengths ${LENGTHS:-100000 1000000} --sequential-max 0 --budget 1 \
    --repeats 10 --models "$model" --prefix "$(best $model)" | tee -a "$out/best_forms.jsonl"
done
# Maxwell-slip's gradient with the adjoint recurrence as a backward affine prefix instead of JAX's transpose
timeout "${ADJOINT_S:-60}" python3 parallel_scan.py --lengths ${LENGTHS:-100000 1000000} --sequential-max 0 --budget 1 \
  --repeats 10 --models maxwell_nlr7 --prefix "$(best maxwell_nlr7)" --transpose adjoint | tee "$out/adjoint.jsonl"
timeout "${FIT_S:-60}" python3 parallel_scan.py --lengths --prefix "$(best lugre)" --fit-length "${FIT_LENGTH:-1000000}" \
  | tee "$out/fit.jsonl"
cd "$root"
if [ "${COMPARE:-0}" = 1 ]; then  # the wall time of a default compare on the GPU machine and on its CPU
  bash "$root/benchmarks/accelerator.sh" "$out" compare
fi
