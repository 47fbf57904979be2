"""A guided path tracer for Mitsuba 3, run as a wavefront: one bounce of every path at a time.

Mitsuba traces the rays and evaluates and samples its own BSDFs and emitters; sdguide, between
two bounces, gives each vertex the guide's learned probability, draws the guided directions
(from the product with the clamped cosine) and their pdfs, and records the finished paths
through :class:`sdguide.PathRecorderBatch`. Everything a bounce needs from Mitsuba is
evaluated in one ``dr.eval`` and handed to numpy; the loop over bounces is plain Python.

The estimator at a vertex with a smooth, reflecting BSDF samples the one-sample mixture
``q = a·p_guide + (1 − a)·p_bsdf`` (``a`` the cell's learned guide probability), weighs the
sampled direction by ``f·cos/q``, and combines next-event estimation with the mixture by the
power heuristic. BSDFs with a delta lobe, and transmitting ones, are left to the BSDF
(``a = 0``): the cosine product guides the reflecting hemisphere only. Russian roulette is
classic by default, on the throughput after ``rr_depth`` bounces as Mitsuba's ``path`` plays
it; ``roulette="ears"`` plays the library's efficiency-aware roulette and splitting instead,
a split vertex's continuations becoming more lanes of its camera sample.

Training follows the SD-tree schedule: passes of 1, 2, 4, … samples per pixel, each recorded
and followed by ``refine``; the image is the final render, with the trained field, combined
with the training passes' images by inverse variance (:func:`sdguide.pass_weights`). Every
pass also feeds :class:`sdguide.ImageStatistics`, the image terms of the splitting factor.

    from sdguide.mitsuba import GuidedPathTracer, register, set_variant
    set_variant("llvm_ad_rgb")      # finds an LLVM ≥ 16 for Dr.Jit
    image, field, info = GuidedPathTracer(max_depth=8).render(scene, spp=64, seed=1)
    register()                      # or as a Mitsuba plugin:
    mi.render(scene, integrator=mi.load_dict({"type": "sdguide", "spp_training": 31}))

Needs Mitsuba 3.6 or newer and a vectorized variant (``llvm_ad_rgb``; Dr.Jit's LLVM backend
needs LLVM 16 or newer, which :func:`set_variant` finds; ``scalar_rgb`` does not apply — the
loop works on arrays).
"""

from __future__ import annotations

import glob
import os
import sys
import time
from dataclasses import dataclass
from dataclasses import field as dataclass_field

import numpy as np

import sdguide

try:
    import drjit as dr
    import mitsuba as mi
except ImportError as error:  # pragma: no cover - the message is the point
    raise ImportError(
        "sdguide.mitsuba needs Mitsuba 3: pip install 'sdguide[mitsuba]' (or mitsuba)"
    ) from error


def set_variant(variant: str = "llvm_ad_rgb") -> None:
    """``mi.set_variant(variant)``, first pointing Dr.Jit at an LLVM it can use for the LLVM
    variants: ``DRJIT_LIBLLVM_PATH`` if set, else the newest ``libLLVM`` 16–19 in the usual
    library directories (Debian: ``apt-get install libllvm19``). Older ones abort the process
    at the first kernel."""
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        for version in (19, 18, 17, 16):
            found = sorted(
                glob.glob(f"/usr/lib/*/libLLVM.so.{version}*")
                + glob.glob(f"/usr/lib/*/libLLVM-{version}.so*")
                + glob.glob(f"/usr/lib/llvm-{version}/lib/libLLVM*.so*")
            )
            if found:
                os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
                break
    mi.set_variant(variant)


#: Lanes traced at once: passes with more samples run in waves of this many paths.
MAX_LANES = 1 << 20


def _soa(v) -> np.ndarray:
    """A Mitsuba 3-vector array as an ``(N, 3)`` C-contiguous float32 numpy array."""
    return np.ascontiguousarray(np.asarray(v, dtype=np.float32).T)


def _np(v) -> np.ndarray:
    return np.asarray(v)


def _vec(a: np.ndarray):
    """An ``(N, 3)`` numpy array as a Mitsuba vector array."""
    return _opaque(mi.Vector3f(np.ascontiguousarray(a.T)))


def _opaque(x):
    """``x`` kept in memory, never folded into a kernel as a constant: Dr.Jit turns an array of
    one element into a literal, and a kernel with a random literal in it is a new kernel to
    compile (tens of milliseconds) every time a path's last lane reaches it."""
    dr.make_opaque(x)
    return x


@dataclass
class PassSums:
    """One pass's per-pixel sums of its samples: RGB and squared RGB ``(H·W, 3)``,
    luminance and squared luminance ``(H·W,)`` (what :func:`sdguide.pass_weights` takes);
    ``spp`` samples per pixel."""

    rgb: np.ndarray
    rgb_squares: np.ndarray
    luminance: np.ndarray
    luminance_squares: np.ndarray
    spp: int = 0

    @classmethod
    def empty(cls, pixels: int) -> PassSums:
        zeros = np.zeros(pixels, np.float64)
        return cls(np.zeros((pixels, 3)), np.zeros((pixels, 3)), zeros, zeros.copy())

    @classmethod
    def of_samples(cls, estimates: np.ndarray, luminance: np.ndarray, spp: int) -> PassSums:
        """The sums of ``spp`` samples per pixel: ``estimates`` ``(pixels·spp, 3)`` RGB and
        their ``luminance`` ``(pixels·spp,)``, pixel ``p``'s samples at rows ``p·spp`` to
        ``p·spp + spp − 1``."""
        pixels = len(luminance) // spp
        return cls(
            estimates.reshape(pixels, spp, 3).sum(axis=1),
            (estimates**2).reshape(pixels, spp, 3).sum(axis=1),
            luminance.reshape(pixels, spp).sum(axis=1),
            (luminance**2).reshape(pixels, spp).sum(axis=1),
            spp,
        )

    def add(self, other: PassSums) -> None:
        """Pools ``other``'s samples into this pass."""
        self.rgb += other.rgb
        self.rgb_squares += other.rgb_squares
        self.luminance += other.luminance
        self.luminance_squares += other.luminance_squares
        self.spp += other.spp

    def image_mean(self):
        """The pass image's mean over pixels and that mean's variance (from the pixels'
        sample variances), per channel."""
        pixels, n = len(self.rgb), max(self.spp, 1)
        variance = (self.rgb_squares - self.rgb**2 / n) / max(n - 1, 1)
        return self.rgb.sum(axis=0) / n / pixels, variance.sum(axis=0) / n / pixels**2


@dataclass
class RenderInfo:
    """What a render did: its passes and times, how they were combined, and the field's size
    at the end."""

    seconds_training: float = 0.0
    seconds_render: float = 0.0
    passes: list = dataclass_field(default_factory=list)
    #: Per pass of the image (the training passes, then the final render): the mean over
    #: the image per channel, and that mean's variance from its pixels' sample variances.
    pass_means: list = dataclass_field(default_factory=list)
    pass_variances: list = dataclass_field(default_factory=list)
    #: The weight of each of those passes in the image (:func:`sdguide.pass_weights`; the
    #: final render's alone without ``combine``).
    weights: list = dataclass_field(default_factory=list)
    stats: dict = dataclass_field(default_factory=dict)
    #: Rays traced (camera, extension and shadow rays), camera samples and samples per pixel
    #: in the final render.
    rays: int = 0
    camera_samples: int = 0
    spp: int = 0

    @property
    def seconds(self) -> float:
        return self.seconds_training + self.seconds_render

    @property
    def rays_per_sample(self) -> float:
        return self.rays / max(self.camera_samples, 1)

    def image_mean(self):
        """The image's mean over pixels and its standard error, per channel (the passes are
        independent given the fields they were rendered with, their weights taken as fixed)."""
        w = np.asarray(self.weights, np.float64)[:, None]
        mean = np.sum(w * np.asarray(self.pass_means), axis=0)
        return mean, np.sqrt(np.sum(w**2 * np.asarray(self.pass_variances), axis=0))


class GuidedPathTracer:
    """Path tracing with next-event estimation, MIS and the guide–BSDF mixture.

    ``guided=False`` gives the same tracer with the guide off (``a = 0``): the baseline that
    separates the guide's effect from the tracer's. ``roulette``: ``"classic"`` (on the
    throughput after ``rr_depth`` bounces, as Mitsuba's ``path``), ``"ear"`` (the library's
    efficiency-aware roulette at every vertex, classic where a cell has no estimate yet) or
    ``"ears"`` (roulette and splitting: a vertex may trace up to ``max_splits``
    continuations, as more lanes of its path). ``config`` holds
    :class:`sdguide.GuidingField` keywords; ``spatial_threshold`` defaults to 4000 here, not
    the library's 12000: on the four test scenes at 128×128 pixels the finer cells lowered the
    guided relMSE times rays by 16–29% (``docs/python.md``). ``training_passes`` passes of 1,
    2, 4, … spp train the field (the guide, and the continuation estimates the roulette
    needs) before the final render; they are skipped when a field is passed to ``render``,
    or when the guide is off under classic roulette, where nothing would use them. With a
    ``budget``, time sets the passes instead (unless ``training_share`` is ``None``): they go
    on doubling while the next one (at twice the last one's time) would end within
    ``training_share`` of the budget. Their images join the final render's by inverse
    variance, so training longer costs little: on ``door`` at 60 s, a share of 0.5 (255 spp
    of training) measured ahead of 0.3 (127 spp; ``docs/python.md``).
    """

    #: The camera sample's rays beyond which a vertex no longer splits (the demo's bound).
    MAX_RAYS_PER_SAMPLE = 256

    def __init__(
        self,
        max_depth: int = 8,
        rr_depth: int = 5,
        guided: bool = True,
        roulette: str = "classic",
        training_passes: int = 5,
        training_share: float | None = 0.5,
        max_splits: float = 8.0,
        progress: bool = False,
        **config,
    ):
        if max_depth < 1 or rr_depth < 1:
            raise ValueError("max_depth and rr_depth must be at least 1")
        if roulette not in ("classic", "ear", "ears"):
            raise ValueError(f"roulette is {roulette!r}: 'classic', 'ear' or 'ears'")
        self.max_depth = max_depth
        self.rr_depth = rr_depth
        self.guided = guided
        self.roulette = roulette
        if training_share is not None and not 0.0 < training_share < 1.0:
            raise ValueError(f"training_share is {training_share!r}: in (0, 1)")
        self.trains = guided or roulette != "classic"
        self.training_passes = training_passes if self.trains else 0
        self.training_share = training_share
        self.max_splits = max_splits
        self.progress = progress
        self.config = {"spatial_threshold": 4000.0, **config}

    # --- the public entry points ------------------------------------------------------------

    def render(
        self,
        scene,
        spp: int,
        seed: int = 0,
        field=None,
        sensor=None,
        budget=None,
        waves=1,
        combine=True,
    ):
        """Trains (unless ``field`` is given), then renders ``waves`` waves of ``spp``
        samples per pixel: returns ``(image (H, W, 3) float32, field, RenderInfo)``.

        With ``budget`` (seconds), waves go on until the training and rendering time reaches
        it: an equal-time render. The image is the training passes' and the final render's
        combined by inverse variance (:func:`sdguide.pass_weights`: the training passes are
        unbiased, only noisier); ``combine=False`` gives the final render alone.
        """
        sensor = sensor or scene.sensors()[0]
        width, height = (int(v) for v in sensor.film().crop_size())
        rng = np.random.default_rng(seed)
        info = RenderInfo()
        image_stats = sdguide.ImageStatistics(width, height)
        passes = []
        start = time.perf_counter()
        if field is None:
            lower, upper = self._bounds(scene)
            field = sdguide.GuidingField(lower, upper, **self.config)
            timed = budget is not None and self.training_share is not None and self.trains
            last = 0.0
            for k in range(24 if timed else self.training_passes):
                # The next pass takes about twice the last one's time.
                next_ends = time.perf_counter() - start + 2.0 * last
                if timed and k > 0 and next_ends > self.training_share * budget:
                    break
                t = time.perf_counter()
                sums, _ = self._pass(scene, sensor, 1 << k, rng, field, image_stats, record=True)
                passes.append(sums)
                field.refine()
                last = time.perf_counter() - t
                info.passes.append(("training", 1 << k, last))
                self._say(f"training pass {k}: {1 << k} spp, {time.perf_counter() - t:.1f} s")
        info.seconds_training = time.perf_counter() - start
        start = time.perf_counter()
        final, done = PassSums.empty(width * height), 0
        while True:
            t = time.perf_counter()
            sums, rays = self._pass(scene, sensor, spp, rng, field, image_stats, record=False)
            final.add(sums)
            done += 1
            info.rays += rays
            info.passes.append(("render", spp, time.perf_counter() - t))
            self._say(f"render wave {done}: {spp} spp, {time.perf_counter() - t:.1f} s")
            if done < waves:
                continue
            elapsed = info.seconds_training + time.perf_counter() - start
            per_wave = (time.perf_counter() - start) / done
            if budget is None or elapsed + 0.5 * per_wave > budget:
                break
        passes.append(final)
        info.spp = final.spp
        info.camera_samples = final.spp * width * height
        weights = None
        if combine and len(passes) > 1:
            weights = sdguide.pass_weights(
                width,
                height,
                np.stack([p.luminance for p in passes]),
                np.stack([p.luminance_squares for p in passes]),
                np.stack([np.full(width * height, p.spp, np.uint32) for p in passes]),
            )
        if weights is None:
            weights = np.zeros(len(passes))
            weights[-1] = 1.0
        image = sum(w / p.spp * p.rgb for w, p in zip(weights, passes) if w > 0)
        for p in passes:
            mean, variance = p.image_mean()
            info.pass_means.append(mean)
            info.pass_variances.append(variance)
        info.weights = [float(w) for w in weights]
        info.seconds_render = time.perf_counter() - start
        info.stats = field.stats()
        return image.reshape(height, width, 3).astype(np.float32), field, info

    # --- one pass -----------------------------------------------------------------------------

    def _say(self, text):
        if self.progress:
            print(f"[sdguide] {text}", file=sys.stderr, flush=True)

    @staticmethod
    def _bounds(scene):
        bbox = scene.bbox()
        lower = np.array(bbox.min, np.float64).ravel()
        upper = np.array(bbox.max, np.float64).ravel()
        pad = 1e-3 * max(float(np.max(upper - lower)), 1e-6)
        return tuple(lower - pad), tuple(upper + pad)

    def _pass(self, scene, sensor, spp, rng, field, image_stats, record):
        """One pass of ``spp`` samples per pixel, in waves of at most ``MAX_LANES`` camera
        samples; adds its camera samples to ``image_stats`` and returns its
        :class:`PassSums` and the rays it traced."""
        width, height = (int(v) for v in sensor.film().crop_size())
        pixels = width * height
        per_wave = max(1, min(spp, MAX_LANES // pixels))
        sums = PassSums.empty(pixels)
        rays_traced = 0
        while sums.spp < spp:
            k = min(per_wave, spp - sums.spp)
            estimates, rays = self._wave(
                scene, sensor, width, height, k, rng, field, image_stats, record
            )
            pixel = np.repeat(np.arange(pixels, dtype=np.uint32), k)
            luminance = _luminance(estimates)
            image_stats.add(pixel, _f32(luminance), _f32(rays))
            sums.add(PassSums.of_samples(estimates, luminance, k))
            rays_traced += int(rays.sum())
        image_stats.end_pass()
        return sums, rays_traced

    def _wave(
        self, scene, sensor, width, height, spp, rng, field, image_stats, record, estimates=False
    ):
        """``spp`` camera samples through every pixel (path ``p`` in pixel ``p // spp``):
        returns every camera sample's estimate (P, 3) and the rays it traced (P,); with
        ``estimates``, the path recorder's estimates too (recording only)."""
        pixels = width * height
        n_paths = pixels * spp
        film = rng.random((n_paths, 2), dtype=np.float32)
        pixel_of_path = np.repeat(np.arange(pixels, dtype=np.uint32), spp)
        film[:, 0] = (pixel_of_path % width + film[:, 0]) / width
        film[:, 1] = (pixel_of_path // width + film[:, 1]) / height
        ray, weight = sensor.sample_ray(
            time=0.0,
            sample1=mi.Float(rng.random(n_paths, dtype=np.float32)),
            sample2=mi.Point2f(np.ascontiguousarray(film.T)),
            sample3=mi.Point2f(np.ascontiguousarray(rng.random((2, n_paths), dtype=np.float32))),
        )
        radiance = np.zeros((n_paths, 3), np.float64)
        rays = np.ones(n_paths, np.int64)  # the camera rays
        recorder = sdguide.PathRecorderBatch(n_paths) if record else None
        # The lanes: one per camera sample at first; a split adds lanes to its path, roulette
        # and escape remove them. `path` stays sorted, as the recorder wants it.
        path = np.arange(n_paths, dtype=np.uint32)
        handle = recorder.start() if record else np.zeros(n_paths, np.uint32)
        throughput = np.ones((n_paths, 3)) * _soa(mi.Spectrum(weight))  # a size-1 weight broadcasts
        ctx = mi.BSDFContext()
        prev_si, prev_q, prev_delta = None, None, None
        for depth in range(self.max_depth):
            lanes = len(path)
            if lanes == 0:
                break
            paths_kw = {"paths": path} if record else {}
            si = scene.ray_intersect(ray)
            # Emission the ray hit, weighed against next-event estimation at the last vertex.
            emitted = si.emitter(scene).eval(si)
            if depth > 0:
                ds = mi.DirectionSample3f(scene, si, prev_si)
                light_pdf = scene.pdf_emitter_direction(prev_si, ds, ~prev_delta)
                q2 = prev_q * prev_q
                mis = dr.select(prev_delta, 1.0, q2 / dr.maximum(q2 + light_pdf * light_pdf, 1e-30))
                emitted = emitted * mis
            go_on = si.is_valid() & (depth + 1 < self.max_depth)
            bsdf = si.bsdf(ray)
            flags = bsdf.flags()
            smooth = go_on & mi.has_flag(flags, mi.BSDFFlags.Smooth)
            guidable = smooth & ~mi.has_flag(flags, mi.BSDFFlags.Delta)
            guidable &= ~mi.has_flag(flags, mi.BSDFFlags.Transmission)
            # Next-event estimation at this vertex.
            light, light_weight = scene.sample_emitter_direction(
                si, _point2(rng, lanes), True, smooth
            )
            f_light, bsdf_pdf_light = bsdf.eval_pdf(ctx, si, si.to_local(light.d), smooth)
            facing = dr.select(mi.Frame3f.cos_theta(si.wi) < 0, -1.0, 1.0)
            normal = si.sh_frame.n * facing
            nee = f_light * light_weight
            dr.eval(si, emitted, go_on, smooth, guidable, light, nee, bsdf_pdf_light, normal)
            x = _soa(si.p)
            n_sh = _soa(normal)
            go_on_np, smooth_np, guidable_np = _np(go_on), _np(smooth), _np(guidable)
            emitted_np = _soa(emitted).astype(np.float64)
            _accumulate(radiance, path, throughput * emitted_np)
            if record:
                recorder.add_radiance(handle, _f32(emitted_np), **paths_kw)
            a = np.zeros(lanes, np.float32)
            if self.guided:
                a = np.where(guidable_np, field.guide_probability(x), 0.0).astype(np.float32)
            guide_pdf_light = field.pdf(x, _soa(light.d), n_sh)
            q_light = a * guide_pdf_light + (1.0 - a) * _np(bsdf_pdf_light)
            p_light = _np(light.pdf)
            mis_light = np.where(
                _np(light.delta), 1.0, p_light**2 / np.maximum(p_light**2 + q_light**2, 1e-30)
            )
            nee_np = _soa(nee).astype(np.float64) * mis_light[:, None]
            nee_np[~smooth_np] = 0.0
            _accumulate(radiance, path, throughput * nee_np)
            rays += np.bincount(path, weights=smooth_np, minlength=n_paths).astype(np.int64)
            if record:
                recorder.add_radiance(handle, _f32(nee_np), active=smooth_np, **paths_kw)
                recorder.add_cost(handle, np.ones(lanes, np.float32), active=smooth_np, **paths_kw)
            # How many continuations: the efficiency-aware factor where the cell has an
            # estimate, else one, under classic roulette below.
            traced = go_on_np.astype(np.uint32)
            factor = np.full(lanes, np.nan, np.float32)
            if self.roulette != "classic":
                factor = field.splitting_factor(
                    x,
                    _f32(_luminance(throughput)),
                    pixel_of_path[path],
                    image_stats,
                    mode="roulette" if self.roulette == "ear" else "splitting",
                    max_splits=self.max_splits,
                )
                # The camera vertex only plays roulette (as in the demo: its factor there is
                # mostly noise), and so does a camera sample past its ray budget.
                capped = (depth == 0) | (rays[path] >= self.MAX_RAYS_PER_SAMPLE)
                factor = np.where(capped, np.minimum(factor, 1.0), factor).astype(np.float32)
                has_factor = go_on_np & np.isfinite(factor)
                k, w = sdguide.continuations(factor, rng.random(lanes, dtype=np.float32))
                traced = np.where(has_factor, k, traced).astype(np.uint32)
                throughput = throughput * np.where(has_factor, w, 1.0)[:, None]
                if record:
                    recorder.split(handle, factor, traced, active=has_factor, **paths_kw)
            classic = ~np.isfinite(factor)
            # The continuations: lane i becomes traced[i] lanes of its path.
            idx = np.repeat(np.arange(lanes), traced)
            lanes = len(idx)
            if lanes == 0:
                break
            si = dr.gather(type(si), si, _opaque(mi.UInt32(idx.astype(np.uint32))))
            bsdf = si.bsdf()
            x, n_sh, a = x[idx], n_sh[idx], a[idx]
            path, handle, throughput = path[idx], handle[idx], throughput[idx]
            smooth_np, guidable_np, classic = smooth_np[idx], guidable_np[idx], classic[idx]
            paths_kw = {"paths": path} if record else {}
            # The direction: the guide's with probability a, else the BSDF's.
            bs, bs_weight = bsdf.sample(
                ctx, si, _opaque(mi.Float(rng.random(lanes, dtype=np.float32))), _point2(rng, lanes)
            )
            bs_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            bs_direction = si.to_world(bs.wo)
            dr.eval(bs, bs_weight, bs_delta, bs_direction)
            choose = guidable_np & (rng.random(lanes) < a)
            guide_d, guide_pdf_drawn = field.sample(
                x, rng.random((lanes, 2), dtype=np.float32), n_sh
            )
            bs_d = _soa(bs_direction)
            direction = np.where(choose[:, None], guide_d, bs_d)
            delta_np = _np(bs_delta) & ~choose & (_np(bs.pdf) > 0)
            scatter = ~delta_np & (smooth_np | choose)
            f_d, bsdf_pdf_d = bsdf.eval_pdf(
                ctx, si, si.to_local(_vec(direction)), _opaque(mi.Bool(scatter))
            )
            dr.eval(f_d, bsdf_pdf_d)
            f_np = _soa(f_d)
            bsdf_pdf_np = _np(bsdf_pdf_d).astype(np.float32)
            guide_pdf_d = np.where(choose, guide_pdf_drawn, field.pdf(x, direction, n_sh))
            q = a * guide_pdf_d + (1.0 - a) * bsdf_pdf_np
            scatter &= q > 0.0
            weight = np.zeros((lanes, 3), np.float64)
            weight[scatter] = f_np[scatter] / q[scatter, None]
            weight[delta_np] = _soa(bs_weight)[delta_np]
            if record:
                pushed = recorder.push(
                    handle,
                    x,
                    direction,
                    f_np,
                    _f32(np.where(scatter, q, 1.0)),
                    normals=n_sh,
                    bsdf_pdfs=bsdf_pdf_np,
                    guide_pdfs=_f32(guide_pdf_d),
                    active=scatter,
                    **paths_kw,
                )
                pushed_delta = recorder.push_delta(
                    handle, x, _soa(bs_weight), active=delta_np, **paths_kw
                )
                handle = np.where(delta_np, pushed_delta, pushed)
            throughput = throughput * weight
            alive = (scatter | delta_np) & (throughput.max(axis=1) > 0.0)
            rays += np.bincount(path, weights=alive, minlength=n_paths).astype(np.int64)
            if record:
                recorder.add_cost(handle, np.ones(lanes, np.float32), active=alive, **paths_kw)
            # Classic roulette, where no factor decided.
            if depth + 1 >= self.rr_depth:
                plays = alive & classic
                p = np.minimum(throughput.max(axis=1), 0.95)
                survived = rng.random(lanes) < p
                if record:
                    recorder.roulette(
                        handle, _f32(np.maximum(p, 1e-30)), survived, active=plays, **paths_kw
                    )
                throughput[plays & survived] /= p[plays & survived, None]
                alive &= ~plays | survived
            keep = np.nonzero(alive)[0]
            si = dr.gather(type(si), si, _opaque(mi.UInt32(keep.astype(np.uint32))))
            ray = si.spawn_ray(_vec(direction[keep]))
            path, handle, throughput = path[keep], handle[keep], throughput[keep]
            prev_si = si
            prev_q = _opaque(mi.Float(_f32(np.where(scatter, q, 0.0)[keep])))
            prev_delta = _opaque(mi.Bool(delta_np[keep]))
        recorded = None
        if record:
            recorded = recorder.finish()
            recorder.record(field)
        if estimates:
            return radiance, rays, recorded
        return radiance, rays


def _luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def _point2(rng, n):
    return _opaque(mi.Point2f(np.ascontiguousarray(rng.random((2, n), dtype=np.float32))))


def _accumulate(total: np.ndarray, path: np.ndarray, values: np.ndarray) -> None:
    """Adds each lane's RGB `values` to its path's row of `total`."""
    for c in range(3):
        total[:, c] += np.bincount(path, weights=values[:, c], minlength=len(total))


def register(name: str = "sdguide"):
    """Registers the guided tracer as the Mitsuba integrator plugin ``name``: its properties
    are ``max_depth``, ``rr_depth``, ``guided``, ``roulette``, ``training_passes`` and ``rule``
    (:class:`GuidedPathTracer`); ``mi.render`` then trains and renders with the spp it is
    given. Needs a variant set."""

    class SdguideIntegrator(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            get = (
                props.get if hasattr(props, "get") else (lambda k, d: props[k] if k in props else d)
            )
            config = {}
            if "rule" in props:
                config["rule"] = props["rule"]
            self.tracer = GuidedPathTracer(
                max_depth=int(get("max_depth", 8)),
                rr_depth=int(get("rr_depth", 5)),
                guided=bool(get("guided", True)),
                roulette=str(get("roulette", "classic")),
                training_passes=int(get("training_passes", 5)),
                **config,
            )
            self.field = None

        def render(self, scene, sensor=None, seed=0, spp=0, develop=True, evaluate=True):
            if sensor is None or isinstance(sensor, int):
                sensor = scene.sensors()[sensor or 0]
            spp = spp or sensor.sampler().sample_count()
            image, self.field, _ = self.tracer.render(scene, spp, seed=seed, sensor=sensor)
            return mi.TensorXf(image)

        def to_string(self):
            return f"SdguideIntegrator[max_depth={self.tracer.max_depth}]"

    mi.register_integrator(name, lambda props: SdguideIntegrator(props))


def relative_mse(image: np.ndarray, reference: np.ndarray, eps: float = 1e-2) -> float:
    """Mean over pixels and channels of ``(image − reference)² / (reference² + eps)``."""
    return float(np.mean((image - reference) ** 2 / (reference**2 + eps)))


__all__ = [
    "GuidedPathTracer",
    "PassSums",
    "RenderInfo",
    "register",
    "relative_mse",
    "set_variant",
    "MAX_LANES",
]
