//! Criterion benchmarks of the three hot operations on the standard workload.
//!
//! The workload (see `sdguide_lab::synthetic`): the unit room, points on three walls and a sphere,
//! light from two vMF lobes (κ = 800 and κ = 60) plus a small ambient term; trained 6 iterations
//! with doubling budgets from 1M samples, directions drawn ½ uniform, ½ from the learned
//! distribution. Set `SDGUIDE_BENCH_BUDGET` to train on a smaller first budget.
//!
//! Single-thread figures run inside a one-thread rayon pool; `record/2-threads` records the same
//! batch split over two OS threads.
//!
//! `baseline/*` measure, in the same run, what the figures should be read against on a noisy
//! machine: uniform sphere sampling (the trivial guide: one `sin_cos`), and the C library's
//! `atan2f` (a fixed amount of floating-point work, to compare machines).

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use glam::{Vec2, Vec3};
use sdguide::{
    Continuation, DirectionalFilter, GuidingConfig, GuidingField, LeafRule, PathRecorder,
    PathVertex, Refinement, Sample, SpatialFilter, SpatialSplit,
};
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{LightField, Workload, room_bounds, room_point, room_vertex};
use std::hint::black_box;
use std::sync::OnceLock;

const BATCH: usize = 1 << 16;

fn workload() -> Workload {
    Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 2024,
        bsdf: None,
    }
}

/// The field trained on the standard workload with the default configuration, shared by all
/// benchmarks (trained once).
fn trained() -> &'static GuidingField {
    static FIELD: OnceLock<GuidingField> = OnceLock::new();
    FIELD.get_or_init(|| trained_with(GuidingConfig::default()))
}

/// A field trained on the standard workload with `config`.
fn trained_with(config: GuidingConfig) -> GuidingField {
    let first = std::env::var("SDGUIDE_BENCH_BUDGET")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let mut field = GuidingField::new(room_bounds(), config).unwrap();
    workload().train(&mut field, 6, first);
    eprintln!("trained field: {:?}", field.stats());
    field
}

/// A batch of samples as the workload's renderer would record them.
fn samples(field: &GuidingField) -> Vec<Sample> {
    let w = workload();
    let mut rng = Rng::new(7);
    (0..BATCH).map(|_| w.draw(field, &mut rng)).collect()
}

fn one_thread<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(f)
}

fn bench_record(c: &mut Criterion) {
    let field = trained().clone();
    let batch = samples(&field);
    let mut g = c.benchmark_group("record");
    g.throughput(Throughput::Elements(BATCH as u64));
    g.bench_function("1-thread", |b| {
        b.iter(|| field.record_all(black_box(&batch)))
    });
    // The filters, the refinement criterion and the mixture terms, each on a field trained with
    // that configuration (the default is the directional box filter, refined by variance gain).
    let gain = Refinement::VarianceGain;
    for (name, spatial, directional, refinement) in [
        (
            "1-thread, no filter",
            SpatialFilter::Nearest,
            DirectionalFilter::Nearest,
            gain,
        ),
        (
            "1-thread, deferred box",
            SpatialFilter::Nearest,
            DirectionalFilter::DeferredBox,
            gain,
        ),
        (
            "1-thread, stochastic spatial",
            SpatialFilter::Stochastic,
            DirectionalFilter::Box,
            gain,
        ),
        (
            "1-thread, box spatial",
            SpatialFilter::Box,
            DirectionalFilter::Box,
            gain,
        ),
        (
            "1-thread, refined by flux share",
            SpatialFilter::Nearest,
            DirectionalFilter::Box,
            Refinement::FluxShare,
        ),
    ] {
        let variant = trained_with(GuidingConfig {
            spatial_filter: spatial,
            directional_filter: directional,
            refinement,
            ..GuidingConfig::default()
        });
        let batch = samples(&variant);
        g.bench_function(name, |b| b.iter(|| variant.record_all(black_box(&batch))));
    }
    // Spatial splits by gain: the split signature besides the default's sums.
    let by_gain = trained_with(GuidingConfig {
        spatial_split: SpatialSplit::Gain,
        ..GuidingConfig::default()
    });
    let gain_batch = samples(&by_gain);
    g.bench_function("1-thread, spatial splits by gain", |b| {
        b.iter(|| by_gain.record_all(black_box(&gain_batch)))
    });
    let with_mixture: Vec<Sample> = batch
        .iter()
        .map(|s| s.with_mixture(s.value * 0.3, 0.3, s.pdf))
        .collect();
    g.bench_function("1-thread, with mixture terms", |b| {
        b.iter(|| field.record_all(black_box(&with_mixture)))
    });
    // What a renderer with roulette and splitting adds per vertex: one continuation.
    let continuations: Vec<Continuation> = batch
        .iter()
        .map(|s| Continuation {
            position: s.position,
            value: s.value * 0.3,
            cost: 4.0,
        })
        .collect();
    g.bench_function("1-thread, continuation", |b| {
        b.iter(|| {
            for c in black_box(&continuations) {
                field.record_continuation(c);
            }
        })
    });
    // The same vertices through the path recorder, as 8-vertex paths with mixture terms and
    // their continuations: what a renderer's record costs with the recorder's bookkeeping,
    // against "with mixture terms" plus "continuation" above.
    let mut path = PathRecorder::new();
    g.bench_function("1-thread, path recorder, 8-vertex paths", |b| {
        b.iter(|| {
            for chunk in black_box(&batch).chunks(8) {
                let mut v = path.start();
                for s in chunk {
                    let vertex = PathVertex::new(s.position, s.direction, Vec3::splat(0.3), s.pdf)
                        .with_mixture(0.3, s.pdf);
                    v = path.push(v, vertex);
                    path.add_radiance(v, Vec3::splat(s.value));
                    path.add_cost(v, 2.0);
                }
                path.finish();
                path.record(&field);
            }
        })
    });
    // The mixture rule looks up the guide's own pdf of each sample's direction (its field
    // trains as L2's: the workload records no mixture terms).
    let mixture_rule = trained_with(GuidingConfig {
        rule: LeafRule::L2Mixture,
        ..GuidingConfig::default()
    });
    g.bench_function("1-thread, with mixture terms, rule L2Mixture", |b| {
        b.iter(|| mixture_rule.record_all(black_box(&with_mixture)))
    });
    g.bench_function("2-threads", |b| {
        b.iter(|| {
            std::thread::scope(|s| {
                for half in batch.chunks(BATCH / 2) {
                    let field = &field;
                    s.spawn(move || field.record_all(black_box(half)));
                }
            })
        })
    });
    g.finish();
}

fn bench_query(c: &mut Criterion) {
    let field = trained();
    let mut rng = Rng::new(11);
    let queries: Vec<(Vec3, Vec2, Vec3)> = (0..BATCH)
        .map(|_| {
            let x = room_point([rng.next_f32(), rng.next_f32(), rng.next_f32()]);
            let other = sdguide::sphere::square_to_direction(rng.next_vec2());
            (x, rng.next_vec2(), other)
        })
        .collect();
    let mut g = c.benchmark_group("query");
    g.throughput(Throughput::Elements(BATCH as u64));
    // What a renderer does at a vertex: find the distribution, sample it, and evaluate the pdf
    // of another direction (the BSDF's, for MIS).
    g.bench_function("distribution+sample+pdf", |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for &(x, u, other) in &queries {
                let dist = field.distribution(black_box(x));
                let (d, p) = dist.sample(black_box(u));
                acc += p + d.x + dist.pdf(black_box(other));
            }
            acc
        })
    });
    // The same at a surface: the product with the clamped cosine about a normal (a random
    // one per query; the other direction may lie on either side).
    let normals: Vec<Vec3> = (0..BATCH)
        .map(|_| sdguide::sphere::square_to_direction(rng.next_vec2()))
        .collect();
    g.bench_function("distribution+at_surface+sample+pdf", |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for (&(x, u, other), &n) in queries.iter().zip(&normals) {
                let dist = field.distribution(black_box(x)).at_surface(black_box(n));
                let (d, p) = dist.sample(black_box(u));
                acc += p + d.x + dist.pdf(black_box(other));
            }
            acc
        })
    });
    // The same in a medium: the product with a Henyey–Greenstein phase function about a
    // random direction of travel, over the same trained trees (a volume guide's trees are the
    // same kind). A moderate and a strongly forward-scattering medium: the narrower the lobe,
    // the deeper the product descends.
    for g_value in [0.3f32, 0.9] {
        g.bench_function(
            format!("distribution+with_phase+sample+pdf, g={g_value}"),
            |b| {
                b.iter(|| {
                    let mut acc = 0.0f32;
                    for (&(x, u, other), &travel) in queries.iter().zip(&normals) {
                        let dist = field
                            .distribution(black_box(x))
                            .with_phase(black_box(travel), black_box(g_value));
                        let (d, p) = dist.sample(black_box(u));
                        acc += p + d.x + dist.pdf(black_box(other));
                    }
                    acc
                })
            },
        );
    }
    // The same at the room's walls and floor, whose normals the field stored products for
    // (recorded with the workload's samples); the sphere's points take the per-query product.
    let vertices: Vec<(Vec3, Vec3)> = (0..BATCH)
        .map(|_| room_vertex([rng.next_f32(), rng.next_f32(), rng.next_f32()]))
        .collect();
    g.bench_function(
        "distribution+at_surface+sample+pdf, recorded normals",
        |b| {
            b.iter(|| {
                let mut acc = 0.0f32;
                for (&(_, u, other), &(x, n)) in queries.iter().zip(&vertices) {
                    let dist = field.distribution(black_box(x)).at_surface(black_box(n));
                    let (d, p) = dist.sample(black_box(u));
                    acc += p + d.x + dist.pdf(black_box(other));
                }
                acc
            })
        },
    );
    g.bench_function("distribution", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(x, _, _)| field.distribution(black_box(x)).pdf(Vec3::Z))
                .sum::<f32>()
        })
    });
    let dist = field.distribution(Vec3::new(0.5, 0.0, 0.5));
    g.bench_function("sample", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(_, u, _)| dist.sample(black_box(u)).1)
                .sum::<f32>()
        })
    });
    g.bench_function("pdf", |b| {
        b.iter(|| {
            queries
                .iter()
                .map(|&(_, _, d)| dist.pdf(black_box(d)))
                .sum::<f32>()
        })
    });
    g.finish();
}

fn bench_baseline(c: &mut Criterion) {
    let mut rng = Rng::new(13);
    let us: Vec<Vec2> = (0..BATCH).map(|_| rng.next_vec2()).collect();
    let mut g = c.benchmark_group("baseline");
    g.throughput(Throughput::Elements(BATCH as u64));
    g.bench_function("uniform-sample+pdf", |b| {
        b.iter(|| {
            us.iter()
                .map(|&u| {
                    sdguide::sphere::square_to_direction(black_box(u)).x
                        + sdguide::sphere::INV_SPHERE_AREA
                })
                .sum::<f32>()
        })
    });
    g.bench_function("libm-atan2f", |b| {
        b.iter(|| {
            us.iter()
                .map(|&u| black_box(u.y).atan2(black_box(u.x)))
                .sum::<f32>()
        })
    });
    g.finish();
}

fn bench_refine(c: &mut Criterion) {
    let mut g = c.benchmark_group("refine");
    g.sample_size(20);
    let flux = GuidingConfig {
        refinement: Refinement::FluxShare,
        ..GuidingConfig::default()
    };
    let deferred = GuidingConfig {
        directional_filter: DirectionalFilter::DeferredBox,
        ..GuidingConfig::default()
    };
    for (criterion, field) in [
        ("", trained().clone()),
        (", flux share", trained_with(flux)),
        (", deferred box", trained_with(deferred)),
    ] {
        // One iteration's worth of samples at the trained state, then refine a fresh copy each
        // time (under the deferred box filter the samples' sums are still pending: refine
        // spreads them).
        let w = workload();
        let k = field.iteration();
        w.record_iteration(&field, k, 1_000_000);
        let leaves = field.stats().spatial_leaves;
        g.bench_function(format!("{leaves}-leaves/1-thread{criterion}"), |b| {
            b.iter_batched(
                || field.clone(),
                |mut f| one_thread(move || f.refine()),
                BatchSize::LargeInput,
            )
        });
        g.bench_function(format!("{leaves}-leaves/2-threads{criterion}"), |b| {
            b.iter_batched(|| field.clone(), |mut f| f.refine(), BatchSize::LargeInput)
        });
    }
    g.finish();
}

criterion_group!(
    benches,
    bench_baseline,
    bench_record,
    bench_query,
    bench_refine
);
criterion_main!(benches);
