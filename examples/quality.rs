//! The quality harness's table and plot: relative variance of uniform sampling, of fields
//! trained with the `L1` and `L2` rules, and of the oracle (the best piecewise-constant density
//! on the learned partition), on every light field of `sdguide::quality`, against the training
//! budget.
//!
//! ```text
//! cargo run --release --example quality [-- --iterations 5 --budget 250000 --plot docs/quality.png]
//! ```

use sdguide::quality::{self, Budget, Holdout, Report, TestField};
use sdguide::{GuidingConfig, GuidingField, LeafRule};

#[path = "common/plot.rs"]
mod plot;

struct Args {
    iterations: u32,
    budget: u64,
    plot: String,
}

fn args() -> Args {
    let mut a = Args {
        iterations: 5,
        budget: 250_000,
        plot: "out/quality.png".into(),
    };
    let argv: Vec<String> = std::env::args().skip(1).collect();
    for pair in argv.chunks(2) {
        match (pair[0].as_str(), pair.get(1)) {
            ("--iterations", Some(v)) if v.parse::<u32>().is_ok() => {
                a.iterations = v.parse().unwrap()
            }
            ("--budget", Some(v)) if v.parse::<u64>().is_ok() => a.budget = v.parse().unwrap(),
            ("--plot", Some(v)) => a.plot = v.clone(),
            _ => {
                eprintln!("usage: quality [--iterations N] [--budget N] [--plot FILE.png]");
                std::process::exit(2);
            }
        }
    }
    a
}

/// Trains a field with `rule` on `field`'s workload and reports after every iteration.
fn train(field: &TestField, rule: LeafRule, args: &Args) -> Vec<(u64, Report)> {
    let config = GuidingConfig {
        rule,
        uniform_fraction: std::env::var("SDG_E")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.01),
        spatial_threshold: std::env::var("SDG_C")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(12000.0),
        ..GuidingConfig::default()
    };
    let budget = Budget {
        iterations: args.iterations,
        first: args.budget,
    };
    let holdout = Holdout {
        positions: std::env::var("SDG_P")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(12),
        ..Holdout::default()
    };
    quality::train(field, config, budget, holdout)
        .expect("valid configuration")
        .1
}

fn main() {
    let args = args();
    println!(
        "sdguide quality: {} iterations, budgets {}·2^k samples (½ uniform, ½ guided); relvar averaged over {} held-out cells × {} positions\n",
        args.iterations,
        args.budget,
        Holdout::default().cells,
        Holdout::default().positions
    );
    println!(
        "| light field | uniform | L1 | L2 | oracle (L2 partition) | L2 / L1 | L2 / oracle | spatial leaves | directional leaves |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut panels = Vec::new();
    for field in TestField::all() {
        let l1 = train(&field, LeafRule::L1, &args);
        let l2 = train(&field, LeafRule::L2, &args);
        let (a, b) = (l1.last().unwrap().1, l2.last().unwrap().1);
        println!(
            "| {} | {:.3} | {:.4} | {:.4} | {:.4} | {:.3} | {:.3} | {} | {:.0} |",
            field.name,
            b.variances.uniform,
            a.variances.learned,
            b.variances.learned,
            b.variances.oracle,
            b.variances.learned / a.variances.learned,
            b.variances.learned / b.variances.oracle,
            b.spatial_leaves,
            b.directional_leaves,
        );
        let series = |r: &[(u64, Report)], f: fn(&Report) -> f64| -> Vec<(f64, f64)> {
            r.iter().map(|(n, r)| (*n as f64, f(r))).collect()
        };
        panels.push(plot::Panel {
            title: field.name.to_string(),
            series: vec![
                ("L1", series(&l1, |r| r.variances.learned)),
                ("L2", series(&l2, |r| r.variances.learned)),
                ("oracle", series(&l2, |r| r.variances.oracle)),
            ],
        });
    }
    if let Some(dir) = std::path::Path::new(&args.plot).parent() {
        std::fs::create_dir_all(dir).expect("can create the plot's directory");
    }
    plot::write_png(&args.plot, &panels).expect("can write the plot");
    println!("\nplot: {}", args.plot);
}
