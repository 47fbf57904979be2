"""Training on a farm with Dask: workers record shards of each pass, the driver merges.

Each iteration the driver broadcasts the field's cache bytes; every worker loads them, records
its shard of the pass's samples into its own copy, and returns its field's cache bytes; the
driver merges the workers' fields (in whatever order they finish), refines, and broadcasts the
next iteration's. Training is deterministic, so the farm's final cache is byte for byte the
one a single process recording every sample makes — checked at the end, and by
``tests/test_farm.py``.

The samples come from an analytic light field (a bright lobe over a dim ambient, changing with
position), half drawn from the field being trained and half uniformly, as a renderer's would.
A shard's samples depend only on its seed and the broadcast field, never on the worker.

    python examples/dask_farm.py --workers 4 --shards 8 --iterations 4
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time

import numpy as np

import sdguide

LOWER, UPPER = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
CONFIG = {"spatial_threshold": 4000}


def radiance(x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A lobe whose direction turns with x over a dim ambient."""
    angle = 2.0 * x[:, 0]
    axis = np.stack([np.cos(angle), np.full_like(angle, 0.6), np.sin(angle)], axis=1)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    c = np.sum(d * axis, axis=1)
    return (40.0 * np.exp(30.0 * (c - 1.0)) + 0.05).astype(np.float32)


def record_samples(field: sdguide.GuidingField, seed: int, samples: int) -> None:
    """Draws a shard's samples from `field` (its queries read the state of the last
    `refine`, not what is being recorded) and records them into it."""
    rng = np.random.default_rng(seed)
    x = rng.random((samples, 3), dtype=np.float32)
    d, _ = field.sample(x, rng.random((samples, 2), dtype=np.float32))
    uniform = rng.random(samples) < 0.5
    z = rng.uniform(-1.0, 1.0, samples)
    phi = rng.uniform(0.0, 2.0 * math.pi, samples)
    r = np.sqrt(1.0 - z * z)
    u = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)
    d = np.ascontiguousarray(np.where(uniform[:, None], u, d), dtype=np.float32)
    q = (0.5 * field.pdf(x, d) + 0.5 / (4.0 * math.pi)).astype(np.float32)
    field.record(x, d, radiance(x, d), q)


def record_shard(cache: bytes, seed: int, samples: int) -> bytes:
    """One worker's share of a pass: load the broadcast field, record, return the cache."""
    field = sdguide.GuidingField.from_bytes(cache)
    record_samples(field, seed, samples)
    return field.to_bytes()


def shard_seeds(iteration: int, shards: int) -> list[int]:
    return [1000 * iteration + s for s in range(shards)]


def merge(cache: bytes, results: list[bytes]) -> sdguide.GuidingField:
    field = sdguide.GuidingField.from_bytes(cache)
    for data in results:
        field.merge(sdguide.GuidingField.from_bytes(data))
    field.refine()
    return field


def train_on_farm(client, iterations: int, shards: int, samples: int) -> bytes:
    """The driver: broadcast, record shards on the workers, merge as they finish, refine."""
    from dask.distributed import as_completed

    field = sdguide.GuidingField(LOWER, UPPER, **CONFIG)
    for iteration in range(iterations):
        cache = field.to_bytes()
        broadcast = client.scatter(cache, broadcast=True)
        futures = [
            client.submit(record_shard, broadcast, seed, samples, pure=False)
            for seed in shard_seeds(iteration, shards)
        ]
        results = [future.result() for future in as_completed(futures)]
        field = merge(cache, results)
    return field.to_bytes()


def train_in_one_process(iterations: int, shards: int, samples: int) -> bytes:
    """The same training without a farm: one field records every shard's samples."""
    field = sdguide.GuidingField(LOWER, UPPER, **CONFIG)
    for iteration in range(iterations):
        for seed in shard_seeds(iteration, shards):
            record_samples(field, seed, samples)
        field.refine()
    return field.to_bytes()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--shards", type=int, default=6)
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument("--samples", type=int, default=50_000, help="samples per shard")
    args = parser.parse_args(argv)
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True) as cluster:
        with Client(cluster) as client:
            start = time.perf_counter()
            farm = train_on_farm(client, args.iterations, args.shards, args.samples)
            farm_seconds = time.perf_counter() - start
    start = time.perf_counter()
    one = train_in_one_process(args.iterations, args.shards, args.samples)
    one_seconds = time.perf_counter() - start
    digest = hashlib.sha256(farm).hexdigest()[:16]
    print(
        f"farm of {args.workers} workers: {farm_seconds:.1f} s, "
        f"cache {len(farm)} bytes, sha256 {digest}"
    )
    print(f"one process: {one_seconds:.1f} s, identical: {farm == one}")
    return 0 if farm == one else 1


if __name__ == "__main__":
    sys.exit(main())
