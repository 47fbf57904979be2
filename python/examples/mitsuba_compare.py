"""Mitsuba 3 scenes rendered with Mitsuba's `path`, the wavefront tracer with the guide off,
and the guided wavefront tracer: relMSE per sample and at equal time, bias against the
reference, images. Writes `report.md`, EXR and PNG images to `--out`.

    python examples/mitsuba_compare.py --out out/mitsuba            # the documented run
    python examples/mitsuba_compare.py --short --out out/mitsuba    # a minute, for CI

The reference is Mitsuba's `path` at `--reference-spp` (saved beside the report and reused).
"Per sample": every method's final image at `--spp` samples per pixel (the guided tracer
trains first, on 1 + 2 + … + 2^(passes−1) spp more, reported). "Equal time": every method gets
`--time` seconds, the guided tracer's training included. Each is repeated over `--seeds`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from sdguide.mitsuba import GuidedPathTracer, relative_mse, set_variant


def mean_and_error(means):
    m = np.asarray(means, np.float64)
    return m.mean(axis=0), m.std(axis=0, ddof=1) / np.sqrt(len(m))


def render_path(mi, scene, spp, seed, budget=None, chunk=None):
    """Mitsuba's path: one render of `spp`, or chunks of `chunk` spp until `budget` seconds."""
    start = time.perf_counter()
    if budget is None:
        image = np.array(mi.render(scene, spp=spp, seed=seed), np.float64)
        return image, time.perf_counter() - start, spp
    total, done = None, 0
    while True:
        image = np.array(mi.render(scene, spp=chunk, seed=seed * 100_003 + done), np.float64)
        total = image if total is None else total + image
        done += 1
        elapsed = time.perf_counter() - start
        if elapsed + 0.5 * elapsed / done > budget:
            break
    return total / done, time.perf_counter() - start, done * chunk


def reference(mi, name, scene, spp, out):
    """Mitsuba's path at `spp`, in 16 chunks (their spread: the reference mean's error)."""
    path = os.path.join(out, f"{name}-reference.npz")
    if os.path.exists(path):
        data = np.load(path)
        if (
            int(data["spp"]) == spp
            and data["image"].shape[0] == scene.sensors()[0].film().crop_size()[1]
        ):
            return data["image"], data["chunk_means"]
    chunks = [
        np.array(mi.render(scene, spp=max(1, spp // 16), seed=10_000 + i), np.float64)
        for i in range(16)
    ]
    image = np.mean(chunks, axis=0)
    chunk_means = np.array([c.mean(axis=(0, 1)) for c in chunks])
    np.savez(path, image=image, chunk_means=chunk_means, spp=spp)
    return image, chunk_means


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="cornell,hidden,door,glossy")
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--time", type=float, default=30.0, help="seconds per method")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--passes", type=int, default=6, help="training passes")
    parser.add_argument("--reference-spp", type=int, default=16384)
    parser.add_argument("--short", action="store_true", help="a quick run for CI")
    parser.add_argument("--out", default="out/mitsuba")
    args = parser.parse_args(argv)
    if args.short:
        args.size, args.spp, args.time, args.seeds = 32, 4, 3.0, 1
        args.passes, args.reference_spp = 3, 1024
    os.makedirs(args.out, exist_ok=True)
    set_variant("llvm_ad_rgb")
    import mitsuba as mi

    from sdguide import scenes

    lines = [
        "# sdguide in Mitsuba 3",
        "",
        f"Mitsuba {mi.__version__}, variant `{mi.variant()}`; {args.size}×{args.size} pixels, "
        f"{args.seeds} seed(s); reference: `path` at {args.reference_spp} spp. Per sample: "
        f"{args.spp} spp (the guided tracer trains {args.passes} passes first: "
        f"{(1 << args.passes) - 1} spp). Equal time: {args.time:g} s per method, training "
        "included. relMSE: mean of (I − R)²/(R² + 0.01) over pixels and channels; ratios are "
        "against the wavefront tracer with the guide off (same tracer, same roulette).",
        "",
        "| scene | method | relMSE per sample | ratio | relMSE equal time | ratio "
        "| spp in the time | seconds | mean − reference (σ) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    verdicts = []
    for name in args.scenes.split(","):
        scene = mi.load_dict(scenes.build(name, args.size))
        max_depth = scenes.build(name, 8)["integrator"]["max_depth"]
        ref, ref_chunks = reference(mi, name, scene, args.reference_spp, args.out)
        ref_mean, ref_error = mean_and_error(ref_chunks)
        off = GuidedPathTracer(max_depth=max_depth, guided=False)
        on = GuidedPathTracer(max_depth=max_depth, guided=True, training_passes=args.passes)
        # Warm Dr.Jit's kernel cache, so that no method pays for compiling in the timed runs.
        off.render(scene, 1, seed=999)
        on.render(scene, 1, seed=999)
        render_path(mi, scene, 1, 999)
        results = {
            m: {"sample": [], "time": [], "spp": [], "seconds": [], "bias": []}
            for m in ("path", "off", "on")
        }
        images = {}
        for seed in range(1, args.seeds + 1):
            image, _, _ = render_path(mi, scene, args.spp, seed)
            results["path"]["sample"].append(relative_mse(image, ref))
            t = time.perf_counter()
            render_path(mi, scene, 1, seed + 500)
            chunk = max(1, int(0.5 / max(time.perf_counter() - t, 1e-4)))
            image, seconds, spp = render_path(mi, scene, None, seed, budget=args.time, chunk=chunk)
            results["path"]["time"].append(relative_mse(image, ref))
            results["path"]["spp"].append(spp)
            results["path"]["seconds"].append(seconds)
            images.setdefault("path", image)
            for key, tracer in (("off", off), ("on", on)):
                image, _, info = tracer.render(scene, args.spp, seed=seed, waves=4)
                results[key]["sample"].append(relative_mse(image, ref))
                mean, error = mean_and_error(info.wave_means)
                z = (mean - ref_mean) / np.sqrt(error**2 + ref_error**2)
                results[key]["bias"].append(float(np.max(np.abs(z))))
                wave = max(1, args.spp // 4)
                image, _, info = tracer.render(scene, wave, seed=seed + 1000, budget=args.time)
                results[key]["time"].append(relative_mse(image, ref))
                results[key]["spp"].append(wave * len(info.wave_means))
                results[key]["seconds"].append(info.seconds)
                images.setdefault(key, image)
        base_sample = np.mean(results["off"]["sample"])
        base_time = np.mean(results["off"]["time"])
        labels = {"path": "Mitsuba `path`", "off": "wavefront, guide off", "on": "sdguide guided"}
        for key in ("path", "off", "on"):
            r = results[key]
            s, tm = np.array(r["sample"]), np.array(r["time"])
            bias = f"{max(r['bias']):.1f}" if r["bias"] else "—"
            lines.append(
                f"| {name} | {labels[key]} | {s.mean():.4g} ± {s.std():.2g} "
                f"| {s.mean() / base_sample:.2f} "
                f"| {tm.mean():.4g} ± {tm.std():.2g} | {tm.mean() / base_time:.2f} "
                f"| {np.mean(r['spp']):.0f} | {np.mean(r['seconds']):.1f} | {bias} |"
            )
        on_time = np.mean(results["on"]["time"])
        verdicts.append(
            f"- **{name}**: guided at equal time {on_time / base_time:.2f}× the guide off, "
            f"{on_time / np.mean(results['path']['time']):.2f}× Mitsuba's `path`; "
            f"per sample {np.mean(results['on']['sample']) / base_sample:.2f}×."
        )
        strip = np.concatenate([ref, images["path"], images["off"], images["on"]], axis=1)
        mi.util.write_bitmap(
            os.path.join(args.out, f"{name}-compare.png"), strip.astype(np.float32)
        )
        mi.util.write_bitmap(
            os.path.join(args.out, f"{name}-guided.exr"), images["on"].astype(np.float32)
        )
        print(lines[-3], lines[-2], lines[-1], sep="\n", flush=True)
    lines += [
        "",
        "The last column: the largest over channels of |mean of the image − mean of the reference| "
        "in standard errors (of four waves, and of the reference's 16 chunks).",
        "",
        "**Verdict.**",
        *verdicts,
        "",
        "Images (`<scene>-compare.png`): reference, `path`, guide off, guided — equal time, "
        "seed 1.",
    ]
    with open(os.path.join(args.out, "report.md"), "w") as report:
        report.write("\n".join(lines) + "\n")
    print("\n".join(verdicts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
