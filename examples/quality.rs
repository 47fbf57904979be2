//! The quality harness's tables and plot (see `sdguide_lab::quality` and `docs/quality.md`).
//!
//! 1. Relative variance of uniform sampling, of fields trained with the `L1` and `L2` rules, and
//!    of the oracle (the best piecewise-constant density on the learned partition), on every
//!    light field of the harness and the held-out sun and sky; a PNG plot of relvar against the
//!    training budget.
//! 2. Refinement: flux share against variance gain, at equal node counts (a node budget per
//!    directional tree that both reach) and at the default thresholds.
//! 3. The filters' effect on relvar.
//! 4. The guide-vs-BSDF mixture: relvar with the fixed selection probability ½, with the learned
//!    one, and with the best one (brute force).
//!
//! ```text
//! cargo run --release --example quality [-- --iterations 5 --budget 250000 --plot out/quality.png]
//! ```

use sdguide::{DirectionalFilter, GuidingConfig, LeafRule, Refinement, SpatialFilter};
use sdguide_lab::quality::{self, Budget, Holdout, Report, TestField};
use std::time::Instant;

#[path = "common/plot.rs"]
mod plot;

fn args() -> (Budget, String) {
    let (mut budget, mut plot) = (Budget::default(), "out/quality.png".to_string());
    let argv: Vec<String> = std::env::args().skip(1).collect();
    for pair in argv.chunks(2) {
        match (pair[0].as_str(), pair.get(1)) {
            ("--iterations", Some(v)) if v.parse::<u32>().is_ok() => {
                budget.iterations = v.parse().unwrap()
            }
            ("--budget", Some(v)) if v.parse::<u64>().is_ok() => budget.first = v.parse().unwrap(),
            ("--plot", Some(v)) => plot = v.clone(),
            _ => {
                eprintln!("usage: quality [--iterations N] [--budget N] [--plot FILE.png]");
                std::process::exit(2);
            }
        }
    }
    (budget, plot)
}

/// Trains on `field` with `config` and returns the report on the trained field and the
/// training time (recording, refining and sampling the workload; not the evaluation).
fn train(field: &TestField, config: GuidingConfig, budget: Budget) -> (Report, f64) {
    let start = Instant::now();
    let trained =
        quality::train(field, config, budget).expect("the harness's configurations are valid");
    let seconds = start.elapsed().as_secs_f64();
    (trained.evaluate(field, Holdout::default()), seconds)
}

/// The reports after every iteration, for the plot.
fn curve(field: &TestField, config: GuidingConfig, budget: Budget) -> Vec<(u64, Report)> {
    quality::learning_curve(field, config, budget, Holdout::default())
        .expect("the harness's configurations are valid")
}

fn main() {
    let (budget, plot_path) = args();
    let holdout = Holdout::default();
    println!(
        "sdguide quality: {} iterations of {}·2^k samples; relvar = Var[v/p]/μ² at {} held-out positions in every spatial cell, cells weighted by their share of training positions\n",
        budget.iterations, budget.first, holdout.positions
    );
    println!("## Leaf rules\n");
    println!(
        "| light field | uniform | L1 | L2 | oracle (L2 partition) | L2 / L1 | L2 / oracle | spatial leaves | directional leaves |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let config = |rule| GuidingConfig {
        rule,
        ..GuidingConfig::default()
    };
    let mut panels = Vec::new();
    for field in TestField::all()
        .into_iter()
        .chain([TestField::sun_and_sky()])
    {
        let l1 = curve(&field, config(LeafRule::L1), budget);
        let l2 = curve(&field, config(LeafRule::L2), budget);
        let (a, b) = (l1.last().unwrap().1, l2.last().unwrap().1);
        println!(
            "| {} | {:.2} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {} | {:.0} |",
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
    if let Some(dir) = std::path::Path::new(&plot_path).parent() {
        std::fs::create_dir_all(dir).expect("can create the plot's directory");
    }
    plot::write_png(&plot_path, &panels).expect("can write the plot");
    println!("\nplot: {plot_path}\n");

    refinement_tables(budget);

    println!("## Filters (L2)\n");
    println!("| spatial | directional | {} | training |", field_names());
    println!("|---|---|---|---|---|---|---|");
    for (spatial, directional) in [
        (SpatialFilter::Nearest, DirectionalFilter::Nearest),
        (SpatialFilter::Nearest, DirectionalFilter::Box),
        (SpatialFilter::Nearest, DirectionalFilter::DeferredBox),
        (SpatialFilter::Stochastic, DirectionalFilter::Box),
        (SpatialFilter::Box, DirectionalFilter::Box),
    ] {
        let config = GuidingConfig {
            spatial_filter: spatial,
            directional_filter: directional,
            ..GuidingConfig::default()
        };
        let mut cells = Vec::new();
        let mut seconds = 0.0;
        for field in TestField::all() {
            let (r, t) = train(&field, config.clone(), budget);
            cells.push(format!("{:.3}", r.variances.learned));
            seconds += t;
        }
        println!(
            "| {spatial:?} | {directional:?} | {} | {seconds:.0} s |",
            cells.join(" | ")
        );
    }

    println!("\n## Guide-vs-BSDF selection (L2; relvar of f/q, f = v·BSDF)\n");
    println!(
        "| light field | a = ½ | learned a | best a per cell | learned / ½ | mean learned a |"
    );
    println!("|---|---|---|---|---|---|");
    for field in TestField::all() {
        let field = field.with_bsdf();
        // Every guide on: the table is of variances, and a guide turned off for its cost
        // trades variance for time.
        let config = GuidingConfig {
            guide_cost: None,
            ..GuidingConfig::default()
        };
        let (r, _) = train(&field, config, budget);
        let s = r.selection.expect("the workload has a BSDF");
        println!(
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} |",
            field.name,
            s.half,
            s.learned,
            s.best,
            s.learned / s.half,
            s.probability
        );
    }
}

/// Flux share against variance gain: at equal node counts, and at the default thresholds.
fn refinement_tables(budget: Budget) {
    println!("## Refinement (L2)\n");
    println!(
        "Equal node counts: both criteria split as much as a budget of interior nodes per directional tree allows.\n"
    );
    println!(
        "| light field | nodes per tree | leaves | flux share | variance gain | gain / flux | oracle, flux partition | oracle, gain partition | L2 / oracle, gain |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for field in TestField::all() {
        for nodes in [30, 60, 120] {
            let capped = |refinement| GuidingConfig {
                refinement,
                subdivision_threshold: 1e-6,
                gain_threshold: 1e-6,
                max_directional_nodes: nodes,
                ..GuidingConfig::default()
            };
            let (flux, _) = train(&field, capped(Refinement::FluxShare), budget);
            let (gain, _) = train(&field, capped(Refinement::VarianceGain), budget);
            println!(
                "| {} | {nodes} | {:.0} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
                field.name,
                gain.directional_leaves,
                flux.variances.learned,
                gain.variances.learned,
                gain.variances.learned / flux.variances.learned,
                flux.variances.oracle,
                gain.variances.oracle,
                gain.variances.learned / gain.variances.oracle,
            );
        }
    }
    let defaults = GuidingConfig::default();
    println!(
        "\nDefault thresholds (flux share ρ = {}, variance gain τ = {}), and the training time of all four fields (2 threads):\n",
        defaults.subdivision_threshold, defaults.gain_threshold
    );
    println!("| refinement | {} | training |", field_names());
    println!("|---|---|---|---|---|---|");
    for refinement in [Refinement::FluxShare, Refinement::VarianceGain] {
        let config = GuidingConfig {
            refinement,
            ..GuidingConfig::default()
        };
        let mut cells = Vec::new();
        let mut seconds = 0.0;
        for field in TestField::all() {
            let (r, t) = train(&field, config.clone(), budget);
            cells.push(format!(
                "{:.3} ({:.0} leaves)",
                r.variances.learned, r.directional_leaves
            ));
            seconds += t;
        }
        println!(
            "| {refinement:?} | {} | {seconds:.0} s |",
            cells.join(" | ")
        );
    }
    println!();
}

/// The fields' names as table columns.
fn field_names() -> String {
    TestField::all()
        .iter()
        .map(|f| f.name)
        .collect::<Vec<_>>()
        .join(" | ")
}
