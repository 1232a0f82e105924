"""One training step of the multi-view cross-domain UNet on torch CPU, for `cargo xtask bench train`.

The same step as crates/w3d-diffusion/benches/train.rs: the whole UNet trained on one object's
12 images (6 views x normal and colour), one timestep per domain group (250, 600), ε-MSE with
Min-SNR-γ (5) weights, backward, clip_grad_norm_(1.0), one AdamW step (class embedding at 10x
the learning rate). Configs: the tiny test checkpoint's (8x8 latents) and the small model's
two widths (configs/small/unet and unet-half, 16x16 latents, with cross-domain attention),
random weights, the multi-view
blocks of fixtures_diffusion.py on diffusers' modules. f32, all CPU threads. Prints one JSON
object per configuration: median and all times in ms.
"""

import inspect
import json
import os
import sys

import torch
import torch.nn.functional as F
from diffusers import DDPMScheduler, UNet2DConditionModel

sys.path.insert(0, os.path.dirname(__file__))
from fixtures_diffusion import MV_UNET, NUM_VIEWS, make_multiview  # noqa: E402
from peer_timing import report  # noqa: E402

root = sys.argv[1]
runs = int(sys.argv[2]) if len(sys.argv) > 2 else 10
torch.set_num_threads(os.cpu_count())
torch.set_grad_enabled(True)
torch.manual_seed(0)

MV_TO_2D = {
    "CrossAttnDownBlockMV2D": "CrossAttnDownBlock2D",
    "CrossAttnUpBlockMV2D": "CrossAttnUpBlock2D",
    "UNetMidBlockMV2DCrossAttn": "UNetMidBlock2DCrossAttn",
}


def small_config(folder):
    with open(os.path.join(root, "crates/w3d-diffusion/configs/small", folder, "config.json")) as f:
        config = json.load(f)
    known = inspect.signature(UNet2DConditionModel.__init__).parameters
    out = {k: v for k, v in config.items() if not k.startswith("_") and k in known}
    out["down_block_types"] = [MV_TO_2D.get(t, t) for t in config["down_block_types"]]
    out["up_block_types"] = [MV_TO_2D.get(t, t) for t in config["up_block_types"]]
    out["mid_block_type"] = MV_TO_2D.get(config["mid_block_type"], config["mid_block_type"])
    return out


def labels():
    rows = []
    for domain in range(2):
        for view in range(NUM_VIEWS):
            v = torch.tensor([1.0 if i == 5 + domain else 0.1 * view for i in range(7)])
            rows.append(torch.cat([torch.sin(v), torch.cos(v)]))
    return torch.stack(rows)


def bench(name, config, side, scheduler_path):
    unet = UNet2DConditionModel(**config)
    make_multiview(unet)
    unet.train()
    with open(scheduler_path) as f:
        sched = {k: v for k, v in json.load(f).items() if not k.startswith("_")}
    scheduler = DDPMScheduler(**{k: v for k, v in sched.items() if k in
                                 ("num_train_timesteps", "beta_start", "beta_end", "beta_schedule", "prediction_type")})
    n = 2 * NUM_VIEWS
    dim = config["cross_attention_dim"]
    latents = torch.randn(n, 4, side, side)
    cond = torch.randn(1, 4, side, side).repeat(n, 1, 1, 1)
    context = torch.randn(1, 1, dim).repeat(n, 1, 1)
    class_labels = labels()
    timesteps = torch.tensor([250, 600]).repeat_interleave(NUM_VIEWS)
    noise = torch.randn(n, 4, side, side)
    class_params = [p for k, p in unet.named_parameters() if k.startswith("class_embedding.")]
    other = [p for k, p in unet.named_parameters() if not k.startswith("class_embedding.")]
    optimizer = torch.optim.AdamW([{"params": other, "lr": 1e-4}, {"params": class_params, "lr": 1e-3}],
                                  betas=(0.9, 0.999), weight_decay=1e-2, eps=1e-8)
    acp = scheduler.alphas_cumprod

    def step():
        optimizer.zero_grad(set_to_none=True)
        noisy = scheduler.add_noise(latents, noise, timesteps)
        pred = unet(torch.cat([noisy, cond], dim=1), timesteps, encoder_hidden_states=context,
                    class_labels=class_labels).sample
        snr = acp[timesteps] / (1.0 - acp[timesteps])
        weights = torch.clamp(snr, max=5.0) / snr
        loss = (F.mse_loss(pred, noise, reduction="none").mean(dim=(1, 2, 3)) * weights).mean()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(unet.parameters(), 1.0)
        optimizer.step()
        return loss.item()

    report(f"train_step/{name}/torch", step, runs, warmup=2,
           parameters=sum(p.numel() for p in unet.parameters()))


tiny = os.path.join(root, "crates/w3d-diffusion/tests/fixtures/wonder3d_tiny")
bench("tiny", dict(MV_UNET), 8, os.path.join(tiny, "scheduler/scheduler_config.json"))
small_scheduler = os.path.join(root, "crates/w3d-diffusion/configs/small/scheduler/scheduler_config.json")
bench("small", small_config("unet"), 16, small_scheduler)
bench("small-half", small_config("unet-half"), 16, small_scheduler)
