"""PathRecorderBatch: the path recorder, one per lane, driven a bounce at a time."""

import numpy as np
import pytest

import sdguide


def f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def test_a_bounce_with_roulette_gives_the_recursive_estimate_and_records():
    # Lane i: the camera ray hits a diffuse floor, the renderer draws a direction there
    # (f·cos 0.2, pdf 0.5), plays roulette with p = 0.4 (survived), and the ray hits a lamp of
    # radiance 3·(i + 1). Lane 3 is inactive from the first push on.
    n = 4
    field = sdguide.GuidingField((0, 0, 0), (1, 1, 1))
    paths = sdguide.PathRecorderBatch(n)
    camera = paths.start()
    active = np.array([True, True, True, False])
    x = f32(np.full((n, 3), 0.5))
    up = f32(np.tile([0.0, 1.0, 0.0], (n, 1)))
    v = paths.push(camera, x, up, f32(np.full((n, 3), 0.2)), f32(np.full(n, 0.5)), active=active)
    assert v[3] == sdguide.NO_VERTEX and np.all(v[:3] != sdguide.NO_VERTEX)
    paths.roulette(v, f32(np.full(n, 0.4)), np.ones(n, bool), active=active)
    lamp = f32(np.repeat(3.0 * (np.arange(n) + 1.0), 3).reshape(n, 3))
    paths.add_radiance(v, lamp, active=active)
    estimates = paths.finish()
    expected = 0.2 / 0.5 * lamp[:, 0] / 0.4
    np.testing.assert_allclose(estimates[:3, 0], expected[:3], rtol=1e-6)
    assert estimates[3, 0] == 0.0
    assert paths.record(field) == 3
    stats = field.stats()
    assert stats["samples_recorded"] == 3 and stats["continuations_recorded"] == 3
    assert paths.stats()["paths"] == n and paths.stats()["bad_values"] == 0


def test_a_random_wavefront_matches_the_per_lane_recursion():
    # Several bounces of random weights, emissions and roulettes over many lanes: each lane's
    # estimate is what a recursive integrator computes, Σ_k (Π_{j<k} w_j / p_j) L_k.
    rng = np.random.default_rng(3)
    n, bounces = 2000, 5
    paths = sdguide.PathRecorderBatch(n)
    at = paths.start()
    alive = np.ones(n, bool)
    throughput = np.ones(n)
    expected = np.zeros(n)
    for _ in range(bounces):
        bsdf = rng.uniform(0.0, 0.3, n)
        pdf = rng.uniform(0.1, 1.0, n)
        x = f32(rng.random((n, 3)))
        d = f32(rng.normal(size=(n, 3)))
        at = paths.push(at, x, d, f32(np.repeat(bsdf, 3).reshape(n, 3)), f32(pdf), active=alive)
        throughput = np.where(alive, throughput * bsdf / pdf, throughput)
        p = rng.uniform(0.3, 1.0, n)
        survived = rng.random(n) < p
        paths.roulette(at, f32(p), survived, active=alive)
        alive &= survived
        throughput = np.where(alive, throughput / p, throughput)
        light = rng.exponential(1.0, n)
        paths.add_radiance(at, f32(np.repeat(light, 3).reshape(n, 3)), active=alive)
        expected += np.where(alive, throughput * light, 0.0)
    estimates = paths.finish()[:, 0]
    np.testing.assert_allclose(estimates, expected, rtol=2e-5)


def test_bad_input_is_counted_or_refused():
    n = 3
    paths = sdguide.PathRecorderBatch(n)
    at = paths.start()
    x = f32(np.full((n, 3), 0.5))
    d = f32(np.tile([0.0, 0.0, 1.0], (n, 1)))
    pdf = f32([0.5, 0.0, np.nan])  # lanes 1 and 2: bad vertices
    v = paths.push(at, x, d, f32(np.full((n, 3), 0.1)), pdf)
    paths.add_radiance(v, f32([[1, 1, 1], [1, 1, 1], [-1, 0, 0]]))  # lane 2: bad value
    paths.roulette(v, f32([1.5, 0.5, 0.5]), np.ones(n, bool))  # lane 0: bad probability
    paths.finish()
    stats = paths.stats()
    assert stats["bad_vertices"] == 2 and stats["bad_values"] == 2
    with pytest.raises(ValueError):
        paths.push(at[:2], x, d, d, pdf)  # too few handles
    with pytest.raises(ValueError):
        paths.push(at.astype(np.int64), x, d, d, pdf)  # handles must be uint32
    with pytest.raises(ValueError):
        paths.roulette(v, f32([0.5] * n), np.ones(n, np.float32))  # survived must be bool
    with pytest.raises(ValueError):
        paths.push(at, x, d, d, pdf, bsdf_pdfs=pdf)  # the pair comes together


def test_a_split_path_runs_as_several_lanes_of_its_path():
    # Path 0 splits at its first vertex (factor 2, two continuations, each weighing 1/2) and
    # its continuations bring 1 and 3; path 1 goes on once and brings 2. f·cos/pdf is 0.5.
    paths = sdguide.PathRecorderBatch(2)
    camera = paths.start()
    paths.split(camera[:1], f32([2.0]), np.array([2], np.uint32), paths=np.array([0], np.uint32))
    lane_path = np.array([0, 0, 1], np.uint32)
    at = camera[lane_path]
    x = f32(np.full((3, 3), 0.5))
    d = f32(np.tile([0.0, 1.0, 0.0], (3, 1)))
    v = paths.push(at, x, d, f32(np.full((3, 3), 0.5)), f32(np.ones(3)), paths=lane_path)
    paths.add_radiance(v, f32(np.repeat([1.0, 3.0, 2.0], 3).reshape(3, 3)), paths=lane_path)
    estimates = paths.finish()
    np.testing.assert_allclose(estimates[:, 0], [0.5 * (1.0 + 3.0) / 2.0, 0.5 * 2.0], rtol=1e-6)
    field = sdguide.GuidingField((0, 0, 0), (1, 1, 1))
    assert paths.record(field) == 3
    with pytest.raises(ValueError):
        paths.add_radiance(v, f32(np.ones((3, 3))), paths=np.array([1, 0, 0], np.uint32))
    with pytest.raises(ValueError):
        paths.add_radiance(v, f32(np.ones((3, 3))), paths=np.array([0, 1, 2], np.uint32))


def test_the_splitting_factor_needs_an_image_and_continuations():
    field = sdguide.GuidingField((0, 0, 0), (1, 1, 1))
    image = sdguide.ImageStatistics(2, 2)
    x = f32(np.full((4, 3), 0.5))
    pixels = np.arange(4, dtype=np.uint32)
    ones = f32(np.ones(4))
    # No pass yet, no continuations: no factor.
    assert np.all(np.isnan(field.splitting_factor(x, ones, pixels, image)))
    # A pass of 8 noisy samples per pixel and cells with continuations (from recorded paths:
    # a vertex whose continuation brought 1 or 3) give factors in the documented bounds.
    rng = np.random.default_rng(4)
    for _ in range(8):
        image.add(pixels, f32(rng.exponential(1.0, 4)), f32(np.full(4, 3.0)))
    image.end_pass()
    assert image.relative_variance > 0 and image.cost_per_sample == 3.0
    n = 64
    recorder = sdguide.PathRecorderBatch(n)
    at = recorder.start()
    v = recorder.push(
        at,
        f32(np.full((n, 3), 0.5)),
        f32(np.tile([0.0, 0.0, 1.0], (n, 1))),
        f32(np.full((n, 3), 0.5)),
        f32(np.ones(n)),
    )
    recorder.add_radiance(v, f32(np.repeat(rng.choice([1.0, 3.0], n), 3).reshape(n, 3)))
    recorder.add_cost(v, f32(np.ones(n)))
    recorder.finish()
    recorder.record(field)
    field.refine()
    for mode, top in (("roulette", 1.0), ("splitting", 8.0)):
        q = field.splitting_factor(x, f32([0.0, 0.1, 1.0, 100.0]), pixels, image, mode=mode)
        assert q[0] == pytest.approx(0.05)  # zero throughput: the smallest survival
        assert np.all((q >= 0.05) & (q <= top)) and q[1] <= q[2] <= q[3]
    assert field.splitting_factor(x, ones, pixels, image, mode="roulette")[0] <= 1.0
    with pytest.raises(ValueError):
        field.splitting_factor(x, ones, pixels, image, mode="sometimes")
    with pytest.raises(sdguide.ConfigError):
        field.splitting_factor(x, ones, pixels, image, min_survival=0.0)
    with pytest.raises(sdguide.ConfigError):
        sdguide.ImageStatistics(2, 2, epsilon=0.0)


def test_continuations_round_stochastically():
    traced, weights = sdguide.continuations(
        f32([2.25, 2.25, 0.5, 0.5, np.nan]), f32([0.1, 0.5, 0.7, 0.2, 0.3])
    )
    assert traced.tolist() == [3, 2, 0, 1, 1]
    np.testing.assert_allclose(weights, [1 / 2.25, 1 / 2.25, 2.0, 2.0, 1.0], rtol=1e-6)
    # E[traced] = q: 200k draws at q = 1.3 within 5 standard errors (σ² = 0.3·0.7).
    u = np.random.default_rng(9).random(200_000, dtype=np.float32)
    traced, _ = sdguide.continuations(f32(np.full(200_000, 1.3)), u)
    assert abs(traced.mean() - 1.3) < 5.0 * np.sqrt(0.21 / 200_000)


def test_pass_weights_are_inverse_variances_and_bad_arrays_raise():
    # One pixel, passes of n samples of 0 and 2: the pixel mean's variance is 1/(n − 1), so
    # passes of 4 and 12 samples weigh 3 : 11 (the Rust doc example); a 1-sample pass, 0.
    def passes(*ns):
        n = np.array(ns, np.float64)[:, None]
        return n, 2.0 * n, n.astype(np.uint32)

    w = sdguide.pass_weights(1, 1, *passes(4, 12))
    np.testing.assert_allclose(w, [3 / 14, 11 / 14], rtol=1e-12)
    w = sdguide.pass_weights(1, 1, *passes(1, 4, 12))
    np.testing.assert_allclose(w, [0.0, 3 / 14, 11 / 14], rtol=1e-12)
    assert sdguide.pass_weights(1, 1, *passes(1)) is None
    sums, squares, counts = passes(4, 12)
    squares[0, 0] = np.nan  # a NaN pass is left out, not spread
    np.testing.assert_allclose(sdguide.pass_weights(1, 1, sums, squares, counts), [0.0, 1.0])
    sums, squares, counts = passes(4, 12)
    for bad in (
        (sums.astype(np.float32), squares, counts),  # float32 sums
        (sums, squares[:1], counts),  # a pass short
        (sums, squares, counts.astype(np.int64)),
        (np.ones((2, 2)), np.ones((2, 2)), np.ones((2, 2), np.uint32)),  # 2 pixels, not 1
    ):
        with pytest.raises(ValueError):
            sdguide.pass_weights(1, 1, *bad)
