"""Parity fixtures for crates/w3d-diffusion (run by `cargo xtask fixtures diffusion`).

Builds tiny random-weight configs of the diffusers UNet2DConditionModel and AutoencoderKL and
the transformers CLIPVisionModelWithProjection, runs them (f32, CPU) on fixed inputs, runs DDIM
sampling (with classifier-free guidance) and DDIM inversion, builds a tiny Wonder3D++ multi-view
cross-domain UNet (on diffusers' blocks, with the real checkpoint key names) and runs one forward
per camera type and a 5-step guided multi-view pipeline, plus a tiny UNet with the second
cross-domain attention after the feed-forward (`cd_attention_last`) and one forward of it,
and saves configs, weights, inputs and outputs under crates/w3d-diffusion/tests/fixtures.
Needs torch, diffusers, transformers, safetensors, pillow.

`python fixtures_diffusion.py dpm_solver` writes only `dpm_solver.safetensors` (DPM-Solver++(2M)
timesteps, σ and 10-step trajectories of a closed-form stand-in model, as
`DPMSolverMultistepScheduler.from_config(DDIMScheduler(...).config)`).
`python fixtures_diffusion.py cd_attention_last` writes only the `cd_attention_last` fixtures
(`wonder3d_tiny_last/`, `multiview/unet_last_io.safetensors`): the other fixtures' outputs
move in the last bits between torch / transformers versions, so they need not be rewritten to
add this one. `python fixtures_diffusion.py train_step` writes only `train_step.safetensors`
(one training step of the tiny multi-view UNet). Last written with torch 2.4.1, diffusers 0.30.3, transformers 4.45.2.
"""

import json
import os
import sys
import types

import numpy as np
import torch
import torch.nn.functional as F
from diffusers import (
    AutoencoderKL,
    DDIMInverseScheduler,
    DDIMScheduler,
    DPMSolverMultistepScheduler,
    UNet2DConditionModel,
)
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
    # diffusers records the defaulted fields as a set: sort them so reruns write the same bytes.
    if "_use_default_values" in config:
        config = {**config, "_use_default_values": sorted(config["_use_default_values"])}
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


# ---------------------------------------------------------------------------------------------
# Wonder3D multi-view cross-domain UNet (design reference `wonder3d.md` §1.2-§3), written here
# from that description on top of diffusers' UNet2DConditionModel / Attention building blocks.

NUM_VIEWS = 6

# (d_elev, d_azim) view labels of the six views, radians (wonder3d.md §2).
VIEW_LABELS = [
    (0.000000, 0.000000),
    (-0.236240, 0.812378),
    (-0.168619, 1.693490),
    (0.522037, 3.141593),
    (0.690655, 4.835082),
    (0.373314, 5.586011),
]


def heads_split(x, heads):
    n, t, c = x.shape
    return x.view(n, t, heads, c // heads).transpose(1, 2)


def heads_merge(x):
    n, h, t, d = x.shape
    return x.transpose(1, 2).reshape(n, t, h * d)


class MultiViewAttnProcessor:
    """Self-attention whose keys / values are the tokens of all views of the image's group.

    The batch is `(groups * views, tokens, channels)`; K and V of a group are laid out as one
    sequence of `views * tokens` and repeated for each of its views, so every view's queries
    attend jointly over all views of the same object and domain (itself included).
    """

    def __init__(self, views):
        self.views = views

    def __call__(self, attn, hidden_states, encoder_hidden_states=None, attention_mask=None, temb=None, **kwargs):
        n, t, c = hidden_states.shape
        v = self.views
        q = attn.to_q(hidden_states)
        k = attn.to_k(hidden_states).reshape(n // v, v * t, c).repeat_interleave(v, dim=0)
        val = attn.to_v(hidden_states).reshape(n // v, v * t, c).repeat_interleave(v, dim=0)
        o = F.scaled_dot_product_attention(heads_split(q, attn.heads), heads_split(k, attn.heads), heads_split(val, attn.heads))
        return attn.to_out[1](attn.to_out[0](heads_merge(o)))


class CrossDomainAttnProcessor:
    """Cross-domain attention: the batch is [normal half, colour half]; entry i of either half
    attends to the concatenated tokens of entry i of both halves (same view, both domains)."""

    def __call__(self, attn, hidden_states, encoder_hidden_states=None, attention_mask=None, temb=None, **kwargs):
        n, t, c = hidden_states.shape
        half = n // 2
        q = attn.to_q(hidden_states)
        k = attn.to_k(hidden_states)
        val = attn.to_v(hidden_states)
        k = torch.cat([k[:half], k[half:]], dim=1).repeat(2, 1, 1)
        val = torch.cat([val[:half], val[half:]], dim=1).repeat(2, 1, 1)
        o = F.scaled_dot_product_attention(heads_split(q, attn.heads), heads_split(k, attn.heads), heads_split(val, attn.heads))
        return attn.to_out[1](attn.to_out[0](heads_merge(o)))


def mv_block_forward(self, hidden_states, attention_mask=None, encoder_hidden_states=None, **kwargs):
    """Pre-norm residual order of the multi-view block: MV self-attention, cross-domain
    attention, cross-attention to the CLIP token, GEGLU feed-forward and, with
    `cd_attention_last`, a second cross-domain attention."""
    h = self.attn1(self.norm1(hidden_states)) + hidden_states
    h = self.attn_joint_mid(self.norm_joint_mid(h)) + h
    h = self.attn2(self.norm2(h), encoder_hidden_states=encoder_hidden_states) + h
    h = self.ff(self.norm3(h)) + h
    if getattr(self, "attn_joint_last", None) is not None:
        h = self.attn_joint_last(self.norm_joint_last(h)) + h
    return h


def make_multiview(unet, last=False):
    """Turns every transformer block of a diffusers UNet into the multi-view cross-domain block
    (attn1 keeps its weights, `attn_joint_mid` + `norm_joint_mid` are new; with `last`, also
    `attn_joint_last` + `norm_joint_last`, registered after the feed-forward)."""
    from diffusers.models.attention import BasicTransformerBlock
    from diffusers.models.attention_processor import Attention

    def joint(dim, heads):
        return Attention(
            query_dim=dim, heads=heads, dim_head=dim // heads, bias=False, processor=CrossDomainAttnProcessor()
        )

    for module in unet.modules():
        if isinstance(module, BasicTransformerBlock):
            dim = module.norm1.normalized_shape[0]
            heads = module.attn1.heads
            module.attn1.set_processor(MultiViewAttnProcessor(NUM_VIEWS))
            module.norm_joint_mid = torch.nn.LayerNorm(dim)
            module.attn_joint_mid = joint(dim, heads)
            if last:
                module.attn_joint_last = joint(dim, heads)
                module.norm_joint_last = torch.nn.LayerNorm(dim)
            module.forward = types.MethodType(mv_block_forward, module)


def switcher_labels(domain, camera, input_dim=14):
    """Class labels `(6, input_dim)`: concat(sin v, cos v) of v = [elev_cond, d_elev, d_azim,
    cam_type(2), task(2)] (the camera type only in the 14-d Wonder3D++ form)."""
    task = [1.0, 0.0] if domain == "normal" else [0.0, 1.0]
    cam = [0.0, 1.0] if camera == "ortho" else [1.0, 0.0]
    rows = []
    for de, da in VIEW_LABELS:
        v = [0.0, de, da] + (cam if input_dim == 14 else []) + task
        v = torch.tensor(v, dtype=torch.float32)
        rows.append(torch.cat([torch.sin(v), torch.cos(v)]))
    return torch.stack(rows)


def to_f16_values(model):
    """Rounds every parameter to f16 (the checkpoint is stored in f16; the reference runs the
    rounded values in f32)."""
    for p in model.parameters():
        p.copy_(p.half().float())


MV_UNET = dict(
    sample_size=8,
    in_channels=8,
    out_channels=4,
    down_block_types=["CrossAttnDownBlock2D", "DownBlock2D"],
    up_block_types=["UpBlock2D", "CrossAttnUpBlock2D"],
    block_out_channels=[32, 32],
    layers_per_block=1,
    norm_num_groups=8,
    cross_attention_dim=16,
    attention_head_dim=2,
    class_embed_type="projection",
    projection_class_embeddings_input_dim=14,
)


def wonder3d_unet_config(unet, last=False):
    """The tiny UNet's config.json in the form of a Wonder3D checkpoint (UNetMV2DConditionModel)."""
    config = dict(unet.config)
    config["_class_name"] = "UNetMV2DConditionModel"
    config["down_block_types"] = [t.replace("CrossAttnDownBlock2D", "CrossAttnDownBlockMV2D") for t in config["down_block_types"]]
    config["up_block_types"] = [t.replace("CrossAttnUpBlock2D", "CrossAttnUpBlockMV2D") for t in config["up_block_types"]]
    config["mid_block_type"] = "UNetMidBlockMV2DCrossAttn"
    config.update(num_views=NUM_VIEWS, cd_attention_mid=True, cd_attention_last=last, multiview_attention=True,
                  sparse_mv_attention=False, mvcd_attention=False)
    return config


def tiny_pipeline(unet, vae, clip, processor, image_u8, noise, steps, guidance, camera):
    """The multi-view cross-domain sampling loop (wonder3d.md §3): CLIP image embedding and the
    VAE latent mode of the white-background input as conditions, one noise per view shared by
    both domains, CFG batch [normal_uncond, normal_cond, colour_uncond, colour_cond] with a zero
    embedding and a zero latent for the unconditional branch, deterministic DDIM."""
    pixels = processor(images=Image.fromarray(image_u8), return_tensors="pt").pixel_values
    embeds = clip(pixel_values=pixels).image_embeds
    image = torch.from_numpy(image_u8.astype(np.float32) / 255.0).permute(2, 0, 1)[None]
    cond_latent = vae.encode(image * 2 - 1).latent_dist.mode() * vae.config.scaling_factor
    v = NUM_VIEWS
    cond = cond_latent.expand(v, -1, -1, -1)
    ctx = embeds[:, None, :].expand(v, -1, -1)
    labels_n = switcher_labels("normal", camera)
    labels_c = switcher_labels("colour", camera)
    s = DDIMScheduler(**SD)
    s.set_timesteps(steps)
    latents = torch.cat([noise, noise])
    for t in s.timesteps:
        ln, lc = latents[:v], latents[v:]
        model_in = torch.cat([
            torch.cat([ln, torch.zeros_like(cond)], 1),
            torch.cat([ln, cond], 1),
            torch.cat([lc, torch.zeros_like(cond)], 1),
            torch.cat([lc, cond], 1),
        ])
        context = torch.cat([torch.zeros_like(ctx), ctx, torch.zeros_like(ctx), ctx])
        labels = torch.cat([labels_n, labels_n, labels_c, labels_c])
        out = unet(model_in, t, encoder_hidden_states=context, class_labels=labels).sample
        nu, nc, cu, cc = out.chunk(4)
        eps = torch.cat([nu + guidance * (nc - nu), cu + guidance * (cc - cu)])
        latents = s.step(eps, t, latents, eta=0.0).prev_sample
    decoded = (vae.decode(latents / vae.config.scaling_factor).sample / 2 + 0.5).clamp(0, 1)
    return embeds, cond_latent, latents, decoded


def multiview_fixtures():
    """`tests/fixtures/wonder3d_tiny/`: a tiny Wonder3D++ model directory (unet/ with the real
    key names in f16, vae/, image_encoder/, feature_extractor/, scheduler/, model_index.json)
    and `tests/fixtures/multiview/`: UNet forward outputs for both camera types and a 5-step
    guided pipeline run."""
    torch.manual_seed(1)
    model_dir = os.path.join(OUT, "wonder3d_tiny")
    io_dir = os.path.join(OUT, "multiview")
    for sub in ["unet", "vae", "image_encoder", "feature_extractor", "scheduler"]:
        os.makedirs(os.path.join(model_dir, sub), exist_ok=True)
    os.makedirs(io_dir, exist_ok=True)

    unet = UNet2DConditionModel(**MV_UNET).eval()
    make_multiview(unet)
    perturb_norms(unet)
    to_f16_values(unet)
    save_file(state(unet, torch.float16), os.path.join(model_dir, "unet", "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(model_dir, "unet", "config.json"), wonder3d_unet_config(unet))

    vae = AutoencoderKL(
        down_block_types=["DownEncoderBlock2D"] * 3,
        up_block_types=["UpDecoderBlock2D"] * 3,
        block_out_channels=[8, 16, 16],
        layers_per_block=1,
        latent_channels=4,
        norm_num_groups=4,
        sample_size=32,
    ).eval()
    perturb_norms(vae)
    to_f16_values(vae)
    save_file(state(vae, torch.float16), os.path.join(model_dir, "vae", "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(model_dir, "vae", "config.json"), dict(vae.config))

    clip_config = CLIPVisionConfig(
        hidden_size=32,
        intermediate_size=48,
        projection_dim=16,
        num_hidden_layers=2,
        num_attention_heads=4,
        image_size=32,
        patch_size=8,
        hidden_act="quick_gelu",
    )
    clip = CLIPVisionModelWithProjection(clip_config).eval()
    perturb_norms(clip)
    save_file(state(clip), os.path.join(model_dir, "image_encoder", "model.safetensors"))
    clip_config.save_pretrained(os.path.join(model_dir, "image_encoder"))
    processor = CLIPImageProcessor(size={"shortest_edge": 32}, crop_size={"height": 32, "width": 32})
    processor.save_pretrained(os.path.join(model_dir, "feature_extractor"))
    write_config(os.path.join(model_dir, "scheduler", "scheduler_config.json"), dict(_class_name="DDIMScheduler", **SD))
    write_config(
        os.path.join(model_dir, "model_index.json"),
        {
            "_class_name": "MVDiffusionImagePipeline",
            "feature_extractor": ["transformers", "CLIPImageProcessor"],
            "image_encoder": ["transformers", "CLIPVisionModelWithProjection"],
            "scheduler": ["diffusers", "DDIMScheduler"],
            "unet": ["mv_diffusion_30.models.unet_mv2d_condition", "UNetMV2DConditionModel"],
            "vae": ["diffusers", "AutoencoderKL"],
        },
    )

    # One forward of the 12-image batch [normal x 6 views, colour x 6 views] per camera type.
    n = 2 * NUM_VIEWS
    sample = torch.randn(n, 8, 8, 8)
    context = torch.randn(n, 1, 16)
    timesteps = torch.tensor([421.0])
    io = {"sample": sample, "context": context, "timesteps": timesteps}
    for camera in ["ortho", "persp"]:
        labels = torch.cat([switcher_labels("normal", camera), switcher_labels("colour", camera)])
        io[f"class_labels_{camera}"] = labels
        io[f"out_{camera}"] = unet(sample, timesteps, encoder_hidden_states=context, class_labels=labels).sample
    save(io, os.path.join(io_dir, "unet_io.safetensors"))

    # The 5-step guided pipeline on a 32x32 white-background input (8-bit values).
    rng = np.random.default_rng(2)
    image_u8 = np.full((32, 32, 3), 255, dtype=np.uint8)
    image_u8[6:26, 9:23] = rng.integers(0, 256, size=(20, 14, 3), dtype=np.uint8)
    noise = torch.randn(NUM_VIEWS, 4, 8, 8)
    embeds, cond_latent, latents, decoded = tiny_pipeline(unet, vae, clip, processor, image_u8, noise, 5, 2.0, "ortho")
    save(
        {
            "image": torch.from_numpy(image_u8.astype(np.float32) / 255.0),
            "noise": noise,
            "embeds": embeds,
            "cond_latent": cond_latent,
            "latents": latents,
            "decoded": decoded,
        },
        os.path.join(io_dir, "pipeline_io.safetensors"),
    )


def cd_attention_last_fixtures():
    """`tests/fixtures/wonder3d_tiny_last/unet/`: a tiny multi-view UNet with both cross-domain
    attentions (`cd_attention_mid` and `cd_attention_last`; the last one's output weight is
    random, not zero, so it mixes the domains), f16, and `tests/fixtures/multiview/
    unet_last_io.safetensors`: one forward of the 12-image batch."""
    torch.manual_seed(3)
    unet_dir = os.path.join(OUT, "wonder3d_tiny_last", "unet")
    os.makedirs(unet_dir, exist_ok=True)
    os.makedirs(os.path.join(OUT, "multiview"), exist_ok=True)
    unet = UNet2DConditionModel(**MV_UNET).eval()
    make_multiview(unet, last=True)
    perturb_norms(unet)
    to_f16_values(unet)
    save_file(state(unet, torch.float16), os.path.join(unet_dir, "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(unet_dir, "config.json"), wonder3d_unet_config(unet, last=True))
    n = 2 * NUM_VIEWS
    sample = torch.randn(n, 8, 8, 8)
    context = torch.randn(n, 1, 16)
    timesteps = torch.tensor([421.0])
    labels = torch.cat([switcher_labels("normal", "persp"), switcher_labels("colour", "persp")])
    out = unet(sample, timesteps, encoder_hidden_states=context, class_labels=labels).sample
    save(
        {"sample": sample, "context": context, "timesteps": timesteps, "class_labels": labels, "out": out},
        os.path.join(OUT, "multiview", "unet_last_io.safetensors"),
    )


def dpm_solver_fixture():
    """DPM-Solver++(2M) built from a DDIM config, as users swap schedulers in diffusers."""
    gen = torch.Generator().manual_seed(5)
    out = {}

    def dpm(**extra):
        return DPMSolverMultistepScheduler.from_config(DDIMScheduler(**{**SD, **extra}).config)

    for name, extra, steps in [
        ("leading20", {}, 20),
        ("leading50", {}, 50),
        ("leading1", {}, 1),
        ("trailing7", {"timestep_spacing": "trailing", "steps_offset": 0}, 7),
        ("linspace13", {"timestep_spacing": "linspace", "steps_offset": 0}, 13),
    ]:
        s = dpm(**extra)
        s.set_timesteps(steps)
        out[f"timesteps_{name}"] = s.timesteps.float()
        out[f"sigmas_{name}"] = s.sigmas.float()
    # A closed-form stand-in for the model: out = tanh(x / 2) * a + b * t / 1000.
    shape = (2, 4, 8, 8)
    a = torch.randn(shape, generator=gen)
    b = torch.randn(shape, generator=gen)
    out["model_a"], out["model_b"] = a, b
    for name, extra, steps in [
        ("eps_leading10", {}, 10),
        ("eps_linspace10", {"timestep_spacing": "linspace", "steps_offset": 0}, 10),
        ("v_leading10", {"prediction_type": "v_prediction"}, 10),
        ("eps_trailing20", {"timestep_spacing": "trailing", "steps_offset": 0}, 20),
    ]:
        s = dpm(**extra)
        s.set_timesteps(steps)
        x = torch.randn(shape, generator=gen)
        out[f"start_{name}"] = x.clone()
        traj = []
        for t in s.timesteps:
            model_output = torch.tanh(x / 2) * a + b * (float(t) / 1000.0)
            x = s.step(model_output, t, x).prev_sample
            traj.append(x)
        out[f"trajectory_{name}"] = torch.stack(traj)
    save(out, os.path.join(OUT, "dpm_solver.safetensors"))


TRAIN_STEP_PARAMS = [
    "conv_in.weight",
    "down_blocks.0.attentions.0.transformer_blocks.0.attn1.to_q.weight",
    "down_blocks.0.attentions.0.transformer_blocks.0.attn_joint_mid.to_k.weight",
    "class_embedding.linear_1.weight",
    "conv_out.weight",
]


def train_step_fixture():
    """`tests/fixtures/train_step.safetensors`: one Wonder3D++ training step of the tiny
    multi-view UNet (`wonder3d_tiny/unet`), written from the authors' objective
    (train_mvdiffusion_joint.py as described in docs/training.md): 2 objects × 2 domains × 6
    views, one timestep per group of 6, independent noise per image, condition dropout as a
    whole (object 0 keeps everything, object 1 loses CLIP and the image latent), ε-MSE with
    Min-SNR-γ (γ = 5) weights, backward, clip_grad_norm_(1.0), one AdamW step (lr 1e-3,
    class_embedding at 10×, β 0.9/0.999, wd 1e-2, ε 1e-8, no warm-up). Saves the inputs, the
    loss, the gradients of five named parameters and those parameters after the step."""
    from diffusers import DDPMScheduler
    from safetensors.torch import load_file

    torch.manual_seed(7)
    model_dir = os.path.join(OUT, "wonder3d_tiny")
    unet = UNet2DConditionModel(**MV_UNET)
    make_multiview(unet)
    weights = {k: v.float() for k, v in load_file(os.path.join(model_dir, "unet", "diffusion_pytorch_model.safetensors")).items()}
    unet.load_state_dict(weights, strict=True)
    unet.train()
    with open(os.path.join(model_dir, "scheduler", "scheduler_config.json")) as f:
        sched_config = {k: v for k, v in json.load(f).items() if not k.startswith("_")}
    noise_scheduler = DDPMScheduler(**{k: v for k, v in sched_config.items() if k in
                                       ("num_train_timesteps", "beta_start", "beta_end", "beta_schedule", "prediction_type")})

    objects, views = 2, NUM_VIEWS
    n = 2 * objects * views
    latents = torch.randn(n, 4, 8, 8) * 0.5
    cond = torch.randn(objects, 4, 8, 8)
    embeds = torch.randn(objects, 1, 16)
    # [normal: obj0 views, obj1 views, colour: obj0 views, obj1 views]
    cond_latents = cond.repeat_interleave(views, dim=0).repeat(2, 1, 1, 1)
    image_embeddings = embeds.repeat_interleave(views, dim=0).repeat(2, 1, 1)
    labels = torch.cat([switcher_labels("normal", "ortho")] * objects + [switcher_labels("colour", "ortho")] * objects)
    group_timesteps = torch.tensor([250, 600, 17, 999])
    timesteps = group_timesteps.repeat_interleave(views)
    noise = torch.randn(n, 4, 8, 8)
    random_p = torch.tensor([0.5, 0.07])  # object 0: keep; object 1: drop CLIP and the image latent
    p = 0.05
    image_mask = 1 - ((random_p >= p).float() * (random_p < 3 * p).float())
    image_mask = image_mask.reshape(objects, 1, 1, 1, 1).repeat(1, views, 1, 1, 1).reshape(objects * views, 1, 1, 1)
    image_mask = torch.cat([image_mask, image_mask], dim=0)
    clip_mask = 1 - (random_p < 2 * p).float()
    clip_mask = clip_mask.reshape(objects, 1, 1, 1).repeat(1, views, 1, 1).reshape(objects * views, 1, 1)
    clip_mask = torch.cat([clip_mask, clip_mask], dim=0)

    with torch.enable_grad():
        noisy = noise_scheduler.add_noise(latents, noise, timesteps)
        model_in = torch.cat([noisy, image_mask * cond_latents], dim=1)
        pred = unet(model_in, timesteps, encoder_hidden_states=clip_mask * image_embeddings, class_labels=labels).sample
        alphas_cumprod = noise_scheduler.alphas_cumprod
        alpha = alphas_cumprod[timesteps] ** 0.5
        sigma = (1.0 - alphas_cumprod[timesteps]) ** 0.5
        snr = (alpha / sigma) ** 2
        mse_weights = torch.stack([snr, 5.0 * torch.ones_like(timesteps, dtype=torch.float32)], dim=1).min(dim=1)[0] / snr
        loss = F.mse_loss(pred.float(), noise.float(), reduction="none")
        loss = loss.mean(dim=list(range(1, len(loss.shape)))) * mse_weights
        loss = loss.mean()
        loss.backward()
    named = dict(unet.named_parameters())
    grads = {f"grad.{k}": named[k].grad.detach().clone() for k in TRAIN_STEP_PARAMS}
    grad_norm = torch.nn.utils.clip_grad_norm_(unet.parameters(), 1.0)
    class_params = [p_ for k, p_ in unet.named_parameters() if k.startswith("class_embedding.")]
    other_params = [p_ for k, p_ in unet.named_parameters() if not k.startswith("class_embedding.")]
    lr = 1e-3
    optimizer = torch.optim.AdamW(
        [{"params": other_params, "lr": lr}, {"params": class_params, "lr": lr * 10}],
        betas=(0.9, 0.999), weight_decay=1e-2, eps=1e-8,
    )
    optimizer.step()
    out = {
        "latents": latents, "condition_latents": cond_latents, "image_embeddings": image_embeddings,
        "class_labels": labels, "noise": noise, "group_timesteps": group_timesteps.float(),
        "loss": loss.detach().reshape(1), "grad_norm": grad_norm.detach().reshape(1),
    }
    out.update(grads)
    out.update({f"after.{k}": named[k].detach().clone() for k in TRAIN_STEP_PARAMS})
    save(out, os.path.join(OUT, "train_step.safetensors"))
    print(f"train step: loss {loss.item():.6f}, grad norm {grad_norm.item():.6f}")


def main():
    os.makedirs(OUT, exist_ok=True)
    if sys.argv[1:] == ["dpm_solver"]:
        dpm_solver_fixture()
        return
    if sys.argv[1:] == ["cd_attention_last"]:
        cd_attention_last_fixtures()
        return
    if sys.argv[1:] == ["train_step"]:
        train_step_fixture()
        return
    unet = unet_fixture()
    vae_fixture()
    clip_fixture()
    scheduler_fixture(unet)
    dpm_solver_fixture()
    multiview_fixtures()
    cd_attention_last_fixtures()
    train_step_fixture()
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(OUT) for f in fs)
    print(f"fixtures written to {os.path.normpath(OUT)}: {total / 1e6:.2f} MB")
    if total > 5e6:
        sys.exit("fixtures exceed 5 MB")


if __name__ == "__main__":
    main()
