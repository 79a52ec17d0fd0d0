#!/usr/bin/env bash
# Issue 43: the paper's full training budgets on one lent GPU machine (one GPU, 16 CPU cores), in about
# nine minutes of wall time; run from the repository root with $OUT set:
#
#   bash benchmarks/gpu_full_budgets.sh
#
# Needs gpudata/ (git-ignored; `python benchmarks/gpu_full_budgets.py prepare` and gpudata/base-f5.pt, see
# benchmarks/gpu_full_budgets.py). Stages, side by side: the LCE curve on the GPU; the losses study's L2 and
# MaxInterMinIntra models and the kt3d-loo "augment" folds on CPU workers (one thread each), joined by a GPU
# worker when the LCE stage ends. Every stage stops by GPU43_BUDGET_S seconds after the start (default 480);
# then the results are collected into at most 7 files under $OUT:
#   env.txt, summary.md, results.json, lce.tar.gz, losses.tar.gz, loo.tar.gz, logs.tar.gz
# GPU43_TINY=1: every stage shrunk to seconds (the CPU check of this script).
set -u
cd "$(dirname "$0")/.."
T0=$(date +%s)
: "${OUT:?set OUT to the folder the results go to}"
mkdir -p "$OUT"
TINY=${GPU43_TINY:-0}
BUDGET=${GPU43_BUDGET_S:-$([ "$TINY" != 0 ] && echo 150 || echo 480)}
DEADLINE=$((T0 + BUDGET))
PY=${PYTHON:-python3}
D=benchmarks/gpu_full_budgets.py
WORK=${GPU43_WORK:-$(mktemp -d /tmp/gpu43.XXXXXX)}
mkdir -p "$WORK/logs"
NCPU=$(nproc)
DEFAULT_WORKERS=$((NCPU > 3 ? NCPU - 2 : 1))  # one core for the GPU stage, one for the rest
[ "$TINY" != 0 ] && DEFAULT_WORKERS=2
WORKERS=${GPU43_CPU_WORKERS:-$DEFAULT_WORKERS}
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
left() { echo $((DEADLINE - $(date +%s))); }

{
  echo "start $(date -u +%FT%TZ) budget ${BUDGET}s workers $WORKERS cpus $NCPU tiny $TINY work $WORK"
  echo "git $(git rev-parse HEAD 2>/dev/null || echo '?')"
  "$PY" -c "import sys, torch, numpy; print('python', sys.version.split()[0], 'torch', torch.__version__, 'cuda', torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else '-', 'numpy', numpy.__version__)"
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  lscpu 2>/dev/null | grep -E "Model name|^CPU\(s\)" || true
  du -sh gpudata 2>/dev/null
} > "$OUT/env.txt" 2>&1
cat "$OUT/env.txt"

# The GPU: the LCE stage, then a GPU worker on what is left of the queue.
(
  timeout -k 10 $(($(left) + 5)) "$PY" $D lce --work "$WORK" --deadline "$DEADLINE" > "$WORK/logs/lce.log" 2>&1
  echo "lce exit $? at $(($(date +%s) - T0)) s" >> "$WORK/logs/stages.txt"
  if [ "$(left)" -gt 30 ]; then
    timeout -k 10 $(($(left) + 5)) "$PY" $D worker --work "$WORK" --deadline "$DEADLINE" --id gpu --device auto \
      > "$WORK/logs/worker-gpu.log" 2>&1
    echo "worker gpu exit $? at $(($(date +%s) - T0)) s" >> "$WORK/logs/stages.txt"
  fi
) &
for i in $(seq 1 "$WORKERS"); do
  (
    timeout -k 10 $(($(left) + 5)) "$PY" $D worker --work "$WORK" --deadline "$DEADLINE" --id "$i" --device cpu \
      > "$WORK/logs/worker-$i.log" 2>&1
    echo "worker $i exit $? at $(($(date +%s) - T0)) s" >> "$WORK/logs/stages.txt"
  ) &
done
while [ "$(jobs -r | wc -l)" -gt 0 ]; do
  sleep 15
  echo "$(($(date +%s) - T0)) s: $(ls "$WORK/tasks" 2>/dev/null | wc -l) tasks done; lce: $(tail -n 1 "$WORK/logs/lce.log" 2>/dev/null | cut -c1-150)"
done
wait

timeout -k 5 60 "$PY" $D collect --work "$WORK" --summary "$OUT/summary.md" --results "$OUT/results.json" \
  > "$WORK/logs/collect.log" 2>&1
echo "collect exit $? at $(($(date +%s) - T0)) s" >> "$WORK/logs/stages.txt"
tar -C "$WORK" -czf "$OUT/lce.tar.gz" lce 2>/dev/null
tar -C "$WORK" -czf "$OUT/losses.tar.gz" losses 2>/dev/null
tar -C "$WORK/loo" --exclude="all/by-k-method/*/folds" -czf "$OUT/loo.tar.gz" all 2>/dev/null
tar -C "$WORK" -czf "$OUT/logs.tar.gz" logs tasks 2>/dev/null
ls -l "$OUT"
cat "$WORK/logs/stages.txt"
echo "total $(($(date +%s) - T0)) s"
