"""diffusers UNet forward on torch CPU, for `cargo xtask bench diffusion`.

Same config (crates/w3d-diffusion/configs/wonder3d/unet/config.json), random weights, batch
2 x 8 x 32 x 32, one timestep, a 1-token 768-d context and 14-d class labels; f32, all CPU
threads. Prints one JSON object: median and all times in ms.
"""

import json
import os
import statistics
import sys
import time

import torch
from diffusers import UNet2DConditionModel

root = sys.argv[1]
runs = int(sys.argv[2]) if len(sys.argv) > 2 else 5
torch.set_grad_enabled(False)
torch.set_num_threads(os.cpu_count())
with open(os.path.join(root, "crates/w3d-diffusion/configs/wonder3d/unet/config.json")) as f:
    config = {k: v for k, v in json.load(f).items() if not k.startswith("_")}
unet = UNet2DConditionModel(**config).eval()
sample = torch.randn(2, 8, 32, 32)
context = torch.randn(2, 1, 768)
labels = torch.randn(2, 14)
unet(sample, 500, encoder_hidden_states=context, class_labels=labels)
times = []
for _ in range(runs):
    t = time.perf_counter()
    unet(sample, 500, encoder_hidden_states=context, class_labels=labels)
    times.append((time.perf_counter() - t) * 1e3)
print(json.dumps({
    "id": "unet_forward_b2_32x32/torch",
    "median_ms": statistics.median(times),
    "times_ms": times,
    "torch": torch.__version__,
    "threads": torch.get_num_threads(),
}))
