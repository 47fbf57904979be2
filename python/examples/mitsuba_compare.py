"""Mitsuba 3 scenes rendered with Mitsuba's `path` and with the wavefront tracer
(`sdguide.mitsuba`), the guide off or on, with classic roulette or the library's
efficiency-aware roulette and splitting: relMSE per sample and at equal time, the images'
means against the reference's, images. Writes `report.md`, EXR and PNG images to `--out`.

    python examples/mitsuba_compare.py --out out/mitsuba            # the documented run
    python examples/mitsuba_compare.py --short --out out/mitsuba    # a minute or two, for CI

The reference is Mitsuba's `path` at `--reference-spp` (saved beside the report and reused).
"Per sample": every method's final image at `--spp` camera samples per pixel (those that learn
train first, on 1 + 2 + … + 2^(passes−1) spp more). "Equal time": every method gets `--time`
seconds, training included (passes double while the next would end within half the time),
its training passes' images combined with the final render's by inverse variance. Each is
repeated over `--seeds`."""

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
    """Mitsuba's path at `spp`, in 16 chunks: the image, the chunks' image means (their
    spread: the reference mean's error) and the reference's own relMSE, the part of every
    method's relMSE that is the reference's noise (`E[(I − R)²] = Var I + Var R`)."""
    path = os.path.join(out, f"{name}-reference.npz")
    if os.path.exists(path):
        data = np.load(path)
        if (
            int(data["spp"]) == spp
            and data["image"].shape[0] == scene.sensors()[0].film().crop_size()[1]
            and "own_relmse" in data
        ):
            return data["image"], data["chunk_means"], float(data["own_relmse"])
    chunks = []
    for i in range(16):
        chunks.append(
            np.array(mi.render(scene, spp=max(1, spp // 16), seed=10_000 + i), np.float64)
        )
    image = np.mean(chunks, axis=0)
    chunk_means = np.array([c.mean(axis=(0, 1)) for c in chunks])
    variance = np.var(chunks, axis=0, ddof=1) / len(chunks)
    own = float(np.mean(variance / (image**2 + 1e-2)))
    np.savez(path, image=image, chunk_means=chunk_means, spp=spp, own_relmse=own)
    return image, chunk_means, own


#: The methods compared: Mitsuba's own `path`, then the wavefront tracer's four settings.
METHODS = {
    "path": ("Mitsuba `path`", None),
    "off": ("guide off, classic roulette", {"guided": False}),
    "off-ears": ("guide off, EARS", {"guided": False, "roulette": "ears"}),
    "guided": ("guided, classic roulette", {"guided": True}),
    "guided-ears": ("guided, EARS", {"guided": True, "roulette": "ears"}),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="cornell,hidden,door,glossy")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--spp", type=int, default=32)
    parser.add_argument("--time", type=float, default=30.0, help="seconds per method")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--passes", type=int, default=6, help="training passes")
    parser.add_argument("--reference-spp", type=int, default=65536)
    parser.add_argument("--short", action="store_true", help="a quick run for CI")
    parser.add_argument("--out", default="out/mitsuba")
    args = parser.parse_args(argv)
    if args.short:
        args.size, args.spp, args.time, args.seeds = 32, 4, 3.0, 1
        args.passes, args.reference_spp = 3, 1024
    methods = args.methods.split(",")
    os.makedirs(args.out, exist_ok=True)
    set_variant("llvm_ad_rgb")
    import mitsuba as mi

    from sdguide import scenes

    lines = [
        "# sdguide in Mitsuba 3",
        "",
        f"Mitsuba {mi.__version__}, variant `{mi.variant()}`; {args.size}×{args.size} pixels, "
        f"seeds 1–{args.seeds}; reference: `path` at {args.reference_spp} spp. The wavefront "
        "tracer (`sdguide.mitsuba`) with the guide off or on, with classic roulette or the "
        "library's efficiency-aware roulette and splitting (EARS); those that learn train "
        f"{args.passes} passes first ({(1 << args.passes) - 1} spp; at equal time, passes "
        "double while the next would end within half the budget). Per sample: the final "
        f"render at {args.spp} camera samples per pixel (EARS traces more rays per sample: "
        f"compare it at equal time). Equal time: {args.time:g} s per method, training "
        "included, the training passes combined with the final render by inverse variance. "
        "relMSE: mean of (I − R)²/(R² + 0.01) over pixels and channels, mean ± "
        "standard deviation over seeds; ratios against the guide off with classic roulette.",
        "",
        "| scene | method | relMSE per sample | ratio | rays per sample | relMSE equal time "
        "| ratio | spp in the time | mean − reference (σ) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    verdicts = []
    for name in args.scenes.split(","):
        scene = mi.load_dict(scenes.build(name, args.size))
        max_depth = scenes.build(name, 8)["integrator"]["max_depth"]
        ref, ref_chunks, ref_noise = reference(mi, name, scene, args.reference_spp, args.out)
        ref_mean, ref_error = mean_and_error(ref_chunks)
        tracers = {
            key: GuidedPathTracer(max_depth=max_depth, training_passes=args.passes, **kw)
            for key, (_, kw) in METHODS.items()
            if kw is not None and key in methods
        }
        # Warm Dr.Jit's kernel cache, so that no method pays for compiling in the timed runs.
        for tracer in tracers.values():
            tracer.render(scene, 1, seed=999)
        render_path(mi, scene, 1, 999)
        results = {
            key: {"sample": [], "time": [], "spp": [], "bias": [], "rays": []} for key in methods
        }
        images = {}
        for seed in range(1, args.seeds + 1):
            for key in methods:
                r = results[key]
                if key == "path":
                    image, _, _ = render_path(mi, scene, args.spp, seed)
                    r["sample"].append(relative_mse(image, ref))
                    t = time.perf_counter()
                    render_path(mi, scene, 1, seed + 500)
                    chunk = max(1, int(0.5 / max(time.perf_counter() - t, 1e-4)))
                    image, _, spp = render_path(
                        mi, scene, None, seed, budget=args.time, chunk=chunk
                    )
                    r["time"].append(relative_mse(image, ref))
                    r["spp"].append(spp)
                    images.setdefault(key, image)
                    continue
                tracer = tracers[key]
                image, _, info = tracer.render(scene, args.spp, seed=seed, combine=False)
                r["sample"].append(relative_mse(image, ref))
                r["rays"].append(info.rays_per_sample)
                wave = max(2, args.spp // 4)
                image, _, timed = tracer.render(scene, wave, seed=seed + 1000, budget=args.time)
                r["time"].append(relative_mse(image, ref))
                r["spp"].append(timed.spp)
                images.setdefault(key, image)
                for run in (info, timed):
                    mean, error = run.image_mean()
                    z = (mean - ref_mean) / np.sqrt(error**2 + ref_error**2)
                    r["bias"].append(float(np.max(np.abs(z))))
        base = results.get("off") or results[methods[0]]
        base_sample, base_time = np.mean(base["sample"]), np.mean(base["time"])
        for key in methods:
            r = results[key]
            s, tm = np.array(r["sample"]), np.array(r["time"])
            bias = f"{max(r['bias']):.1f}" if r["bias"] else "—"
            rays = f"{np.mean(r['rays']):.2f}" if r["rays"] else "—"
            lines.append(
                f"| {name} | {METHODS[key][0]} | {s.mean():.4g} ± {s.std():.2g} "
                f"| {s.mean() / base_sample:.2f} | {rays} "
                f"| {tm.mean():.4g} ± {tm.std():.2g} | {tm.mean() / base_time:.2f} "
                f"| {np.mean(r['spp']):.0f} | {bias} |"
            )
            print(lines[-1], flush=True)
        if "guided-ears" in results and "off-ears" in results:
            best = np.mean(results["guided-ears"]["time"])
            verdicts.append(
                f"- **{name}**: guided with EARS at equal time {best / base_time:.2f}× the guide "
                f"off with classic roulette, {best / np.mean(results['off-ears']['time']):.2f}× "
                "the guide off with EARS"
                + (
                    f", {best / np.mean(results['path']['time']):.2f}× Mitsuba's `path`"
                    if "path" in results
                    else ""
                )
                + f" (the reference's own relMSE, {ref_noise:.2g}, is in every figure; less "
                f"it, {(best - ref_noise) / (base_time - ref_noise):.2f}× the guide off with "
                "classic roulette)."
            )
        strip = np.concatenate([ref] + [images[k] for k in methods], axis=1)
        mi.util.write_bitmap(
            os.path.join(args.out, f"{name}-compare.png"), strip.astype(np.float32)
        )
        if "guided-ears" in images:
            mi.util.write_bitmap(
                os.path.join(args.out, f"{name}-guided-ears.exr"),
                images["guided-ears"].astype(np.float32),
            )
    lines += [
        "",
        "The last column: the largest over channels, seeds and both renders of |mean of the "
        "image − mean of the reference| in standard errors (the image's from its pixels' sample "
        "variances, the reference's from its 16 chunks).",
        "",
        "**Verdict.**",
        *verdicts,
        "",
        "Images (`<scene>-compare.png`): the reference, then each method at equal time "
        f"({', '.join(methods)}), seed 1.",
    ]
    with open(os.path.join(args.out, "report.md"), "w") as report:
        report.write("\n".join(lines) + "\n")
    print("\n".join(verdicts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
