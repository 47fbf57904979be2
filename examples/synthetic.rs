//! Train guiding fields on synthetic light and compare estimator variance.
//!
//! For each light field — the standard one (a sharp κ = 800 lobe, a broad κ = 60 lobe, ambient)
//! with exact values, and the same with heavy-tailed noise on the lobes (E[ξ²] = 10) — two
//! fields are trained with the same workload, one per leaf rule. Then, at held-out points, the
//! relative variance Var[v/p]/μ² of the one-sample estimator is measured for uniform sphere
//! sampling and for sampling each learned distribution. The table gives the median over the
//! points and the mean, which a few bad points can dominate (see the README's quality section).
//! A second table compares the two rules point by point: the ratio of the two medians above
//! compares the middle of two distributions, not the same points.
//!
//! Each trained field is saved as a cache in `out/` (`synthetic-standard-l2.sdgc`, ...), for
//! `examples/inspect.rs` to look at.
//!
//! ```text
//! cargo run --release --example synthetic [-- --iterations 6 --budget 500000 --points 48 --samples 100000]
//! ```

use glam::Vec3;
use sdguide::sphere::{INV_SPHERE_AREA, square_to_direction};
use sdguide::{GuidingConfig, GuidingField, LeafRule};
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{LightField, Workload, room_bounds, room_point};
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
    let mut per_point = Vec::new();
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
        per_point.push((name, PointByPoint::new(&guided[0].all, &guided[1].all)));
    }
    println!(
        "\nL2 / L1 at each point (halves: the points sorted by the geometric mean of both rules' relvar):\n"
    );
    println!(
        "| light field | median | geometric mean | points where L2 is lower | median, easier half | median, harder half |"
    );
    println!("|---|---|---|---|---|---|");
    for (name, p) in per_point {
        println!(
            "| {name} | {:.3} | {:.3} | {} of {} | {:.3} | {:.3} |",
            p.median, p.geometric_mean, p.l2_lower, args.points, p.easy_half, p.hard_half
        );
    }
}

/// Median and mean of the relative variance over held-out points, and its value at each.
struct RelVar {
    all: Vec<f64>,
    median: f64,
    mean: f64,
}

/// L2's relative variance over L1's at the same points.
struct PointByPoint {
    /// Median of the per-point ratios.
    median: f64,
    /// Geometric mean of the per-point ratios.
    geometric_mean: f64,
    /// Points where L2's relative variance is lower.
    l2_lower: usize,
    /// Median ratio over the easier half of the points, and over the harder half. A point's
    /// difficulty is the geometric mean of the two rules' relvar there: sorting by one rule's
    /// estimate alone would put the points where its Monte Carlo estimate came out low in the
    /// easier half, and bias the ratio there.
    easy_half: f64,
    hard_half: f64,
}

impl PointByPoint {
    fn new(l1: &[f64], l2: &[f64]) -> Self {
        let ratios: Vec<f64> = l1.iter().zip(l2).map(|(a, b)| b / a).collect();
        let mut by_difficulty: Vec<(f64, f64)> = l1
            .iter()
            .zip(l2)
            .zip(&ratios)
            .map(|((a, b), &r)| ((a * b).sqrt(), r))
            .collect();
        by_difficulty.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (easy, hard) = by_difficulty.split_at(by_difficulty.len() / 2);
        let log_sum: f64 = ratios.iter().map(|r| r.ln()).sum();
        PointByPoint {
            median: median(ratios.clone()),
            geometric_mean: (log_sum / ratios.len() as f64).exp(),
            l2_lower: ratios.iter().filter(|&&r| r < 1.0).count(),
            easy_half: median(easy.iter().map(|p| p.1).collect()),
            hard_half: median(hard.iter().map(|p| p.1).collect()),
        }
    }
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
    let all: Vec<f64> = points
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
    RelVar {
        median: median(all.clone()),
        mean: all.iter().sum::<f64>() / all.len() as f64,
        all,
    }
}

/// The middle value (the upper one of an even count); NaN for none (an empty half of a run
/// with one point).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}
