"""The timing every torch peer benchmark of `cargo xtask bench` shares.

`report(id, fn, runs, warmup, **extra)` calls `fn` `warmup` times untimed, then `runs` times,
and prints one JSON line: `id`, the median and all times in ms, torch's version and thread
count, and any `extra` fields (the xtask matches `id` against its burn rows).
"""

import json
import statistics
import time

import torch


def report(id, fn, runs, warmup=1, **extra):
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    print(json.dumps({
        "id": id,
        "median_ms": statistics.median(times),
        "times_ms": times,
        **extra,
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
    }), flush=True)
