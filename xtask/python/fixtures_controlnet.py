"""ControlNet parity fixtures for crates/w3d-diffusion (run by `cargo xtask fixtures diffusion`,
or directly: `python xtask/python/fixtures_controlnet.py` from the repository root).

Builds a tiny SD-layout diffusers `UNet2DConditionModel` (4 → 4 channels, levels (8, 16):
`CrossAttnDownBlock2D` + `DownBlock2D`, 2 layers per block, the cross-attention mid block, no
class embedding) and `ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(4, 8, 8, 16))`, so the
control image is 8× the latent size as in Stable Diffusion 1.5. Then it gives every ControlNet
transformer block the cross-domain ("joint") attention of Wonder3D++'s MVControlNet, written
from a description of the authors' block (their `MVControlNet/model/transformer_2d_cd.py`,
summarised in `docs/weights.md`, "ControlNet (enhancer)"), not from their code: after the
self-attention, `h += attn_joint_mid(norm_joint_mid(h))`, where `attn_joint_mid` is an
`Attention` with the block's head count and head width, no q/k/v bias, and `norm_joint_mid` a
LayerNorm; the batch is `[domain A half, domain B half]` and row i of either half attends over
the concatenated tokens of row i of both halves (`CrossDomainAttnProcessor` of
`fixtures_diffusion.py`, the same pairing as the multi-view UNet's). Keys:
`…transformer_blocks.0.attn_joint_mid.{to_q,to_k,to_v}.weight`, `…to_out.0.{weight,bias}`,
`…norm_joint_mid.{weight,bias}`.

Every zero-initialised tensor (the zero convolutions `controlnet_down_blocks.*`,
`controlnet_mid_block`, the condition embedding's `conv_out`) is randomised and every norm
perturbed, so that a wrong residual or a missing joint attention shows in the outputs.

Writes under crates/w3d-diffusion/tests/fixtures/controlnet/:
- `unet/` (config.json, diffusion_pytorch_model.safetensors): the frozen UNet, weights stored in f16;
- `mv/` (config.json, diffusion_pytorch_model.safetensors): the ControlNet with joint attention;
- `stock/`: a stock ControlNet (no joint attention) from the same UNet, weights stored in f16;
- `io.safetensors`: latents [4, 4, 8, 8], timesteps [4] (one per row), context [4, 5, 32],
  control [4, 3, 64, 64] in [0, 1], scale 0.7 → the joint ControlNet's residuals `down.{i}`,
  `mid`, the UNet output `unet_out` with them injected and `unet_plain` without; and the stock
  ControlNet's residuals `stock.down.{i}`, `stock.mid` on the first 3 rows (an odd batch).

Written with torch 2.4.1, diffusers 0.30.3 (and transformers 4.44.2, imported by the helpers of
`fixtures_diffusion.py`, not used here).
"""

import os
import sys
import types

import torch

sys.path.insert(0, os.path.dirname(__file__))
from fixtures_diffusion import CrossDomainAttnProcessor, perturb_norms, save, state, write_config  # noqa: E402

from diffusers import ControlNetModel, UNet2DConditionModel  # noqa: E402
from diffusers.models.attention import BasicTransformerBlock  # noqa: E402
from diffusers.models.attention_processor import Attention  # noqa: E402

OUT = os.path.join(os.path.dirname(__file__), "..", "..", "crates", "w3d-diffusion", "tests", "fixtures", "controlnet")
SCALE = 0.7


def joint_block_forward(self, hidden_states, attention_mask=None, encoder_hidden_states=None, **kwargs):
    """The MVControlNet block's pre-norm residual order (reference §B.2): self-attention,
    cross-domain attention, cross-attention to the text tokens, GEGLU feed-forward."""
    h = self.attn1(self.norm1(hidden_states)) + hidden_states
    h = self.attn_joint_mid(self.norm_joint_mid(h)) + h
    h = self.attn2(self.norm2(h), encoder_hidden_states=encoder_hidden_states) + h
    return self.ff(self.norm3(h)) + h


def add_joint_attention(controlnet):
    """Gives every transformer block of `controlnet` the cross-domain attention (random weights,
    including the output projection the authors zero-initialise)."""
    for module in controlnet.modules():
        if isinstance(module, BasicTransformerBlock):
            dim = module.norm1.normalized_shape[0]
            heads = module.attn1.heads
            module.attn_joint_mid = Attention(
                query_dim=dim, heads=heads, dim_head=dim // heads, bias=False, processor=CrossDomainAttnProcessor()
            )
            module.norm_joint_mid = torch.nn.LayerNorm(dim)
            module.forward = types.MethodType(joint_block_forward, module)


def randomise_zero_init(controlnet):
    """Random values for the tensors diffusers initialises to zero (else the residuals would be
    zero whatever the network computed)."""
    for name, p in controlnet.named_parameters():
        if name.startswith(("controlnet_down_blocks.", "controlnet_mid_block.", "controlnet_cond_embedding.conv_out.")):
            p.copy_(0.3 * torch.randn_like(p))


def save_model(model, name, dtype=torch.float32):
    d = os.path.join(OUT, name)
    os.makedirs(d, exist_ok=True)
    save(state(model, dtype), os.path.join(d, "diffusion_pytorch_model.safetensors"))
    write_config(os.path.join(d, "config.json"), dict(model.config))


def main():
    torch.manual_seed(22)
    os.makedirs(OUT, exist_ok=True)
    unet = UNet2DConditionModel(
        sample_size=8,
        in_channels=4,
        out_channels=4,
        down_block_types=["CrossAttnDownBlock2D", "DownBlock2D"],
        up_block_types=["UpBlock2D", "CrossAttnUpBlock2D"],
        block_out_channels=[8, 16],
        layers_per_block=2,
        norm_num_groups=4,
        cross_attention_dim=32,
        attention_head_dim=2,
    ).eval()
    perturb_norms(unet)
    # The UNet is stored in f16 (size); the reference runs on the same rounded values.
    for p in unet.parameters():
        p.copy_(p.half().float())

    mv = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(4, 8, 8, 16)).eval()
    add_joint_attention(mv)
    randomise_zero_init(mv)
    perturb_norms(mv)
    stock = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(4, 8, 8, 16)).eval()
    randomise_zero_init(stock)
    perturb_norms(stock)
    # Stored in f16 (the f16 -> f32 path): the reference runs on the same rounded values.
    for p in stock.parameters():
        p.copy_(p.half().float())

    latents = torch.randn(4, 4, 8, 8)
    timesteps = torch.tensor([981.0, 500.0, 21.0, 760.0])
    context = torch.randn(4, 5, 32)
    # f16-exact values, so the half-precision copy below stores them without rounding.
    control = torch.rand(4, 3, 64, 64).half().float()
    down, mid = mv(latents, timesteps, context, control, conditioning_scale=SCALE, return_dict=False)
    unet_out = unet(
        latents, timesteps, encoder_hidden_states=context, down_block_additional_residuals=down,
        mid_block_additional_residual=mid,
    ).sample
    unet_plain = unet(latents, timesteps, encoder_hidden_states=context).sample
    s_down, s_mid = stock(
        latents[:3], timesteps[:3], context[:3], control[:3], conditioning_scale=SCALE, return_dict=False
    )

    save_model(unet, "unet", torch.float16)
    save_model(mv, "mv")
    save_model(stock, "stock", torch.float16)
    io = {
        "latents": latents, "timesteps": timesteps, "context": context, "control": control.half(),
        "scale": torch.tensor([SCALE]), "mid": mid, "unet_out": unet_out, "unet_plain": unet_plain,
        "stock.mid": s_mid,
    }
    io.update({f"down.{i}": r for i, r in enumerate(down)})
    io.update({f"stock.down.{i}": r for i, r in enumerate(s_down)})
    save(io, os.path.join(OUT, "io.safetensors"))
    joint = [k for k in state(mv) if "joint_mid" in k]
    print(f"{len(down)} down residuals {[tuple(r.shape) for r in down]}, mid {tuple(mid.shape)}; {len(joint)} joint tensors")
    total = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(OUT) for f in fs)
    print(f"fixtures written to {os.path.normpath(OUT)}: {total / 1e6:.3f} MB")
    if total > 1e6:
        sys.exit("fixtures exceed 1 MB")


if __name__ == "__main__":
    main()
