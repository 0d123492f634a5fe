#!/usr/bin/env bash
# Issue 53's GPU check, for the device tool (`run`, in the repository root; results in $OUT):
#
#   bash benchmarks/gpu_check.sh       (carry: .gpu-carry, made here by benchmarks/gpu_prepare.sh;
#                                       timeout_s 600)
#
# 1. installs this checkout without its dependencies (the machine's image brings PyTorch with
#    CUDA, Triton and ONNX Runtime; it has no network) and, from .gpu-carry/wheels, what evsmap
#    needs and the image lacks;
# 2. runs benchmarks/gpu_check.py within a 480 s budget (8 minutes; the install takes about a
#    minute before it, so the run fits the tool's 600 s), most important step first, each step
#    with its own timeout: (a) speed vs gate, (b) backend sweeps, (c) batch sweeps, (d) EVSMap
#    end to end on TUM, (e) the resume proof, (f) the gate's GPU kind. Its log, JSON and
#    Markdown table in $OUT (gpu_check.{log,json,md}, gpu_baseline.json,
#    gpu_pair_baseline.json). Device time: about 9 minutes of the session's 15 with the start;
#    BUDGET=300 bash benchmarks/gpu_check.sh keeps steps (a)-(c) and whatever fits.
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
  python3 benchmarks/gpu_check.py --out "$OUT" --data .gpu-carry --budget "${BUDGET:-480}" "$@"
} 2>&1 | tee "$OUT/gpu_check.log"
