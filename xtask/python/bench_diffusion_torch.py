"""diffusers UNet forward on torch CPU, for `cargo xtask bench diffusion`.

Same config (crates/w3d-diffusion/configs/wonder3d/unet/config.json), random weights, batch
2 x 8 x 32 x 32, one timestep, a 1-token 768-d context and 14-d class labels; f32, all CPU
threads. Prints one JSON object: median and all times in ms.

Then the attention of the multi-view UNet's guided step at its five shapes (the same list as
`ATTENTION_SHAPES` in crates/w3d-diffusion/benches/diffusion.rs): torch's
`scaled_dot_product_attention` on [batch, heads, tokens, head_dim] views of token-major
tensors, one JSON object per shape.
"""

import json
import os
import sys

import torch
from diffusers import UNet2DConditionModel

sys.path.insert(0, os.path.dirname(__file__))
from peer_timing import report  # noqa: E402

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
report("unet_forward_b2_32x32/torch", lambda: unet(sample, 500, encoder_hidden_states=context, class_labels=labels),
       runs)

# name, batch, tokens (queries = keys), channels; 8 heads everywhere.
ATTENTION_SHAPES = [
    ("mv32", 4, 6144, 320),
    ("mv16", 4, 3072, 640),
    ("mv8", 4, 1536, 1280),
    ("cd32", 12, 2048, 320),
    ("cd16", 12, 512, 640),
]
for name, batch, tokens, channels in ATTENTION_SHAPES:
    heads = 8
    def split(t):
        return t.view(batch, tokens, heads, channels // heads).transpose(1, 2)
    q, k, v = (torch.randn(batch, tokens, channels) for _ in range(3))
    def attention():
        o = torch.nn.functional.scaled_dot_product_attention(split(q), split(k), split(v))
        return o.transpose(1, 2).reshape(batch, tokens, channels)
    report(f"attention_{name}/torch", attention, runs, gflop=4 * batch * tokens * tokens * channels / 1e9)
