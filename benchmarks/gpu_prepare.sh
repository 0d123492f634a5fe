#!/usr/bin/env bash
# What benchmarks/gpu_check.sh needs on a device machine that has no network, made here into
# .gpu-carry/ (git-ignored; name it in the device run's `carry`):
#
#   bash benchmarks/gpu_prepare.sh [PYTHON_VERSION]     # default 3.12, the device image's
#
# - wheels/: what evsmap's GPU check imports beyond the device image (which brings PyTorch
#   with CUDA, Triton, NumPy, SciPy, numba, ONNX, ONNX Runtime (CPU) and the usual scientific
#   stack; /work/.library/device/KINDS.md lists it), at constraints.txt's versions;
# - tum_fr1_xyz/: the TUM RGB-D sample (../shared does not travel), for `evsmap map`;
# - train/: 16 labelled frames of the synthetic room at 320x240 (`evsmap synth`; the image has
#   no Open3D to render them there), for `evsmap train`.
#
# The working tree that travels is limited to 64 MiB: the script prints the folder's size.
set -euo pipefail
PY="${1:-3.12}"
DEST=.gpu-carry
SHARED="${EVSMAP_SHARED:-../shared}"
rm -rf "$DEST"
mkdir -p "$DEST/wheels"
grep -qxF "/$DEST/" .git/info/exclude 2>/dev/null || echo "/$DEST/" >> .git/info/exclude
BINARY=(termcolor pydantic pydantic-core annotated-types typing-inspection pooch platformdirs
        plyfile)
python3 -m pip download -q --no-deps --only-binary=:all: --dest "$DEST/wheels" \
  --python-version "$PY" --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 \
  --platform manylinux_2_28_x86_64 --platform any -c constraints.txt "${BINARY[@]}" 2>&1 \
  | grep -v "^WARNING: Location" || true
# fvcore, iopath and yacs publish source archives only: built into wheels here (pure Python)
python3 -m pip wheel -q --no-deps -c constraints.txt -w "$DEST/wheels" fvcore iopath yacs 2>&1 \
  | grep -v "^WARNING: Location" || true
cp -r "$SHARED/data/tum_fr1_xyz" "$DEST/tum_fr1_xyz"
python3 -m evsmap synth --out "$DEST/train" --frames 16 --width 320 --height 240 --noise
du -sh "$DEST" "$DEST"/*
ls "$DEST/wheels"
