"""GuidingField from Python: the batch queries' numerics, training, caches, merges, bad input."""

import math
import os
import subprocess
import sys

import numpy as np
import pytest

import sdguide

LOWER, UPPER = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
LIGHT = np.array([0.3, 0.8, 0.5], np.float32) / np.linalg.norm([0.3, 0.8, 0.5])


def f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def radiance(directions):
    """A lobe around LIGHT over a dim ambient: what the test fields learn."""
    c = directions @ LIGHT
    return f32(np.exp(20.0 * (c - 1.0)) * 50.0 + 0.05)


def uniform_directions(rng, n):
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * math.pi, n)
    r = np.sqrt(1.0 - z * z)
    return f32(np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1))


def train(field, rng, n=60_000, iterations=4):
    """Records `n` samples per iteration (half from the guide, half uniform, with the mixture
    pdf) and refines."""
    for _ in range(iterations):
        x = f32(rng.uniform(0.0, 1.0, (n, 3)))
        d, _ = field.sample(x, f32(rng.random((n, 2))))
        uniform = rng.random(n) < 0.5
        d[uniform] = uniform_directions(rng, int(uniform.sum()))
        q = f32(0.5 * field.pdf(x, d) + 0.5 / (4.0 * math.pi))
        assert field.record(x, d, radiance(d), q) == 0
        field.refine()
    return field


@pytest.fixture(scope="module")
def trained():
    return train(sdguide.GuidingField(LOWER, UPPER), np.random.default_rng(7))


def test_sample_pdf_match_to_the_bit_plain_and_with_normals(trained):
    rng = np.random.default_rng(1)
    n = 20_000
    x = f32(rng.random((n, 3)))
    u = f32(rng.random((n, 2)))
    for normals in (None, uniform_directions(rng, n)):
        d, p = trained.sample(x, u, normals)
        assert d.shape == (n, 3) and p.shape == (n,)
        assert np.all(p > 0)
        np.testing.assert_array_equal(p, trained.pdf(x, d, normals))
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    # The product with the cosine draws below the horizon only from cells whose corners are
    # all below it, which keep 10^-5 of the cosine's weight (for an unbiased estimator): rare,
    # where the plain guide sends about half of its draws below.
    below_plain = np.mean(np.sum(trained.sample(x, u)[0] * normals, axis=1) < 0.0)
    below_product = np.mean(np.sum(d * normals, axis=1) < 0.0)
    assert below_plain > 0.3 and below_product < 0.01


def test_a_lane_does_not_depend_on_its_batch(trained):
    rng = np.random.default_rng(2)
    x, u = f32(rng.random((5000, 3))), f32(rng.random((5000, 2)))
    d, p = trained.sample(x, u)
    for i in (0, 1234, 4999):
        di, pi = trained.sample(x[i : i + 1], u[i : i + 1])
        np.testing.assert_array_equal(di[0], d[i])
        assert pi[0] == p[i]


def test_pdf_integrates_to_one(trained):
    # E[pdf(ω)] over uniform ω is 1/(4π): the mean lies within 5 standard errors.
    rng = np.random.default_rng(3)
    n = 400_000
    x = f32(np.tile(np.array([[0.4, 0.6, 0.5]], np.float32), (n, 1)))
    values = trained.pdf(x, uniform_directions(rng, n)) * 4.0 * math.pi
    sigma = values.std() / math.sqrt(n)
    assert abs(values.mean() - 1.0) < 5.0 * sigma


def test_training_lowers_the_estimators_variance(trained):
    rng = np.random.default_rng(4)
    n = 200_000
    x = f32(rng.random((n, 3)))
    d, p = trained.sample(x, f32(rng.random((n, 2))))
    guided = radiance(d) / p
    uniform = radiance(uniform_directions(rng, n)) * 4.0 * math.pi
    # Both estimate the same integral (5 standard errors of their difference) ...
    se = math.hypot(guided.std(), uniform.std()) / math.sqrt(n)
    assert abs(guided.mean() - uniform.mean()) < 5.0 * se
    # ... and the guide, trained on this lobe, is far better than uniform sampling.
    assert guided.var() < 0.25 * uniform.var()


def test_guide_probability_is_a_probability(trained):
    a = trained.guide_probability(f32(np.random.default_rng(5).random((1000, 3))))
    assert a.shape == (1000,) and np.all((a >= 0.0) & (a <= 1.0))


def test_cache_round_trips_and_corruption_is_refused(trained, tmp_path):
    data = trained.to_bytes()
    assert sdguide.GuidingField.from_bytes(data).to_bytes() == data
    path = tmp_path / "field.sdgc"
    trained.save(path)
    assert sdguide.GuidingField.load(str(path)).to_bytes() == data
    bad = bytearray(data)
    bad[len(bad) // 2] ^= 0x40
    with pytest.raises(sdguide.CacheError):
        sdguide.GuidingField.from_bytes(bytes(bad))
    with pytest.raises(sdguide.CacheError):
        sdguide.GuidingField.from_bytes(data[:100])
    with pytest.raises(sdguide.CacheError):
        sdguide.GuidingField.load(tmp_path / "missing.sdgc")


def record_shard(field, shard):
    x, d, v, q = shard
    field.record(x, d, v, q)


def shards_of(rng, n, k):
    x = f32(rng.random((n, 3)))
    d = uniform_directions(rng, n)
    q = f32(np.full(n, 1.0 / (4.0 * math.pi)))
    v = radiance(d) * f32(rng.exponential(1.0, n))
    parts = np.array_split(rng.permutation(n), k)
    return [(f32(x[i]), f32(d[i]), f32(v[i]), f32(q[i])) for i in parts]


def test_workers_merged_in_any_order_give_one_fields_bytes():
    rng = np.random.default_rng(6)
    one = sdguide.GuidingField(LOWER, UPPER, spatial_threshold=2000)
    for _ in range(3):
        shards = shards_of(rng, 40_000, 4)
        base = one.to_bytes()
        workers = [sdguide.GuidingField.from_bytes(base) for _ in shards]
        for w, s in zip(workers, shards):
            record_shard(w, s)
        for s in shards:
            record_shard(one, s)
        for order in ([0, 1, 2, 3], [3, 1, 0, 2]):
            merged = sdguide.GuidingField.from_bytes(base)
            for i in order:
                merged.merge(workers[i])
            assert merged.to_bytes() == one.to_bytes()
        one.refine()
    assert one.stats()["spatial_leaves"] > 1


TRAIN_SCRIPT = """
import hashlib, sys
sys.path.insert(0, {tests!r})
import numpy as np, sdguide
from test_field import train, LOWER, UPPER
field = sdguide.GuidingField(LOWER, UPPER, spatial_threshold=3000)
train(field, np.random.default_rng(11), 30_000, 3)
print(hashlib.sha256(field.to_bytes()).hexdigest())
"""


def test_training_is_identical_whatever_the_threads():
    script = TRAIN_SCRIPT.format(tests=os.path.dirname(__file__))
    digests = set()
    for threads in ("1", "2", "5"):
        env = dict(os.environ, RAYON_NUM_THREADS=threads)
        out = subprocess.run(
            [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
        )
        digests.add(out.stdout.strip())
    assert len(digests) == 1


def test_merge_refuses_a_different_field():
    a = sdguide.GuidingField(LOWER, UPPER)
    with pytest.raises(sdguide.MergeError):
        a.merge(sdguide.GuidingField(LOWER, (2.0, 1.0, 1.0)))


def test_config_keywords():
    field = sdguide.GuidingField(
        LOWER, UPPER, rule="l2-mixture", directional_filter="deferred_box", filter_samples=128
    )
    assert field.config["rule"] == "L2Mixture"
    assert field.config["directional_filter"] == "DeferredBox"
    assert field.config["filter_samples"] == 128
    gain = sdguide.GuidingField(LOWER, UPPER, spatial_split="gain", spatial_gain_threshold=0.02)
    assert gain.config["spatial_split"] == "Gain"
    assert sdguide.GuidingField.from_bytes(gain.to_bytes()).config == gain.config
    assert field.bounds == ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    for bad in (
        {"bogus": 1},
        {"uniform_fraction": 3.0},
        {"rule": "l3"},
        {"spatial_threshold": float("nan")},
        {"volumes": [1]},
    ):
        with pytest.raises(sdguide.ConfigError):
            sdguide.GuidingField(LOWER, UPPER, **bad)
    with pytest.raises(sdguide.ConfigError):
        sdguide.GuidingField(LOWER, (float("nan"), 1.0, 1.0))
    assert issubclass(sdguide.ConfigError, ValueError)


def test_bad_arrays_raise_value_error_and_write_nothing():
    field = sdguide.GuidingField(LOWER, UPPER)
    x, u = f32(np.full((8, 3), 0.5)), f32(np.full((8, 2), 0.5))
    cases = [
        lambda: field.sample(x.astype(np.float64), u),  # float64
        lambda: field.sample(x.tolist(), u),  # not an array
        lambda: field.sample(x[::2], u[:4]),  # strided
        lambda: field.sample(np.asfortranarray(x), u),  # Fortran order
        lambda: field.sample(x, u[:7]),  # mismatched lengths
        lambda: field.sample(x[:, :2], u),  # wrong width
        lambda: field.sample(x.reshape(2, 4, 3), u),  # wrong rank
        lambda: field.pdf(x, x, normals=x[:3]),
        lambda: field.guide_probability(x.ravel()),
        lambda: field.record(x, x, np.ones(7, np.float32), np.ones(8, np.float32)),
        lambda: field.record(
            x, x, np.ones(8, np.float32), np.ones(8, np.float32), bsdf_pdfs=np.ones(8, np.float32)
        ),
        lambda: field.record(
            x, x, np.ones(8, np.float32), np.ones(8, np.float32), volume=np.ones(8, np.float32)
        ),
    ]
    for case in cases:
        with pytest.raises(ValueError):
            case()
    assert field.stats()["samples_recorded"] == 0


def test_bad_values_are_answered_or_counted_never_raised():
    field = sdguide.GuidingField(LOWER, UPPER)
    n = 6
    x = f32(np.full((n, 3), 0.5))
    x[0] = np.nan
    x[1] = 5.0  # outside the bounds
    u = f32(np.full((n, 2), 0.5))
    u[2] = np.nan
    d, p = field.sample(x, u)
    assert np.all(np.isfinite(d)) and np.all(p > 0)
    v = np.ones(n, np.float32)
    q = np.ones(n, np.float32)
    v[3] = np.inf
    q[4] = 0.0
    d2 = d.copy()
    d2[5] = 0.0
    assert field.record(x, d2, v, q) == 5  # lane 2 is good: only its u was NaN
    rejected = field.stats()["rejected"]
    assert rejected["non_finite_position"] == 1
    assert rejected["out_of_bounds"] == 1
    assert rejected["bad_value"] == 1
    assert rejected["bad_pdf"] == 1
    assert rejected["bad_direction"] == 1
    # A NaN direction has density 0.
    assert field.pdf(x[2:3], f32([[np.nan, 0.0, 1.0]]))[0] == 0.0


def test_zero_lanes():
    field = sdguide.GuidingField(LOWER, UPPER)
    empty3, empty2, empty1 = (np.zeros((0, k), np.float32) for k in (3, 2, 1))
    d, p = field.sample(empty3, empty2)
    assert d.shape == (0, 3) and p.shape == (0,)
    assert field.pdf(empty3, empty3).shape == (0,)
    assert field.record(empty3, empty3, empty1[:, 0], empty1[:, 0]) == 0
