#!/usr/bin/env bash
# The @gpu benchmark blocks, run on a lent GPU machine (issue #27): installs the wheels and the
# EGL libraries carried with the checkout (.whl/, .gl/: prepared by hand, git-ignored), then
# publish.py rewrites the @gpu blocks of docs/benchmarks.md; the docs and the log go to $OUT.
#   run(command="bash benchmarks/gpu_jobs.sh", carry=[".whl", ".gl"], timeout_s=540)
set -o pipefail
export PYTHONUNBUFFERED=1
OUT="${OUT:-/tmp/gpu_out}"; mkdir -p "$OUT"
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl \
  && python3 -m pip install -q --no-index --no-deps --no-build-isolation --target /tmp/site . \
  || { echo "install failed"; exit 1; }
export PYTHONPATH=/tmp/site GLOBEVIEW_CACHE_DIR=/tmp/gvc GLOBEVIEW_CONFIG_DIR=/tmp/gvcfg
export PATH=/tmp/site/bin:$PATH
nvidia-smi --query-gpu=name,driver_version --format=csv 2>&1 | tee "$OUT/gpu.txt"
python3 -m globeview render --size 256x256 --out /tmp/warm.png 2>&1 | tail -2  # ingests the embedded data
timeout 420 python3 benchmarks/publish.py ${GPU_JOBS:-render-4k lod tiles flight-async} 2>&1 | tee "$OUT/publish.log"
cp docs/benchmarks.md "$OUT/"
