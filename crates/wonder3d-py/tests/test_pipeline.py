"""render → reconstruct → texture → evaluate from Python equal the CLI's; progress, GIL, Ctrl-C."""

import json
import os
import signal
import threading
import time

import numpy as np
import pytest

import wonder3d
from conftest import SPOT


def files_of(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_render_equals_the_cli(tmp_path, spot_views_dir):
    views = wonder3d.render_views(wonder3d.Mesh.load(SPOT), size=128)
    views.save(tmp_path / "views")
    assert files_of(tmp_path / "views") == files_of(spot_views_dir)


def test_reconstruct_texture_evaluate_equal_the_cli(tmp_path, cli, spot_views_dir):
    cli("reconstruct", spot_views_dir, "--preset", "fast", "--out", tmp_path / "cli.ply", "--quiet")
    cli("texture", tmp_path / "cli.ply", spot_views_dir, "--size", 256, "--out", tmp_path / "cli.glb", "--quiet")
    cli_metrics = json.loads(cli("eval", tmp_path / "cli.ply", SPOT, "--json"))

    views = wonder3d.ViewSet.load(spot_views_dir)
    mesh = wonder3d.reconstruct(views, preset="fast")
    mesh.save(tmp_path / "py.ply")
    assert (tmp_path / "py.ply").read_bytes() == (tmp_path / "cli.ply").read_bytes()
    textured = wonder3d.texture(mesh, views, size=256)
    textured.save(tmp_path / "py.glb")
    assert (tmp_path / "py.glb").read_bytes() == (tmp_path / "cli.glb").read_bytes()
    metrics = wonder3d.evaluate(mesh, wonder3d.Mesh.load(SPOT))
    assert metrics == cli_metrics
    assert metrics["chamfer"] < 0.02 and metrics["fscore_0.02"] > 0.8


def test_pipeline_from_views(spot_views_dir):
    views = wonder3d.ViewSet.load(spot_views_dir)
    output = wonder3d.Pipeline(preset="fast", texture_size=512).from_views(views)
    assert output.mesh.texture.shape == (512, 512, 3) and output.geometry.is_watertight
    assert output.report["preset"] == "fast" and output.report["triangles"] == output.geometry.triangle_count
    assert output.input is None
    with pytest.raises(wonder3d.InvalidInputError, match="generator"):
        wonder3d.Pipeline().run(np.zeros((8, 8, 4), np.float32))


def test_progress_events_arrive_in_order(spot_views_dir):
    views = wonder3d.ViewSet.load(spot_views_dir)
    events = []
    wonder3d.reconstruct(views, preset="fast", progress=events.append)
    stages = [e.stage for e in events]
    order = ["init", "coarse", "untangle", "polish"]
    # Stages in order, each contiguous, never going back.
    seen = [s for i, s in enumerate(stages) if i == 0 or stages[i - 1] != s]
    assert [s for s in seen if s != "coarse" or seen.count("coarse") == 1] == [s for s in order if s in seen]
    assert seen[0] == "init" and seen[-1] == "polish"
    coarse = [e for e in events if e.stage == "coarse"]
    assert len(coarse) >= 10 and all(e.loss is not None for e in coarse)
    assert all(a.done <= b.done for a, b in zip(coarse, coarse[1:]))
    assert events[-1].done == events[-1].total == 1
    assert "ProgressEvent(stage=" in repr(events[0])


def test_tqdm_progress(spot_views_dir):
    pytest.importorskip("tqdm")
    views = wonder3d.ViewSet.load(spot_views_dir)
    with wonder3d.tqdm_progress(disable=True) as progress:
        wonder3d.reconstruct(views, preset="fast", progress=progress)
        assert progress._stage == "polish"


def test_an_exception_in_the_callback_stops_the_call(spot_views_dir):
    views = wonder3d.ViewSet.load(spot_views_dir)
    calls = []

    def fail_at_coarse(event):
        calls.append(event.stage)
        if event.stage == "coarse":
            raise ZeroDivisionError("stop here")

    with pytest.raises(ZeroDivisionError, match="stop here"):
        wonder3d.reconstruct(views, progress=fail_at_coarse)
    assert calls[-1] == "coarse" and calls.count("coarse") == 1


def test_long_calls_release_the_gil(spot_views_dir):
    views = wonder3d.ViewSet.load(spot_views_dir)
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.005)

    thread = threading.Thread(target=tick)
    thread.start()
    start = time.perf_counter()
    wonder3d.reconstruct(views, preset="fast")
    end = time.perf_counter()
    stop.set()
    thread.join()
    during = [t for t in ticks if start < t < end]
    # The other thread ran all along: at least a third of the ticks it would make alone.
    assert len(during) > (end - start) / 0.005 / 3, (len(during), end - start)


def test_ctrl_c_interrupts_a_reconstruction_within_a_second(spot_views_dir, tmp_path):
    views = wonder3d.ViewSet.load(spot_views_dir)
    sent = []

    def interrupt_later():
        time.sleep(0.3)
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)

    timer = threading.Thread(target=interrupt_later)
    started = []

    def progress(event):
        if event.stage == "coarse" and not started:
            started.append(True)
            timer.start()

    with pytest.raises(KeyboardInterrupt):
        wonder3d.Pipeline(preset="quality").from_views(views, progress=progress)
    raised = time.perf_counter()
    timer.join()
    assert sent, "the interrupt was never sent: the reconstruction ended first"
    assert raised - sent[0] < 1.0, f"KeyboardInterrupt {raised - sent[0]:.2f} s after Ctrl-C"
    assert list(tmp_path.iterdir()) == []
    # The interpreter and the library go on working.
    assert wonder3d.reconstruct(views, preset="fast").is_watertight


def test_the_gil_is_not_needed_to_interrupt(spot_views_dir):
    """Ctrl-C while no progress callback is given: the stop flag alone ends the work."""
    views = wonder3d.ViewSet.load(spot_views_dir)

    def interrupt_later():
        time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGINT)

    timer = threading.Thread(target=interrupt_later)
    timer.start()
    start = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        wonder3d.Pipeline(preset="quality").from_views(views)
    timer.join()
    assert time.perf_counter() - start < 2.5
