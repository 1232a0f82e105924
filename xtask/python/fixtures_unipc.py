"""UniPC parity fixture for crates/w3d-diffusion (run by `cargo xtask fixtures diffusion` after
`fixtures_diffusion.py`, or alone: `$W3D_PYTHON xtask/python/fixtures_unipc.py` from the
repository root; it rewrites only `unipc.safetensors`).

Writes `crates/w3d-diffusion/tests/fixtures/unipc.safetensors`: diffusers'
`UniPCMultistepScheduler.from_config(cfg)` where `cfg` is the Stable Diffusion 1.5 scheduler
config as Wonder3D++'s enhancer loads it (a PNDM config without a `timestep_spacing` key, so
UniPC's own defaults apply: linspace spacing, order 2, bh2, x0 prediction, lower order on the
last step, final σ = 0), plus a `leading` and a `trailing` variant:

- `timesteps_<variant><steps>` / `sigmas_<variant><steps>` for 50 and 13 steps;
- trajectories of a closed-form stand-in model `out = tanh(x / 2) * a + b * t / 1000`
  (`model_a`, `model_b`), every intermediate sample saved (`trajectory_<name>`, `[steps, ...]`)
  so a failing test names the first diverging step: 50 steps from noise (authors' config),
  13 steps with leading and trailing spacing, 20 steps of v- and of sample-prediction;
- img2img / SDEdit as diffusers' img2img pipeline runs it (strength 0.2 and 0.1 at 50 steps):
  `get_timesteps` → `set_begin_index`, `add_noise` of a given x0 (`img2img_x0`) and ε
  (`img2img_noise`) at the first timestep run (`img2img_start_s<strength>`), the timesteps run
  (`img2img_timesteps_s<strength>`) and the trajectory (`img2img_trajectory_s<strength>`).

Last written with torch 2.4.1, diffusers 0.30.3 (transformers 4.44.2 for the shared helpers).
"""

import os
import sys

import torch
from diffusers import UniPCMultistepScheduler

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fixtures_diffusion import OUT, save  # noqa: E402

# runwayml/stable-diffusion-v1-5 `scheduler/scheduler_config.json` (PNDM), as the authors load it.
SD15 = {
    "_class_name": "PNDMScheduler",
    "_diffusers_version": "0.6.0",
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "beta_start": 0.00085,
    "num_train_timesteps": 1000,
    "set_alpha_to_one": False,
    "skip_prk_steps": True,
    "steps_offset": 1,
    "trained_betas": None,
    "clip_sample": False,
}

VARIANTS = {
    "linspace": {},
    "leading": {"timestep_spacing": "leading"},
    "trailing": {"timestep_spacing": "trailing"},
}


def unipc(**extra):
    s = UniPCMultistepScheduler.from_config({**SD15, **extra})
    assert s.config.solver_order == 2 and s.config.solver_type == "bh2" and s.config.predict_x0
    assert s.config.lower_order_final and s.config.final_sigmas_type == "zero"
    assert not s.config.use_karras_sigmas
    return s


def model(x, t, a, b):
    return torch.tanh(x / 2) * a + b * (float(t) / 1000.0)


def img2img_begin(steps, strength):
    """The img2img pipeline's `get_timesteps` (scheduler order 1)."""
    init = min(int(steps * strength), steps)
    return max(steps - init, 0)


def main():
    gen = torch.Generator().manual_seed(11)
    out = {}
    assert unipc().config.timestep_spacing == "linspace", "the SD1.5 config must leave UniPC's linspace default"
    for variant, extra in VARIANTS.items():
        for steps in (50, 13):
            s = unipc(**extra)
            s.set_timesteps(steps)
            out[f"timesteps_{variant}{steps}"] = s.timesteps.float()
            out[f"sigmas_{variant}{steps}"] = s.sigmas.float()

    shape = (2, 4, 8, 8)
    a = torch.randn(shape, generator=gen)
    b = torch.randn(shape, generator=gen)
    out["model_a"], out["model_b"] = a, b

    for name, extra, steps in [
        ("eps_linspace50", {}, 50),
        ("eps_leading13", {"timestep_spacing": "leading"}, 13),
        ("eps_trailing13", {"timestep_spacing": "trailing"}, 13),
        ("v_linspace20", {"prediction_type": "v_prediction"}, 20),
        ("sample_linspace20", {"prediction_type": "sample"}, 20),
    ]:
        s = unipc(**extra)
        s.set_timesteps(steps)
        x = torch.randn(shape, generator=gen)
        out[f"start_{name}"] = x.clone()
        traj = []
        for t in s.timesteps:
            x = s.step(model(x, t, a, b), t, x).prev_sample
            traj.append(x)
        assert torch.isfinite(x).all()
        out[f"trajectory_{name}"] = torch.stack(traj)

    x0 = torch.randn(shape, generator=gen)
    noise = torch.randn(shape, generator=gen)
    out["img2img_x0"], out["img2img_noise"] = x0, noise
    for strength, tag in [(0.2, "s02"), (0.1, "s01")]:
        s = unipc()
        s.set_timesteps(50)
        begin = img2img_begin(50, strength)
        timesteps = s.timesteps[begin * s.order:]
        s.set_begin_index(begin * s.order)
        x = s.add_noise(x0, noise, timesteps[:1].repeat(shape[0]))
        out[f"img2img_start_{tag}"] = x.clone()
        out[f"img2img_timesteps_{tag}"] = timesteps.float()
        traj = []
        for t in timesteps:
            x = s.step(model(x, t, a, b), t, x).prev_sample
            traj.append(x)
        out[f"img2img_trajectory_{tag}"] = torch.stack(traj)
        print(f"img2img strength {strength}: timesteps {timesteps.tolist()}")

    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, "unipc.safetensors")
    save(out, path)
    print(f"wrote {os.path.normpath(path)}: {os.path.getsize(path) / 1e3:.0f} kB")


if __name__ == "__main__":
    main()
