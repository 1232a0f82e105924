"""How close the UNet forward comes to the machine's GEMM peak (issue #20, item 6).

Counts the floating-point operations of the real-size UNet forward that
`cargo xtask bench diffusion -- unet_forward` times (batch 2 x 8 x 32 x 32, the config of
crates/w3d-diffusion/configs/wonder3d/unet, random weights) with torch's FlopCounterMode
(2 per multiply-add of matmuls, convolutions and attention; element-wise work not counted),
and measures an f32 GEMM peak on the same machine with torch.mm at 2048..4096 (best of 5).
Prints one JSON object. Usage: python unet_flops.py REPO_ROOT
"""

import json
import os
import sys
import time

import torch
from diffusers import UNet2DConditionModel
from torch.utils.flop_counter import FlopCounterMode

root = sys.argv[1]
torch.set_grad_enabled(False)
torch.set_num_threads(os.cpu_count())
with open(os.path.join(root, "crates/w3d-diffusion/configs/wonder3d/unet/config.json")) as f:
    config = {k: v for k, v in json.load(f).items() if not k.startswith("_")}
unet = UNet2DConditionModel(**config).eval()
sample, context, labels = torch.randn(2, 8, 32, 32), torch.randn(2, 1, 768), torch.randn(2, 14)
with FlopCounterMode(display=False) as counter:
    unet(sample, 500, encoder_hidden_states=context, class_labels=labels)
flops = counter.get_total_flops()

peak = {}
for n in (2048, 3072, 4096):
    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    best = min(
        (lambda t: (torch.mm(a, b), time.perf_counter() - t)[1])(time.perf_counter()) for _ in range(5)
    )
    peak[n] = 2 * n**3 / best / 1e9
print(json.dumps({
    "unet_forward_gflop": flops / 1e9,
    "sgemm_gflops": peak,
    "torch": torch.__version__,
    "threads": torch.get_num_threads(),
}))
