"""The guided Mitsuba 3 tracer: unbiased against Mitsuba's `path`, and usable as a plugin.

Skipped where Mitsuba or an LLVM for its vectorized variant is missing, unless
SDGUIDE_REQUIRE_MITSUBA is set (CI sets it)."""

import os

import numpy as np
import pytest

try:
    from sdguide.mitsuba import GuidedPathTracer, register, set_variant

    set_variant("llvm_ad_rgb")
    import mitsuba as mi

    from sdguide import scenes
except (ImportError, AttributeError) as error:  # pragma: no cover
    if os.environ.get("SDGUIDE_REQUIRE_MITSUBA"):
        raise
    pytest.skip(f"Mitsuba unavailable: {error}", allow_module_level=True)


def image_mean_and_error(images):
    means = np.array([im.mean(axis=(0, 1)) for im in images], np.float64)
    return means.mean(axis=0), means.std(axis=0, ddof=1) / np.sqrt(len(means))


@pytest.mark.parametrize(
    "name,roulette",
    [("hidden", "classic"), ("hidden", "ears"), ("door", "ears"), ("glossy", "ears")],
)
def test_guided_image_mean_is_within_four_sigma_of_paths(name, roulette):
    # Both are unbiased estimators of the image mean: their difference, in standard errors
    # (the reference's from 8 independent renders, the guided image's from its pixels' sample
    # variances), is about a normal deviate; 4σ fails about once in 10 000 by chance.
    scene = mi.load_dict(scenes.build(name, 24))
    max_depth = scenes.build(name, 8)["integrator"]["max_depth"]
    path = [np.array(mi.render(scene, spp=64, seed=100 + i), np.float64) for i in range(8)]
    tracer = GuidedPathTracer(max_depth=max_depth, training_passes=4, roulette=roulette)
    _, field, info = tracer.render(scene, spp=16, seed=1, waves=4)
    assert field.stats()["samples_recorded_total"] > 0
    reference, reference_error = image_mean_and_error(path)
    mean, error = info.image_mean()
    z = np.abs(mean - reference) / np.sqrt(error**2 + reference_error**2)
    assert np.all(z < 4.0), (mean, reference, z)


def test_the_recorders_estimates_are_the_tracers():
    # The path recorder's estimate per camera sample equals the tracer's own throughput
    # arithmetic, so what the field learns from is what the image shows.
    scene = mi.load_dict(scenes.build("cornell", 16))
    tracer = GuidedPathTracer(training_passes=0)
    import sdguide

    field = sdguide.GuidingField(*tracer._bounds(scene))
    rng = np.random.default_rng(3)
    sensor = scene.sensors()[0]
    image_stats = sdguide.ImageStatistics(16, 16)
    own, _, recorded = tracer._wave(
        scene, sensor, 16, 16, 2, rng, field, image_stats, record=True, estimates=True
    )
    np.testing.assert_allclose(recorded, own, rtol=1e-3, atol=1e-5)


def test_plugin_renders_with_mi_render():
    register()
    scene = mi.load_dict(scenes.build("cornell", 16))
    integrator = mi.load_dict({"type": "sdguide", "training_passes": 2, "max_depth": 6})
    image = np.array(mi.render(scene, integrator=integrator, spp=4))
    assert image.shape == (16, 16, 3) and np.all(np.isfinite(image)) and image.mean() > 0.05


def test_training_passes_join_the_image_by_inverse_variance():
    # The combined image's standard error is below the final render's alone, its weights sum
    # to one, and the 1-spp pass (no variance estimate) has none.
    scene = mi.load_dict(scenes.build("cornell", 16))
    tracer = GuidedPathTracer(max_depth=6, training_passes=4)
    _, _, info = tracer.render(scene, spp=8, seed=2)
    assert len(info.weights) == 5 and info.weights[0] == 0.0
    assert abs(sum(info.weights) - 1.0) < 1e-12 and all(w > 0 for w in info.weights[1:])
    _, combined_error = info.image_mean()
    final_error = np.sqrt(info.pass_variances[-1])
    assert np.all(combined_error < final_error), (combined_error, final_error)
    image, _, alone = tracer.render(scene, spp=8, seed=2, combine=False)
    assert alone.weights == [0.0] * 4 + [1.0] and np.all(np.isfinite(image))
