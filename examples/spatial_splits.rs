//! Spatial splits by count against splits by gain, on the quality harness's light fields (see
//! `sdguide_lab::quality`, `docs/quality.md`, *Spatial splits*): relative variance of the
//! learned guide (L2; with `--l1`, L1 too) and of the oracle on its partition, spatial leaves
//! and the field's bytes, at equal training budgets.
//!
//! ```text
//! cargo run --release --example spatial_splits [-- --iterations 5 --budget 250000 --tau T... --threshold C... --l1]
//! ```

use sdguide::{GuidingConfig, LeafRule, SpatialSplit};
use sdguide_lab::quality::{self, Budget, Holdout, TestField};

fn main() {
    let mut budget = Budget::default();
    let mut taus = Vec::new();
    let mut thresholds = Vec::new();
    let mut rules = vec![LeafRule::L2];
    let mut argv = std::env::args().skip(1);
    while let Some(flag) = argv.next() {
        if flag == "--l1" {
            rules.insert(0, LeafRule::L1);
            continue;
        }
        match (
            flag.as_str(),
            argv.next().and_then(|v| v.parse::<f64>().ok()),
        ) {
            ("--iterations", Some(v)) => budget.iterations = v as u32,
            ("--budget", Some(v)) => budget.first = v as u64,
            ("--tau", Some(v)) => taus.push(v as f32),
            ("--threshold", Some(v)) => thresholds.push(v as f32),
            _ => {
                eprintln!(
                    "usage: spatial_splits [--iterations N] [--budget N] [--tau T]... [--threshold C]... [--l1]"
                );
                std::process::exit(2);
            }
        }
    }
    if taus.is_empty() {
        taus.push(GuidingConfig::default().spatial_gain_threshold);
    }
    println!(
        "{} iterations of {}·2^k samples; relvar (oracle on the learned partition), spatial leaves, bytes\n",
        budget.iterations, budget.first
    );
    println!("| light field | split | rule | relvar | oracle | spatial leaves | MB |");
    println!("|---|---|---|---:|---:|---:|---:|");
    let mut fields = TestField::all();
    fields.push(TestField::sun_and_sky());
    for field in &fields {
        let mut configs = vec![("count".to_string(), GuidingConfig::default())];
        for &c in &thresholds {
            configs.push((
                format!("count, c = {c}"),
                GuidingConfig {
                    spatial_threshold: c,
                    ..GuidingConfig::default()
                },
            ));
        }
        for &tau in &taus {
            configs.push((
                format!("gain, τ = {tau}"),
                GuidingConfig {
                    spatial_split: SpatialSplit::Gain,
                    spatial_gain_threshold: tau,
                    ..GuidingConfig::default()
                },
            ));
        }
        for (name, config) in configs {
            for &rule in &rules {
                let config = GuidingConfig {
                    rule,
                    ..config.clone()
                };
                let trained = quality::train(field, config, budget).expect("valid configurations");
                let r = trained.evaluate(field, Holdout::default());
                println!(
                    "| {} | {name} | {rule:?} | {:.4} | {:.4} | {} | {:.1} |",
                    field.name,
                    r.variances.learned,
                    r.variances.oracle,
                    r.spatial_leaves,
                    trained.field.stats().bytes as f64 / 1e6
                );
            }
        }
    }
}
