"""Parity fixtures for crates/w3d-diffusion (run by `cargo xtask fixtures diffusion`).

Builds tiny random-weight configs of the diffusers UNet2DConditionModel and AutoencoderKL and
the transformers CLIPVisionModelWithProjection, runs them (f32, CPU) on fixed inputs, runs DDIM
sampling (with classifier-free guidance) and DDIM inversion, and saves configs, weights, inputs
and outputs under crates/w3d-diffusion/tests/fixtures. Needs torch, diffusers, transformers,
safetensors, pillow.
"""

import json
import os
import sys

import numpy as np
import torch
from diffusers import AutoencoderKL, DDIMInverseScheduler, DDIMScheduler, UNet2DConditionModel
from PIL import Image
from safetensors.torch import save_file
from transformers import CLIPImageProcessor, CLIPVisionConfig, CLIPVisionModelWithProjection

OUT = os.path.join(os.path.dirname(__file__), "..", "..", "crates", "w3d-diffusion", "tests", "fixtures")
torch.manual_seed(0)
torch.set_grad_enabled(False)


def perturb_norms(model):
    """Random affine parameters on every norm, so the tests see non-trivial scales/shifts."""
    for name, p in model.named_parameters():
        if "norm" in name or "layrnorm" in name:
            if name.endswith("weight"):
                p.copy_(1.0 + 0.2 * torch.randn_like(p))
            else:
                p.copy_(0.2 * torch.randn_like(p))


def state(model, dtype=torch.float32):
    return {k: v.detach().to(dtype).contiguous() for k, v in model.state_dict().items()}


def save(tensors, path):
    save_file({k: v.detach().contiguous() for k, v in tensors.items()}, path)


def write_config(path, config):
    with open(path, "w") as f:
        json.dump(config, f, indent=1, sort_keys=True)


def unet_fixture():
    d = os.path.join(OUT, "unet")
    os.makedirs(d, exist_ok=True)
    config = dict(
        sample_size=16,
        in_channels=8,
        out_channels=4,
        down_block_types=["CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "DownBlock2D"],
        up_block_types=["UpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D"],
        block_out_channels=[16, 24, 32],
        layers_per_block=2,
        norm_num_groups=8,
        cross_attention_dim=12,
        attention_head_dim=2,
        class_embed_type="projection",
        projection_class_embeddings_input_dim=14,
    )
    unet = UNet2DConditionModel(**config).eval()
    perturb_norms(unet)
    save_file(state(unet), os.path.join(d, "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(d, "config.json"), dict(unet.config))
    sample = torch.randn(2, 8, 16, 16)
    timesteps = torch.tensor([10.0, 701.0])
    context = torch.randn(2, 1, 12)
    labels = torch.randn(2, 14)
    out = unet(sample, timesteps, encoder_hidden_states=context, class_labels=labels).sample
    save(
        {"sample": sample, "timesteps": timesteps, "context": context, "class_labels": labels, "out": out},
        os.path.join(d, "io.safetensors"),
    )
    return unet


def vae_fixture():
    d = os.path.join(OUT, "vae")
    os.makedirs(d, exist_ok=True)
    config = dict(
        in_channels=3,
        out_channels=3,
        down_block_types=["DownEncoderBlock2D"] * 3,
        up_block_types=["UpDecoderBlock2D"] * 3,
        block_out_channels=[8, 16, 16],
        layers_per_block=1,
        latent_channels=4,
        norm_num_groups=4,
        sample_size=32,
    )
    vae = AutoencoderKL(**config).eval()
    perturb_norms(vae)
    # Weights are stored in f16 (tests the f16 -> f32 path); the reference runs on the same
    # f16-rounded values in f32.
    for p in vae.parameters():
        p.copy_(p.half().float())
    save_file(state(vae, torch.float16), os.path.join(d, "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(d, "config.json"), dict(vae.config))
    image = torch.rand(2, 3, 32, 24) * 2 - 1
    mean = vae.encode(image).latent_dist.mode()
    latents = torch.randn(1, 4, 8, 8)
    decoded = vae.decode(latents).sample
    save(
        {"image": image, "mean": mean, "latents": latents, "decoded": decoded}, os.path.join(d, "io.safetensors")
    )


def clip_fixture():
    d = os.path.join(OUT, "clip")
    os.makedirs(d, exist_ok=True)
    config = CLIPVisionConfig(
        hidden_size=32,
        intermediate_size=48,
        projection_dim=12,
        num_hidden_layers=2,
        num_attention_heads=4,
        image_size=30,
        patch_size=6,
        hidden_act="quick_gelu",
    )
    model = CLIPVisionModelWithProjection(config).eval()
    perturb_norms(model)
    save_file(state(model), os.path.join(d, "model.safetensors"))
    config.save_pretrained(d)
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, size=(40, 52, 3), dtype=np.uint8)
    processor = CLIPImageProcessor(size={"shortest_edge": 30}, crop_size={"height": 30, "width": 30})
    pixels = processor(images=Image.fromarray(rgb), return_tensors="pt").pixel_values
    noise_pixels = torch.randn(1, 3, 30, 30)
    batch = torch.cat([pixels, noise_pixels])
    embeds = model(pixel_values=batch).image_embeds
    save(
        {"rgb": torch.from_numpy(rgb.astype(np.float32)), "pixels": batch, "embeds": embeds},
        os.path.join(d, "io.safetensors"),
    )


SD = dict(
    num_train_timesteps=1000,
    beta_start=0.00085,
    beta_end=0.012,
    beta_schedule="scaled_linear",
    clip_sample=False,
    set_alpha_to_one=False,
    steps_offset=1,
    prediction_type="epsilon",
    timestep_spacing="leading",
)


def scheduler_fixture(unet):
    out = {}
    # Timesteps of several spacings.
    for name, extra, steps in [
        ("leading50", {}, 50),
        ("leading10", {}, 10),
        ("trailing7", {"timestep_spacing": "trailing", "steps_offset": 0}, 7),
        ("linspace13", {"timestep_spacing": "linspace", "steps_offset": 0}, 13),
    ]:
        s = DDIMScheduler(**{**SD, **extra})
        s.set_timesteps(steps)
        out[f"timesteps_{name}"] = s.timesteps.float()
        if name != "linspace13":
            inv = DDIMInverseScheduler(**{**SD, **extra})
            inv.set_timesteps(steps)
            out[f"inverse_timesteps_{name}"] = inv.timesteps.float()
    out["alphas_cumprod_scaled_linear"] = DDIMScheduler(**SD).alphas_cumprod.float()
    out["alphas_cumprod_cosine"] = DDIMScheduler(beta_schedule="squaredcos_cap_v2").alphas_cumprod.float()

    # 10-step DDIM with classifier-free guidance (scale 2): batch [uncond, cond]; the
    # unconditional branch has a zero context and a zero condition latent (Wonder3D's CFG).
    cond_latent = torch.randn(1, 4, 16, 16)
    context = torch.randn(1, 1, 12)
    labels = torch.randn(1, 14)
    s = DDIMScheduler(**SD)
    s.set_timesteps(10)
    latent = torch.randn(1, 4, 16, 16)
    out["cfg_start"] = latent.clone()
    traj = []
    for t in s.timesteps:
        model_in = torch.cat([torch.cat([latent, torch.zeros_like(cond_latent)], 1), torch.cat([latent, cond_latent], 1)])
        ctx = torch.cat([torch.zeros_like(context), context])
        eps = unet(model_in, t, encoder_hidden_states=ctx, class_labels=labels.repeat(2, 1)).sample
        uncond, cond = eps.chunk(2)
        eps = uncond + 2.0 * (cond - uncond)
        latent = s.step(eps, t, latent, eta=0.0).prev_sample
        traj.append(latent)
    out["cfg_trajectory"] = torch.stack(traj)
    out["cond_latent"] = cond_latent
    out["context"] = context
    out["class_labels"] = labels

    # 10-step DDIM inversion (conditional, no guidance).
    inv = DDIMInverseScheduler(**SD)
    inv.set_timesteps(10)
    latent = torch.randn(1, 4, 16, 16)
    out["inversion_start"] = latent.clone()
    traj = []
    for t in inv.timesteps:
        eps = unet(torch.cat([latent, cond_latent], 1), t, encoder_hidden_states=context, class_labels=labels).sample
        latent = inv.step(eps, t, latent).prev_sample
        traj.append(latent)
    out["inversion_trajectory"] = torch.stack(traj)

    # Single steps: stochastic (eta) with given noise, v-prediction, clipping, sample prediction.
    sample = torch.randn(2, 4, 4)
    model_output = torch.randn(2, 4, 4)
    noise = torch.randn(2, 4, 4)
    out["step_sample"], out["step_model_output"], out["step_noise"] = sample, model_output, noise
    for name, extra, eta in [
        ("eps_eta1", {}, 1.0),
        ("v_eta05", {"prediction_type": "v_prediction"}, 0.5),
        ("sample_clip", {"prediction_type": "sample", "clip_sample": True, "set_alpha_to_one": True}, 0.0),
        ("linear_eps", {"beta_schedule": "linear", "beta_start": 0.0001, "beta_end": 0.02}, 0.0),
    ]:
        s = DDIMScheduler(**{**SD, **extra})
        s.set_timesteps(20)
        for t in [int(s.timesteps[0]), int(s.timesteps[-1])]:
            out[f"step_{name}_t{t}"] = s.step(model_output, t, sample, eta=eta, variance_noise=noise).prev_sample
    save(out, os.path.join(OUT, "scheduler.safetensors"))


def main():
    os.makedirs(OUT, exist_ok=True)
    unet = unet_fixture()
    vae_fixture()
    clip_fixture()
    scheduler_fixture(unet)
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(OUT) for f in fs)
    print(f"fixtures written to {os.path.normpath(OUT)}: {total / 1e6:.2f} MB")
    if total > 5e6:
        sys.exit("fixtures exceed 5 MB")


if __name__ == "__main__":
    main()
