//! Train guiding fields on synthetic light and compare estimator variance.
//!
//! For each light field — the standard one (a sharp κ = 800 lobe, a broad κ = 60 lobe, ambient)
//! with exact values, and the same with heavy-tailed noise on the lobes (E[ξ²] = 10) — two
//! fields are trained with the same workload, one per leaf rule. Then, at held-out points, the
//! relative variance Var[v/p]/μ² of the one-sample estimator is measured for uniform sphere
//! sampling and for sampling each learned distribution. The table gives the median over the
//! points and the mean, which a few bad points can dominate (see the README's quality section).
//!
//! Each trained field is saved as a cache in `out/` (`synthetic-standard-l2.sdgc`, ...), for
//! `examples/inspect.rs` to look at.
//!
//! ```text
//! cargo run --release --example synthetic [-- --iterations 6 --budget 500000 --points 48 --samples 100000]
//! ```

use glam::Vec3;
use sdguide::sphere::{INV_SPHERE_AREA, square_to_direction};
use sdguide::synthetic::{LightField, Rng, Workload, room_bounds, room_point};
use sdguide::{GuidingConfig, GuidingField, LeafRule};
use std::time::Instant;

struct Args {
    iterations: u32,
    budget: u64,
    points: usize,
    samples: u64,
}

fn args() -> Args {
    let mut a = Args {
        iterations: 6,
        budget: 500_000,
        points: 48,
        samples: 100_000,
    };
    let argv: Vec<String> = std::env::args().skip(1).collect();
    for pair in argv.chunks(2) {
        let value = pair.get(1).and_then(|v| v.parse::<u64>().ok());
        match (pair[0].as_str(), value) {
            ("--iterations", Some(v)) => a.iterations = v as u32,
            ("--budget", Some(v)) => a.budget = v,
            ("--points", Some(v)) => a.points = v as usize,
            ("--samples", Some(v)) => a.samples = v,
            _ => {
                eprintln!(
                    "usage: synthetic [--iterations N] [--budget N] [--points N] [--samples N]"
                );
                std::process::exit(2);
            }
        }
    }
    a
}

fn main() {
    let args = args();
    println!(
        "sdguide synthetic: {} iterations, budgets {}·2^k samples (½ uniform, ½ guided), {} held-out points × {} samples\n",
        args.iterations, args.budget, args.points, args.samples
    );
    println!(
        "| light field | sampling | training | spatial leaves | directional leaves | relvar median | relvar mean |"
    );
    println!("|---|---|---|---|---|---|---|");
    std::fs::create_dir_all("out").expect("can create out/");
    for (name, tag, lobe_noise) in [
        ("standard", "standard", 1.0),
        ("standard, noisy lobes (E[ξ²] = 10)", "noisy", 10.0),
    ] {
        let workload = Workload {
            light: LightField::standard(),
            lobe_noise,
            seed: 1,
            bsdf: None,
        };
        // Held-out points: inside the room, off the surfaces the workload trains on.
        let mut rng = Rng::new(99);
        let points: Vec<Vec3> = (0..args.points)
            .map(|_| {
                room_point([rng.next_f32(), rng.next_f32(), rng.next_f32()]) * 0.96
                    + Vec3::splat(0.02)
            })
            .collect();
        let uniform = relvars(&workload, &points, args.samples, |_| None);
        println!(
            "| {name} | uniform | | | | {:.3} | {:.3} |",
            uniform.median, uniform.mean
        );
        let mut guided = Vec::new();
        for rule in [LeafRule::L1, LeafRule::L2] {
            let mut field = GuidingField::new(
                room_bounds(),
                GuidingConfig {
                    rule,
                    ..Default::default()
                },
            )
            .expect("the default configuration is valid");
            let start = Instant::now();
            workload.train(&mut field, args.iterations, args.budget);
            let trained_in = start.elapsed();
            let cache = format!(
                "out/synthetic-{tag}-{}.sdgc",
                format!("{rule:?}").to_lowercase()
            );
            field.save_to_path(&cache).expect("can write the cache");
            let relvar = relvars(&workload, &points, args.samples, |x| {
                Some(field.distribution(x))
            });
            let stats = field.stats();
            println!(
                "| {name} | guided, {rule:?} | {:.1} s | {} | {} | {:.3} | {:.3} |",
                trained_in.as_secs_f64(),
                stats.spatial_leaves,
                stats.directional_leaves,
                relvar.median,
                relvar.mean,
            );
            guided.push(relvar);
        }
        println!(
            "| {name} | ratio L2 / L1 | | | | {:.3} | {:.3} |",
            guided[1].median / guided[0].median,
            guided[1].mean / guided[0].mean
        );
    }
}

/// Median and mean of the relative variance over held-out points.
struct RelVar {
    median: f64,
    mean: f64,
}

/// Relative variance at each of `points`, sampling each point's distribution (or the uniform
/// sphere where `dist` gives none).
fn relvars<'a>(
    workload: &Workload,
    points: &[Vec3],
    samples: u64,
    dist: impl Fn(Vec3) -> Option<sdguide::DirectionalDistribution<'a>>,
) -> RelVar {
    let mut rng = Rng::new(7);
    let mut v: Vec<f64> = points
        .iter()
        .map(|&x| {
            let d = dist(x);
            workload
                .estimate(x, samples, &mut rng, |u| match &d {
                    Some(d) => d.sample(u),
                    None => (square_to_direction(u), INV_SPHERE_AREA),
                })
                .relative_variance
        })
        .collect();
    v.sort_by(f64::total_cmp);
    RelVar {
        median: v[v.len() / 2],
        mean: v.iter().sum::<f64>() / v.len() as f64,
    }
}
