"""Guide samples and pdfs per second through Python's batch calls, against the Rust one-vertex
calls on the same field and lanes, in the same run.

    python examples/batch_throughput.py [--lanes 1000000] [--rounds 5] [--repeats 3]

A field is trained on an analytic light field and saved; 1M lanes (position, normal, two
uniform numbers) are written beside it. Then, alternating, for 1 and 2 threads: a Python
process times `sample` + `pdf` with normals over every lane (`RAYON_NUM_THREADS` threads,
the best of `--rounds`), and the Rust example `vertex_rate` times the one-vertex calls
`distribution(x).at_surface(n).sample(u)` and `.pdf(ω)` from as many threads. Each pair repeats
`--repeats` times; the report gives the median rates and their ratio, and checks that both
computed the same pdfs (checksums).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))

TIME_BATCH = """
import sys, time, numpy as np, sdguide
field = sdguide.GuidingField.load(sys.argv[1])
lanes = np.fromfile(sys.argv[2], dtype='<f4').reshape(-1, 8)
x, n, u = (np.ascontiguousarray(lanes[:, a:b]) for a, b in ((0, 3), (3, 6), (6, 8)))
best = float('inf')
for _ in range(int(sys.argv[3])):
    t = time.perf_counter()
    d, p = field.sample(x, u, n)
    q = field.pdf(x, d, n)
    best = min(best, time.perf_counter() - t)
print(f"{len(x) / best:.6e} {float(np.sum(p, dtype=np.float64) + np.sum(q, dtype=np.float64)):.9e}")
"""


def train(path: str, lanes_path: str, lanes: int) -> None:
    import sdguide

    sys.path.insert(0, HERE)
    from dask_farm import record_samples  # the farm example's light field and sampling

    field = sdguide.GuidingField((0, 0, 0), (1, 1, 1), spatial_threshold=4000)
    for iteration in range(5):
        for shard in range(4):
            record_samples(field, 100 * iteration + shard, 100_000)
        field.refine()
    field.save(path)
    rng = np.random.default_rng(5)
    n = rng.normal(size=(lanes, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    data = np.concatenate([rng.random((lanes, 3)), n, rng.random((lanes, 2))], axis=1)
    data.astype("<f4").tofile(lanes_path)


def measure(command, env=None):
    # From the scratch directory: a checkout's `python/sdguide` must not shadow the package.
    out = subprocess.run(
        command, capture_output=True, text=True, check=True, env=env, cwd=tempfile.gettempdir()
    )
    rate, checksum = out.stdout.split()
    return float(rate), float(checksum)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=1_000_000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    subprocess.run(
        ["cargo", "build", "--release", "--locked", "--example", "vertex_rate"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    rust = os.path.join(ROOT, "target", "release", "examples", "vertex_rate")
    with tempfile.TemporaryDirectory() as scratch:
        cache = os.path.join(scratch, "field.sdgc")
        lanes = os.path.join(scratch, "lanes.f32")
        train(cache, lanes, args.lanes)
        print(f"{args.lanes} lanes, guide sample + pdf with normals (the product with the cosine)")
        print("| threads | Python batch (lanes/s) | Rust one-vertex (lanes/s) | ratio |")
        print("|---:|---:|---:|---:|")
        worst = math.inf
        for threads in (1, 2):
            env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
            py, rs = [], []
            for _ in range(args.repeats):
                rate, sum_py = measure(
                    [sys.executable, "-c", TIME_BATCH, cache, lanes, str(args.rounds)], env
                )
                py.append(rate)
                rate, sum_rs = measure([rust, cache, lanes, str(threads), str(args.rounds)])
                rs.append(rate)
                if not math.isclose(sum_py, sum_rs, rel_tol=1e-9):
                    print(f"checksums differ: {sum_py} against {sum_rs}")
                    return 1
            ratio = float(np.median(py) / np.median(rs))
            worst = min(worst, ratio)
            print(f"| {threads} | {np.median(py):.3e} | {np.median(rs):.3e} | {ratio:.2f} |")
    return 0 if worst > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
