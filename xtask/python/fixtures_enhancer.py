"""End-to-end parity fixture of the Wonder3D++ enhancer call for crates/w3d-diffusion (run by
`cargo xtask fixtures diffusion`, or directly from the repository root:
`python xtask/python/fixtures_enhancer.py`; needs the clip_text fixtures written first).

Builds a complete tiny enhancer directory in the layout `EnhancerPipeline::from_dir` reads
(`docs/weights.md`, "The enhancer") from diffusers / transformers modules with random weights:
- `unet/`: a Stable-Diffusion-layout `UNet2DConditionModel` (4 → 4, levels (8, 16)), with an
  IP-Adapter loaded by diffusers' own loader from `ip_adapter/ip-adapter_sd15.safetensors`
  (the file layout, k = 1, 3, … over the cross-attention layers);
- `controlnet/`: `ControlNetModel.from_unet` with the cross-domain attention of every
  transformer block (`fixtures_controlnet.add_joint_attention`, written from a description of
  the authors' block), zero-initialised layers randomised;
- `vae/`: an 8× `AutoencoderKL`; `text_encoder/`, `tokenizer/`: the clip_text fixtures;
  `image_encoder/`: a `CLIPVisionModelWithProjection` with `gelu`;
- `scheduler/scheduler_config.json`: Stable Diffusion 1.5's PNDM config, which has no
  `timestep_spacing`, so UniPC uses its default `linspace` (as in the authors' run).

Then one enhancer call as the authors' pipeline runs it (`reference/enhancer.md` of the design
notes, summarised in `docs/refinement.md`), written here step by step on those modules: the
grids `[colour, normal]` (2×2 tiles of 32²) are the init and the control image; VAE posterior
sample with given noise, × scaling factor; UniPC (50 steps, strength 0.2 → timesteps 200 … 20),
forward noise with given noise at the first timestep; per step the ControlNet in the domain
order `[c_uc, c_cond, n_uc, n_cond]` at conditioning scale 0.7, its residuals put back into the
guidance order `[c_uc, n_uc, c_cond, n_cond]`, the UNet with text and IP tokens (uncond rows:
empty prompt and the projection of a zero embedding; the IP image seen by CLIP as the authors'
preprocessing leaves it: a float [0, 1] image rescaled once more), guidance 3. Both the
corrected batch order and the authors' released order (ControlNet text rows in guidance order;
mid residual's channel blocks permuted instead of its rows) are recorded.

Written with torch 2.4.1, diffusers 0.30.3, transformers 4.44.2.
"""

import json
import os
import shutil
import sys

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import load_file

sys.path.insert(0, os.path.dirname(__file__))
from fixtures_controlnet import add_joint_attention, randomise_zero_init  # noqa: E402
from fixtures_diffusion import perturb_norms, save, state, write_config  # noqa: E402

from diffusers import AutoencoderKL, ControlNetModel, UNet2DConditionModel, UniPCMultistepScheduler  # noqa: E402
from transformers import (  # noqa: E402
    CLIPImageProcessor,
    CLIPTextConfig,
    CLIPTextModel,
    CLIPTokenizer,
    CLIPVisionConfig,
    CLIPVisionModelWithProjection,
)

FIXTURES = os.path.join(os.path.dirname(__file__), "..", "..", "crates", "w3d-diffusion", "tests", "fixtures")
OUT = os.path.join(FIXTURES, "enhancer")
CROSS = 32
EMBED = 24
TOKENS = 4
STEPS, STRENGTH, CONTROL_SCALE, GUIDANCE = 50, 0.2, 0.7, 3.0
PROMPTS = ["", "4views, multiview color", "4views, multiview normal map"]
SD15_SCHEDULER = {
    "_class_name": "PNDMScheduler",
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "beta_start": 0.00085,
    "clip_sample": False,
    "num_train_timesteps": 1000,
    "set_alpha_to_one": False,
    "skip_prk_steps": True,
    "steps_offset": 1,
    "trained_betas": None,
}
torch.set_grad_enabled(False)


def to_f16_values(model):
    for p in model.parameters():
        p.copy_(p.half().float())


def save_diffusers(model, name, dtype=torch.float16):
    d = os.path.join(OUT, name)
    os.makedirs(d, exist_ok=True)
    save(state(model, dtype), os.path.join(d, "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(d, "config.json"), dict(model.config))


def ip_adapter_file(unet):
    """A random IP-Adapter in the file layout: k = 1, 3, … over the cross-attention layers in
    module order (down, up, mid), each with its layer's width."""
    hidden = [m.to_q.out_features for n, m in unet.named_modules() if n.endswith("attn2")]
    sd = {
        "image_proj.proj.weight": torch.randn(TOKENS * CROSS, EMBED) * 0.3,
        "image_proj.proj.bias": torch.randn(TOKENS * CROSS) * 0.5,
        "image_proj.norm.weight": 1.0 + 0.2 * torch.randn(CROSS),
        "image_proj.norm.bias": 0.2 * torch.randn(CROSS),
    }
    for i, h in enumerate(hidden):
        sd[f"ip_adapter.{2 * i + 1}.to_k_ip.weight"] = (torch.randn(h, CROSS) * 0.3).half().float()
        sd[f"ip_adapter.{2 * i + 1}.to_v_ip.weight"] = (torch.randn(h, CROSS) * 0.3).half().float()
    return {k: v.half().float() for k, v in sd.items()}


def smooth_images(n, size, seed):
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(n, 3, size // 8, size // 8, generator=g)
    return F.interpolate(coarse, size=(size, size), mode="bilinear", align_corners=False).clamp(0, 1)


def cfg_to_domain(x):
    """[c_uc, n_uc, c_cond, n_cond] → [c_uc, c_cond, n_uc, n_cond] (an involution)."""
    a, b, c, d = x.chunk(4)
    return torch.cat([a, c, b, d])


def main():
    torch.manual_seed(24)
    if os.path.isdir(OUT):
        shutil.rmtree(OUT)
    os.makedirs(OUT)

    unet = UNet2DConditionModel(
        sample_size=8,
        in_channels=4,
        out_channels=4,
        down_block_types=["CrossAttnDownBlock2D", "DownBlock2D"],
        up_block_types=["UpBlock2D", "CrossAttnUpBlock2D"],
        block_out_channels=[8, 16],
        layers_per_block=1,
        norm_num_groups=4,
        cross_attention_dim=CROSS,
        attention_head_dim=2,
    ).eval()
    perturb_norms(unet)
    to_f16_values(unet)
    controlnet = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(4, 8, 8, 16)).eval()
    add_joint_attention(controlnet)
    randomise_zero_init(controlnet)
    perturb_norms(controlnet)
    to_f16_values(controlnet)
    save_diffusers(unet, "unet")
    save_diffusers(controlnet, "controlnet")

    ip = ip_adapter_file(unet)
    os.makedirs(os.path.join(OUT, "ip_adapter"))
    save(ip, os.path.join(OUT, "ip_adapter", "ip-adapter_sd15.safetensors"))
    nested = {"image_proj": {}, "ip_adapter": {}}
    for key, value in ip.items():
        top, rest = key.split(".", 1)
        nested[top][rest] = value
    unet._load_ip_adapter_weights([nested])
    unet.eval()

    vae = AutoencoderKL(
        in_channels=3,
        out_channels=3,
        down_block_types=["DownEncoderBlock2D"] * 4,
        up_block_types=["UpDecoderBlock2D"] * 4,
        block_out_channels=[8, 8, 16, 16],
        layers_per_block=1,
        latent_channels=4,
        norm_num_groups=4,
        sample_size=64,
    ).eval()
    perturb_norms(vae)
    to_f16_values(vae)
    save_diffusers(vae, "vae")

    for part in ["text_encoder", "tokenizer"]:
        shutil.copytree(os.path.join(FIXTURES, "clip_text", part), os.path.join(OUT, part))
    text_dir = os.path.join(OUT, "text_encoder")
    text_encoder = CLIPTextModel(CLIPTextConfig.from_pretrained(text_dir)).eval()
    missing, _ = text_encoder.load_state_dict(load_file(os.path.join(text_dir, "model.safetensors")), strict=False)
    assert not missing, missing
    tokenizer = CLIPTokenizer.from_pretrained(os.path.join(OUT, "tokenizer"))

    vision_config = CLIPVisionConfig(
        hidden_size=32,
        intermediate_size=48,
        projection_dim=EMBED,
        num_hidden_layers=2,
        num_attention_heads=4,
        image_size=32,
        patch_size=8,
        hidden_act="gelu",
    )
    image_encoder = CLIPVisionModelWithProjection(vision_config).eval()
    perturb_norms(image_encoder)
    d = os.path.join(OUT, "image_encoder")
    os.makedirs(d)
    save(state(image_encoder), os.path.join(d, "model.safetensors"))
    vision_config.save_pretrained(d)

    os.makedirs(os.path.join(OUT, "scheduler"))
    with open(os.path.join(OUT, "scheduler", "scheduler_config.json"), "w") as f:
        json.dump(SD15_SCHEDULER, f, indent=1, sort_keys=True)

    # The text: three prompts padded to 77 tokens.
    ids = tokenizer(PROMPTS, padding="max_length", max_length=77, truncation=True, return_tensors="pt").input_ids
    uc, colour, normal = text_encoder(ids).last_hidden_state.chunk(3)

    # The IP image as the authors' pipeline hands it to CLIP: a float [0, 1] array, rescaled again.
    rng = np.random.default_rng(5)
    ip_image = rng.random((40, 48, 3)).astype(np.float32)
    processor = CLIPImageProcessor(size={"shortest_edge": 32}, crop_size={"height": 32, "width": 32})
    pixels = processor(images=ip_image, return_tensors="pt").pixel_values
    embeds = image_encoder(pixel_values=pixels).image_embeds
    project = unet.encoder_hid_proj.image_projection_layers[0]
    ip_uncond = project(torch.zeros_like(embeds))
    ip_cond = project(embeds)

    # The call.
    grids = torch.cat([smooth_images(1, 64, 1), smooth_images(1, 64, 2)])
    posterior_noise = torch.randn(2, 4, 8, 8)
    noise = torch.randn(2, 4, 8, 8)
    dist = vae.encode(grids * 2 - 1).latent_dist
    init = (dist.mean + dist.std * posterior_noise) * vae.config.scaling_factor

    scheduler = UniPCMultistepScheduler.from_config(SD15_SCHEDULER)
    tensors = {
        "grids": grids,
        "posterior_noise": posterior_noise,
        "noise": noise,
        "init": init,
        "ip_image": torch.from_numpy(ip_image),
        "prompt_uncond": uc,
        "prompt_colour": colour,
        "prompt_normal": normal,
        "ip_uncond": ip_uncond,
        "ip_cond": ip_cond,
    }
    prompt_embeds = torch.cat([uc, uc, colour, normal])  # guidance order
    image_embeds = torch.cat([torch.zeros_like(embeds), torch.zeros_like(embeds), embeds, embeds]).unsqueeze(1)
    control = torch.cat([grids, grids])  # [c, n, c, n]
    for name, upstream_bugs in [("fixed", False), ("upstream", True)]:
        scheduler.set_timesteps(STEPS)
        t_start = STEPS - int(STEPS * STRENGTH)
        timesteps = scheduler.timesteps[t_start:]
        scheduler.set_begin_index(t_start)
        latents = scheduler.add_noise(init, noise, timesteps[:1].repeat(2))
        tensors["noised"] = latents
        tensors["timesteps"] = timesteps.float()
        control_text = prompt_embeds if upstream_bugs else cfg_to_domain(prompt_embeds)
        for t in timesteps:
            model_input = torch.cat([latents, latents])
            down, mid = controlnet(
                cfg_to_domain(model_input),
                t,
                encoder_hidden_states=control_text,
                controlnet_cond=cfg_to_domain(control),
                conditioning_scale=CONTROL_SCALE,
                return_dict=False,
            )
            down = [cfg_to_domain(r) for r in down]
            if upstream_bugs:
                mid = torch.stack([cfg_to_domain(m) for m in mid])  # the channel blocks, not the rows
            else:
                mid = cfg_to_domain(mid)
            out = unet(
                model_input,
                t,
                encoder_hidden_states=prompt_embeds,
                down_block_additional_residuals=down,
                mid_block_additional_residual=mid,
                added_cond_kwargs={"image_embeds": [image_embeds]},
            ).sample
            uncond, cond = out.chunk(2)
            latents = scheduler.step(uncond + GUIDANCE * (cond - uncond), t, latents).prev_sample
        tensors[f"latents_{name}"] = latents
    decoded = vae.decode(tensors["latents_fixed"] / vae.config.scaling_factor).sample
    tensors["decoded_fixed"] = (decoded * 0.5 + 0.5).clamp(0, 1)
    save(tensors, os.path.join(OUT, "io.safetensors"))
    moved = (tensors["latents_fixed"] - tensors["latents_upstream"]).abs().max().item()
    print(f"timesteps {timesteps.tolist()}; the upstream batch order moves the latents by {moved:.3f}")
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(OUT) for f in fs)
    print(f"fixtures written to {os.path.normpath(OUT)}: {total / 1e6:.3f} MB")


if __name__ == "__main__":
    main()
