#!/usr/bin/env bash
# Issue 41's GPU check, for the device tool (`run`, in the repository root; results in $OUT):
#
#   bash benchmarks/gpu_check.sh       (carry: .gpu-carry, made here by benchmarks/gpu_prepare.sh;
#                                       timeout_s 600)
#
# 1. installs this checkout without its dependencies (the machine's image brings PyTorch with
#    CUDA, Triton and ONNX Runtime; it has no network) and, from .gpu-carry/wheels, what evsmap
#    needs and the image lacks;
# 2. runs benchmarks/gpu_check.py within a 500 s budget, its log, JSON and Markdown summary in
#    $OUT (at most 8 files come back: gpu_check.{log,json,md}, gpu_baseline.json).
set -uo pipefail
OUT="${OUT:-/tmp/gpu-check}"
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 EVSMAP_CACHE_DIR="${EVSMAP_CACHE_DIR:-/tmp/evsmap-cache}"
{
  nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv || true
  python3 -c 'import sys, torch; print("python", sys.version.split()[0], "torch", torch.__version__, "cuda", torch.version.cuda, torch.cuda.is_available())'
  if [ -d .gpu-carry/wheels ]; then
    python3 -m pip install -q --no-index --no-deps .gpu-carry/wheels/*.whl 2>&1 | tail -3
  fi
  python3 -m pip install -q --no-deps --no-build-isolation -e . 2>&1 | tail -3
  for m in fvcore numba scipy pandas pydantic tqdm onnx onnxscript onnxruntime PIL; do
    python3 -c "import $m" 2>/dev/null || echo "missing module: $m"
  done
  python3 benchmarks/gpu_check.py --out "$OUT" --data .gpu-carry --budget "${BUDGET:-500}" "$@"
} 2>&1 | tee "$OUT/gpu_check.log"
