#!/usr/bin/env bash
# Issue 54's GPU bench, run on a lent GPU machine from what bench/gpu_carry.py prepared (carry .carry):
#   bash bench/gpu_run.sh steps  # each model's training step at demo and paper size (batch 256), eager and
#                                # compiled, its sampling and the long sequence (M2D2M's compiled too)
#   bash bench/gpu_run.sh cli    # each training verb through the command line in the carried demo
#                                # project, beside the synthetic batches' steps at the demo size
# Arguments after the part go to bench/gpu.py after the part's own (`cli --quick` tries it on a CPU).
# Each part fits one call of under ten minutes; bench/gpu.py writes its figures after each one, so a
# part stopped at its limit keeps what it measured. gpu.json, gpu.md and the log land in $OUT/<part>.
set -euo pipefail
part=${1:-}
shift || true
carry=${CARRY:-.carry}
case $part in
  steps) args=(--models m2d2m mmm motiondiffuse vq --sizes demo paper --steps 20 --warmup 5 --paper-batches 256
               --train-compile off on --batches 1 32 --long-compiled) ;;
  cli) args=(--models m2d2m mmm motiondiffuse vq --sizes demo --steps 20 --warmup 5 --train-compile off
             --batches 1 --long-minutes 0.1 --cli-project "$carry/demo-project" --cli-steps 500) ;;
  *) echo "usage: bash bench/gpu_run.sh steps|cli (got '$part')" >&2; exit 2 ;;
esac
out=${OUT:-runs/bench/gpu-run}/$part
work=$(mktemp -d)
mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$work/site" "$carry"/wheels/*.whl
export PYTHONPATH="$work/site:$PWD" PYTHONUNBUFFERED=1
# the bench's model files and clips stay in $work: only its figures and the log come back
status=0
python3 bench/gpu.py "${args[@]}" "$@" --out "$work/bench" 2>&1 | tee "$out/log.txt" || status=$?
cp "$work"/bench/gpu.json "$work"/bench/gpu.md "$out"/ 2>/dev/null || echo "bench/gpu_run.sh: no figures were written" >&2
exit $status
