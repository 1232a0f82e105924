"""Generation from Python equals the CLI's, with the tiny checkpoint and the small model."""

import numpy as np
import pytest

import wonder3d
from conftest import SMALL, TINY
from test_pipeline import files_of


@pytest.fixture(scope="module")
def input_image(spot_views_dir):
    return spot_views_dir / "colour_front.png"


@pytest.mark.parametrize("weights, steps", [(TINY, 2), (SMALL, 4)], ids=["tiny", "small"])
def test_generation_equals_the_cli(tmp_path, cli, input_image, weights, steps):
    cli("generate", input_image, "--weights", weights, "--steps", steps, "--seed", 7, "--out", tmp_path / "cli", "--quiet")
    generator = wonder3d.Generator(weights)
    events = []
    generated = generator.generate(input_image, steps=steps, seed=7, progress=events.append)
    generated.save(tmp_path / "py")
    assert files_of(tmp_path / "py") == files_of(tmp_path / "cli")
    assert [e.stage for e in events][:2] == ["condition", "condition"]
    assert [e.done for e in events if e.stage == "denoise"][-1] == steps
    assert events[-1].stage == "decode"
    # The same image as an array and as a PIL image gives the same views.
    from PIL import Image

    pil = Image.open(input_image)
    from_pil = generator.generate(pil, steps=steps, seed=7).views
    from_array = generator.generate(np.asarray(pil), steps=steps, seed=7).views
    assert np.array_equal(from_pil.normals, generated.views.normals)
    assert np.array_equal(from_array.colours, generated.views.colours)


def test_generator_errors(tmp_path):
    with pytest.raises(wonder3d.Error):
        wonder3d.Generator(tmp_path / "no_such_folder")
    with pytest.raises(wonder3d.InvalidInputError, match="device"):
        wonder3d.Generator(TINY, device="tpu")
    generator = wonder3d.Generator(TINY)
    assert generator.options["steps"] == 50 and generator.options["products"] in ("f32", "bf16")
    with pytest.raises(wonder3d.InvalidInputError, match="image"):
        generator.generate(np.zeros((4, 4), np.float32))
    with pytest.raises(wonder3d.FileError):
        generator.generate(tmp_path / "missing.png")


def test_pipeline_run_with_the_small_model(input_image):
    generator = wonder3d.Generator(SMALL)
    output = wonder3d.Pipeline(generator, preset="fast", texture_size=512).run(input_image)
    assert output.geometry.is_watertight and output.mesh.texture is not None
    assert output.report["generation"]["steps"] == 50
    assert output.input.shape[2] in (3, 4)


def test_a_hub_id_goes_through_the_hub_resolver(tmp_path, monkeypatch):
    """Offline with an empty cache: the error names the repository, so the id reached the
    Hub resolver (the downloads themselves are tested over loopback HTTP in Rust:
    crates/wonder3d/tests/facade/hub.rs)."""
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    events = []
    with pytest.raises(wonder3d.Error, match="someone/some-model"):
        wonder3d.Generator("someone/some-model", progress=events.append)
    assert not (tmp_path / "hf" / "hub" / "models--someone--some-model" / "snapshots").exists()
    with pytest.raises(wonder3d.InvalidInputError):
        wonder3d.Generator("someone/../escape")
