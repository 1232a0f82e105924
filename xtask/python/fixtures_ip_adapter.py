"""Parity fixtures of the IP-Adapter (enhancer) parts of crates/w3d-diffusion.

Run from the repository root with the fixture Python environment:

    python xtask/python/fixtures_ip_adapter.py

It writes crates/w3d-diffusion/tests/fixtures/ip_adapter/:

- `unet/`: a tiny SD-layout `UNet2DConditionModel` (4 → 4 channels, block_out_channels (16, 32),
  CrossAttnDownBlock2D + DownBlock2D, UpBlock2D + CrossAttnUpBlock2D, one layer per block,
  cross_attention_dim 32, 4 heads, 8 norm groups, perturbed norms), weights stored in f16 (the
  reference runs on the same f16-rounded values in f32) to keep the fixture small;
- `ip_adapter.safetensors`: a random IP-Adapter in the `ip-adapter_sd15.safetensors` *file*
  layout (`image_proj.proj.{weight,bias}` [4·32, 24], `image_proj.norm.{weight,bias}` [32],
  `ip_adapter.{k}.to_{k,v}_ip.weight` [hidden, 32] for k = 1, 3, 5, 7), loaded into diffusers with
  diffusers' own loader (`unet._load_ip_adapter_weights`), so the key mapping is checked
  independently of ours;
- `io.safetensors`: the image projection of `image_embeds` [2, 24] (a zero row and an
  embedding), and UNet forwards of a batch of 4 with text context and IP tokens (rows 0-1
  from zero embeddings, rows 2-3 from the embedding, as the enhancer's guided batch) at IP
  scale 1.0 and 0.6, with 8 duplicated tokens per row (two identical images per row, as the
  authors' pipeline builds them) and without the adapter;
- `clip_gelu/`: a tiny `CLIPVisionModelWithProjection` with `hidden_act="gelu"` (as the ViT-H/14
  image encoder) and its `image_embeds` for two pixel tensors (`clip_gelu/io.safetensors`);
- `preprocess.safetensors`: `CLIPImageProcessor` (shortest edge 20, crop 20) fed float images
  already in [0, 1], which it rescales a second time (the authors' quirk): a random image and an
  image of only 0s and 1s (which transformers takes for 8-bit values and does not scale to 255
  before resizing).

Last written with torch 2.4.1, diffusers 0.30.3, transformers 4.44.2 (CPU, f32).
"""

import os
import sys

import numpy as np
import torch
from diffusers import UNet2DConditionModel
from diffusers.models.attention_processor import IPAdapterAttnProcessor, IPAdapterAttnProcessor2_0
from safetensors.torch import save_file
from transformers import CLIPImageProcessor, CLIPVisionConfig, CLIPVisionModelWithProjection

sys.path.insert(0, os.path.dirname(__file__))
from fixtures_diffusion import perturb_norms, save, state, write_config  # noqa: E402

OUT = os.path.join(
    os.path.dirname(__file__), "..", "..", "crates", "w3d-diffusion", "tests", "fixtures", "ip_adapter"
)
torch.manual_seed(0)
torch.set_grad_enabled(False)

CROSS = 32
EMBED = 24
TOKENS = 4


def set_ip_scale(unet, scale):
    for proc in unet.attn_processors.values():
        if isinstance(proc, (IPAdapterAttnProcessor, IPAdapterAttnProcessor2_0)):
            proc.scale = [scale]


def unet_fixture():
    d = os.path.join(OUT, "unet")
    os.makedirs(d, exist_ok=True)
    config = dict(
        sample_size=8,
        in_channels=4,
        out_channels=4,
        down_block_types=["CrossAttnDownBlock2D", "DownBlock2D"],
        up_block_types=["UpBlock2D", "CrossAttnUpBlock2D"],
        block_out_channels=[16, 32],
        layers_per_block=1,
        norm_num_groups=8,
        cross_attention_dim=CROSS,
        attention_head_dim=4,
    )
    unet = UNet2DConditionModel(**config).eval()
    perturb_norms(unet)
    for p in unet.parameters():
        p.copy_(p.half().float())
    save_file(state(unet, torch.float16), os.path.join(d, "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(d, "config.json"), dict(unet.config))

    # The IP-Adapter in the file layout: cross-attention layers in diffusers' module order
    # (down, up, mid) get k = 1, 3, 5, 7 with their hidden widths.
    hidden = [16, 16, 16, 32]  # down_blocks.0.a0, up_blocks.1.a0, up_blocks.1.a1, mid_block.a0
    ip_file = {
        "image_proj.proj.weight": torch.randn(TOKENS * CROSS, EMBED) * 0.3,
        "image_proj.proj.bias": torch.randn(TOKENS * CROSS) * 0.5,
        "image_proj.norm.weight": 1.0 + 0.2 * torch.randn(CROSS),
        "image_proj.norm.bias": 0.2 * torch.randn(CROSS),
    }
    for i, h in enumerate(hidden):
        k = 2 * i + 1
        ip_file[f"ip_adapter.{k}.to_k_ip.weight"] = torch.randn(h, CROSS) * 0.3
        ip_file[f"ip_adapter.{k}.to_v_ip.weight"] = torch.randn(h, CROSS) * 0.3
    save(ip_file, os.path.join(OUT, "ip_adapter.safetensors"))

    sample = torch.randn(4, 4, 8, 8)
    timesteps = torch.tensor([10.0, 10.0, 601.0, 601.0])
    context = torch.randn(4, 3, CROSS)
    out_plain = unet(sample, timesteps, encoder_hidden_states=context).sample

    nested = {"image_proj": {}, "ip_adapter": {}}
    for key, value in ip_file.items():
        top, rest = key.split(".", 1)
        nested[top][rest] = value
    unet._load_ip_adapter_weights([nested])
    unet.eval()

    embed = torch.randn(EMBED)
    proj_in = torch.stack([torch.zeros(EMBED), embed])
    proj_out = unet.encoder_hid_proj.image_projection_layers[0](proj_in)
    # [batch, images, embed]: rows 0-1 zeros (the unconditional half), rows 2-3 the embedding.
    embeds = torch.stack([torch.zeros(EMBED), torch.zeros(EMBED), embed, embed]).reshape(4, 1, EMBED)
    outs = {}
    for name, scale in [("out_s1", 1.0), ("out_s06", 0.6)]:
        set_ip_scale(unet, scale)
        outs[name] = unet(
            sample, timesteps, encoder_hidden_states=context, added_cond_kwargs={"image_embeds": [embeds]}
        ).sample
    set_ip_scale(unet, 1.0)
    twice = embeds.repeat(1, 2, 1)  # two identical images per row: 8 tokens per row
    outs["out_dup"] = unet(
        sample, timesteps, encoder_hidden_states=context, added_cond_kwargs={"image_embeds": [twice]}
    ).sample
    save(
        {
            "proj_in": proj_in,
            "proj_out": proj_out,
            "sample": sample,
            "timesteps": timesteps,
            "context": context,
            "image_embeds": embeds.reshape(4, EMBED),
            "out_plain": out_plain,
            **outs,
        },
        os.path.join(OUT, "io.safetensors"),
    )
    diff = (outs["out_s1"] - out_plain).abs().max().item()
    print(f"ip-adapter changes the UNet output by up to {diff:.3f}")


def clip_gelu_fixture():
    d = os.path.join(OUT, "clip_gelu")
    os.makedirs(d, exist_ok=True)
    config = CLIPVisionConfig(
        hidden_size=32,
        intermediate_size=64,
        projection_dim=16,
        num_hidden_layers=2,
        num_attention_heads=4,
        image_size=28,
        patch_size=7,
        hidden_act="gelu",
    )
    model = CLIPVisionModelWithProjection(config).eval()
    perturb_norms(model)
    save_file(state(model), os.path.join(d, "model.safetensors"))
    config.save_pretrained(d)
    # Large pre-activations, where erf GELU and its tanh approximation differ.
    pixels = torch.randn(2, 3, 28, 28) * 2.0
    embeds = model(pixel_values=pixels).image_embeds
    save({"pixels": pixels, "embeds": embeds}, os.path.join(d, "io.safetensors"))


def preprocess_fixture():
    processor = CLIPImageProcessor(size={"shortest_edge": 20}, crop_size={"height": 20, "width": 20})
    rng = np.random.default_rng(3)
    image = rng.random((26, 31, 3), dtype=np.float32)
    binary = (rng.random((23, 21, 3)) > 0.5).astype(np.float32)
    out = {}
    for name, img in [("random", image), ("binary", binary)]:
        out[f"{name}_rgb"] = torch.from_numpy(img)
        out[f"{name}_pixels"] = processor(images=img, return_tensors="pt").pixel_values[0]
    save(out, os.path.join(OUT, "preprocess.safetensors"))
    print("random image through the quirk: per-channel means", out["random_pixels"].mean(dim=(1, 2)).tolist())


def main():
    os.makedirs(OUT, exist_ok=True)
    unet_fixture()
    clip_gelu_fixture()
    preprocess_fixture()
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(OUT) for f in fs)
    print(f"fixtures written to {os.path.normpath(OUT)}: {total / 1e6:.2f} MB")
    if total > 1e6:
        sys.exit("ip-adapter fixtures exceed 1 MB")


if __name__ == "__main__":
    main()
