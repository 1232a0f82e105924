#!/bin/bash
# The GPU checks and benchmarks on a lent GPU machine without a Rust toolchain
# (docs/gpu.md, "On a lent GPU machine"): run from the repository root there, after
# xtask/gpu-lease/pack.sh here, with .devbin and .gl carried (and .whl for the PyTorch peer).
# Every part has its own timeout and writes under $OUT as it goes; about 5 min on an H200.
set -u
T0=$(date +%s)
log() { echo "=== [$(( $(date +%s) - T0 )) s] $*"; }
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
ICD=$(find /usr/local/nvidia /usr/share/vulkan /etc/vulkan -name "nvidia_icd*.json" 2>/dev/null | head -1)
echo "ICD: $ICD"
[ -n "$ICD" ] && export VK_DRIVER_FILES=$ICD
ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/nvidia/share/vulkan/icd.d 2>&1 | head -5
# The test and bench binaries find their fixtures through the build machine's checkout path.
ROOT=$(cat .devbin/build_root)
if [ "$PWD" != "$ROOT" ]; then mkdir -p "$(dirname "$ROOT")" && ln -sfn "$PWD" "$ROOT"; fi
cd "$ROOT"
python3 -c "
import tarfile
tarfile.open('.devbin/bins.txz').extractall('.devbin')"
B=.devbin; W=$B/wonder3d
nvidia-smi -L; nproc; ls -la $B
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
ldconfig -p | grep -E "libvulkan|GLX_nvidia|GLdispatch" | head
grep library_path $ICD
$W render assets/spot.obj --size 256 --out /tmp/spot-views
if ! timeout 60 $W generate /tmp/spot-views/colour_front.png --weights assets/model-small --steps 2 --quiet --device wgpu --out /tmp/gen-probe; then
  VK_LOADER_DEBUG=error,warn,info timeout 30 $W generate /tmp/spot-views/colour_front.png --weights assets/model-small --steps 2 --quiet --device wgpu --out /tmp/gen-probe2 2>&1 | tail -40
  log "no wgpu adapter: stopping"; exit 3
fi
log "1. real-size generation benchmark on wgpu"
timeout 200 $B/gpu-bench --model real --device wgpu --runs dpmpp-2m:20,ddim:50 --json $OUT/gpu-real.json > $OUT/bench-real.log 2>&1; echo "rc $?" >> $OUT/bench-real.log
tail -20 $OUT/bench-real.log
log "2. wgpu tests (wgpu vs flex)"
timeout 90 $B/wgpu-test --test-threads 1 --nocapture > $OUT/wgpu-tests.log 2>&1; echo "rc $?" >> $OUT/wgpu-tests.log
grep -E "adapter|max|test result|panicked|error|rc " $OUT/wgpu-tests.log | head -30
log "3. PyTorch peer (CUDA), when the diffusers wheels came along in .whl"
if ls .whl/*.whl >/dev/null 2>&1; then
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site
timeout 80 python3 xtask/python/bench_gpu_torch.py "$PWD" 10 > $OUT/torch.jsonl 2> $OUT/torch.err; echo "rc $?" >> $OUT/torch.err
cat $OUT/torch.jsonl; tail -5 $OUT/torch.err
fi
log "4. small model: generate on wgpu and cpu, photo -> mesh on wgpu"
(
  for d in wgpu cpu; do s=$(date +%s%N); timeout 40 $W generate /tmp/spot-views/colour_front.png --weights assets/model-small --steps 20 --quiet --device $d --out /tmp/gen-$d; echo "generate 20 steps $d rc $? $(( ($(date +%s%N) - s) / 1000000 )) ms"; done
  python3 - <<'PY'
import numpy as np
from PIL import Image
worst, mask = 0, []
for v in ["front", "front_right", "right", "back", "left", "front_left"]:
    for k in ["colour", "normal", "mask"]:
        a = np.asarray(Image.open(f"/tmp/gen-wgpu/{k}_{v}.png")).astype(int)
        b = np.asarray(Image.open(f"/tmp/gen-cpu/{k}_{v}.png")).astype(int)
        if k == "mask":
            mask.append((np.abs(a - b) > 127).mean())
        else:
            worst = max(worst, np.abs(a - b).max())
print(f"wgpu vs cpu: colour/normal PNGs differ by at most {worst}/255, masks in {100 * max(mask):.3f} % of pixels")
PY
  s=$(date +%s%N); timeout 60 $W demo --from-image --device wgpu --out /tmp/demo-gpu; echo "demo --from-image wgpu rc $? $(( ($(date +%s%N) - s) / 1000000 )) ms"
  cp /tmp/demo-gpu/report.json $OUT/demo-gpu-report.json
) > $OUT/small.log 2>&1
tail -25 $OUT/small.log
log "5. training steps of the small model on wgpu and on the 16-core CPU"
( $W dataset assets/spot.obj assets/bob_tri.obj --out /tmp/ds --samples 2 --size 64 --quiet
  timeout 50 $W train --stage 3 --train-all --min-snr-gamma none --background white --data /tmp/ds --init assets/model-small --out /tmp/tr-wgpu --steps 40 --warmup 0 --checkpoint-every 1000 --device wgpu --quiet; echo "train wgpu rc $?"
  cp /tmp/tr-wgpu/train_log.jsonl $OUT/train-wgpu.jsonl
  timeout 30 $W train --stage 3 --train-all --min-snr-gamma none --background white --data /tmp/ds --init assets/model-small --out /tmp/tr-cpu --steps 10 --warmup 0 --checkpoint-every 1000 --device cpu --quiet; echo "train cpu rc $?"
  cp /tmp/tr-cpu/train_log.jsonl $OUT/train-cpu.jsonl
) > $OUT/train.log 2>&1
tail -8 $OUT/train.log
log "done"
