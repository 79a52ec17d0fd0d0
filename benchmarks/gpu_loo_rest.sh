#!/usr/bin/env bash
# Issue 43: the five kt3d-loo "augment" folds the first run (benchmarks/gpu_full_budgets.sh) left, 1500 steps
# each from gpudata/base-f5.pt, side by side on the GPU; run from the repository root with $OUT set and
# gpudata/ carried (gpudata/data from `python benchmarks/gpu_full_budgets.py prepare`):
#
#   bash benchmarks/gpu_loo_rest.sh      # one NVIDIA H200: 63 s wall, 46 s of training per fold
#
# Writes $OUT/rest.tar.gz: loo/w<fold>/folds/<fold>.{pt,json} (copy them beside the first run's folds and
# re-score all 22 with `moseg eval kt3d-loo --variant augment --init gpudata/base-f5.pt --steps 1500
# --baselines '' --out DIR`: it trains nothing) and one log per fold.
set -u
export PYTHONPATH="$PWD" PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MPLBACKEND=Agg
W=/tmp/rest; mkdir -p $W
for f in Seq070_Clip01 Seq071_Clip01 Seq084_Clip01 Seq095_Clip01 Seq113_Clip01; do
  timeout 200 python3 - "$f" "$W" > "$W/$f.log" 2>&1 <<'PY' &
import sys, time
from pathlib import Path
sys.path.insert(0, "benchmarks")
import gpu_full_budgets as g
g._quiet_logs()
from mosegpipe.runtime import set_threads
set_threads(1)
t0 = time.time()
print(g._run_loo({"fold": sys.argv[1]}, Path(sys.argv[2]), g.DATA, "cuda", sys.argv[1]), time.time() - t0)
PY
done
wait
tail -n 3 $W/*.log
cd $W && tar czf "$OUT/rest.tar.gz" loo *.log && ls -la "$OUT"
