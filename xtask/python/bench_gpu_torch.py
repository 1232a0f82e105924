"""The real-size multi-view UNet's guided step on a CUDA GPU in PyTorch + diffusers: the peer
of `cargo xtask bench gpu` (docs/benchmarks.md, "On a GPU").

The Wonder3D++ UNet (crates/w3d-diffusion/configs/wonder3d/unet/config.json with the multi-view
self-attention and the cross-domain attention of `fixtures_diffusion.make_multiview`, the same
blocks the parity fixtures check), random weights, one forward of the guided step's batch:
24 images (6 views x normal and colour x conditional and unconditional) of 8 x 32 x 32, a
1-token 768-d context and 14-d class labels. In f32 (what the Burn wgpu backend runs) and in
f16 (what the authors' inference runs), with `torch.cuda.synchronize()` inside the timing.
Prints one JSON line per precision (see peer_timing.report).

    python3 xtask/python/bench_gpu_torch.py REPO_ROOT [RUNS]
"""

import json
import os
import sys

import torch
from diffusers import UNet2DConditionModel

sys.path.insert(0, os.path.dirname(__file__))
from fixtures_diffusion import make_multiview  # noqa: E402
from peer_timing import report  # noqa: E402

root = sys.argv[1]
runs = int(sys.argv[2]) if len(sys.argv) > 2 else 10
torch.set_grad_enabled(False)
device = torch.device("cuda")
with open(os.path.join(root, "crates/w3d-diffusion/configs/wonder3d/unet/config.json")) as f:
    config = {k: v for k, v in json.load(f).items() if not k.startswith("_")}
torch.manual_seed(0)
unet = UNet2DConditionModel(**config)
make_multiview(unet)
unet = unet.to(device).eval()
params = sum(p.numel() for p in unet.parameters())

for dtype, name in [(torch.float32, "f32"), (torch.float16, "f16")]:
    unet = unet.to(dtype)
    sample = torch.randn(24, 8, 32, 32, device=device, dtype=dtype)
    context = torch.randn(24, 1, 768, device=device, dtype=dtype)
    labels = torch.randn(24, 14, device=device, dtype=dtype)

    def step():
        unet(sample, 500, encoder_hidden_states=context, class_labels=labels)
        torch.cuda.synchronize()

    report(f"guided_step_24/torch-cuda-{name}", step, runs, warmup=3, gpu=torch.cuda.get_device_name(),
           unet_params_m=params / 1e6, tf32_matmul=torch.backends.cuda.matmul.allow_tf32,
           tf32_cudnn=torch.backends.cudnn.allow_tf32,
           peak_gib=torch.cuda.max_memory_allocated() / 2**30)
