"""Shared fixtures: the repository, the CLI binary the numbers are compared with, the data."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]
SPOT = REPO / "assets" / "spot.obj"
TINY = REPO / "crates" / "w3d-diffusion" / "tests" / "fixtures" / "wonder3d_tiny"
SMALL = REPO / "assets" / "model-small"


def _cli() -> pathlib.Path:
    """The `wonder3d` binary: $W3D_CLI, else the test build's."""
    path = pathlib.Path(os.environ.get("W3D_CLI", REPO / "target" / "release" / "wonder3d"))
    if not path.is_file():
        pytest.fail(
            f"{path} not found: these tests compare with the CLI; build it with "
            "`cargo build --release -p wonder3d-cli` or point W3D_CLI at it"
        )
    return path


@pytest.fixture(scope="session")
def cli():
    """Runs the CLI with arguments, returning its stdout; fails the test on a non-zero exit."""
    binary = _cli()

    def run(*args, env=None):
        done = subprocess.run(
            [str(binary), *map(str, args)],
            capture_output=True,
            text=True,
            env={**os.environ, **(env or {})},
        )
        assert done.returncode == 0, f"wonder3d {' '.join(map(str, args))} failed:\n{done.stderr}"
        return done.stdout

    return run


@pytest.fixture(scope="session")
def spot_views_dir(tmp_path_factory, cli):
    """`wonder3d render assets/spot.obj --size 128`: the CLI's view set of spot."""
    out = tmp_path_factory.mktemp("cli") / "spot_views"
    cli("render", SPOT, "--size", 128, "--out", out)
    return out
