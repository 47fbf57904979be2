//! The directional learning protocol (`sdguide_lab::protocol`, `docs/quality.md`): sdguide's
//! rules and, built with the `openpgl` feature, Open PGL's VMMs and quadtree, trained on the
//! same samples and scored by the relative variance of sampling their learned distribution
//! alone, in one spatial region and with each library's own spatial subdivision. sdguide's rows
//! also give the oracle: the best density on the partition it learned.
//!
//! ```text
//! cargo run --release -p sdguide-render --example protocol [--features openpgl] \
//!     [-- --positions 32 --resolution 1024 --seed 1]
//! ```

use rayon::prelude::*;
use sdguide::{GuidingConfig, GuidingField, LeafRule, SpatialSplit};
use sdguide_lab::protocol::Protocol;
use sdguide_lab::quality::cell_variances;
use sdguide_lab::synthetic::{Workload, room_bounds};
use std::time::Instant;

/// The protocol's evaluation; the training is fixed by `Protocol::default()` and the seed.
#[derive(clap::Parser)]
#[command(about = "sdguide and Open PGL on the directional protocol")]
struct Args {
    /// Held-out points the relative variance is averaged over.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u64).range(2..=100_000))]
    positions: u64,
    /// Side of the equal-area grid the quadrature runs on.
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(1..=8192))]
    resolution: u32,
    /// Fixes the protocol's samples and held-out points.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// One row of the table: the mean relvar over the held-out points and its standard error,
/// sdguide's oracle, spatial regions and directional leaves per region, and the seconds spent
/// training.
struct Row {
    name: String,
    relvar: f64,
    error: f64,
    sdguide: Option<Partition>,
    seconds: f64,
}

/// What sdguide learned: the oracle on its partition, averaged over the held-out points, and
/// the partition's size.
struct Partition {
    oracle: f64,
    regions: u64,
    leaves: f64,
}

/// Mean and standard error of per-point relvars.
fn mean_and_error(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}

fn sdguide_row(protocol: &Protocol, args: &Args, name: &str, config: GuidingConfig) -> Row {
    let start = Instant::now();
    let mut field = GuidingField::new(room_bounds(), config).expect("a valid configuration");
    protocol.train(&mut field);
    let seconds = start.elapsed().as_secs_f64();
    let workload = Workload {
        light: protocol.light.clone(),
        lobe_noise: 1.0,
        seed: protocol.seed,
        bsdf: None,
    };
    // The light is the same everywhere, so one point's oracle is its region's.
    let per_point: Vec<(f64, f64)> = protocol
        .positions(args.positions as usize)
        .par_iter()
        .map(|&x| {
            let guide = field.distribution(x);
            let relvar = protocol.relative_variance(x, |d| guide.pdf(d), args.resolution);
            (relvar, cell_variances(&workload, &guide, &[x]).oracle)
        })
        .collect();
    let relvars: Vec<f64> = per_point.iter().map(|p| p.0).collect();
    let (relvar, error) = mean_and_error(&relvars);
    let stats = field.stats();
    Row {
        name: name.to_string(),
        relvar,
        error,
        sdguide: Some(Partition {
            oracle: per_point.iter().map(|p| p.1).sum::<f64>() / per_point.len() as f64,
            regions: stats.spatial_leaves,
            leaves: stats.directional_leaves as f64 / stats.spatial_leaves as f64,
        }),
        seconds,
    }
}

#[cfg(feature = "openpgl")]
fn open_pgl_row(
    protocol: &Protocol,
    args: &Args,
    name: &str,
    arguments: sdguide_render::openpgl::Arguments,
) -> Row {
    use glam::Vec3;
    use sdguide_lab::rng::Rng;
    use sdguide_render::openpgl::{Guide, Record};
    let start = Instant::now();
    let threads = rayon::current_num_threads();
    let mut guide = Guide::with_arguments(room_bounds(), arguments, false, threads)
        .expect("Open PGL builds its field");
    for k in 0..protocol.iterations {
        protocol.samples(k).par_chunks(4096).for_each(|chunk| {
            let records: Vec<Record> = chunk
                .iter()
                .map(|s| Record {
                    position: s.position,
                    direction: s.direction,
                    radiance: s.value,
                    pdf: s.pdf,
                    // The lobes' sources are far away: parallax compensation has nothing to do.
                    distance: 1.0e4,
                    outgoing: Vec3::Z,
                    reflected: 0.0,
                    volume: false,
                })
                .collect();
            guide.record(&records);
        });
        guide.update();
    }
    let seconds = start.elapsed().as_secs_f64();
    let positions = protocol.positions(args.positions as usize);
    let relvars: Vec<f64> = positions
        .par_iter()
        .enumerate()
        .map(|(i, &x)| {
            // The stochastic spatial lookup is part of how a renderer samples Open PGL.
            let lookup = Rng::new(protocol.seed ^ i as u64).next_f32();
            match guide.distribution(x, Vec3::ZERO, lookup) {
                Some(distribution) => {
                    protocol.relative_variance(x, |d| distribution.pdf(d), args.resolution)
                }
                None => f64::INFINITY,
            }
        })
        .collect();
    let (relvar, error) = mean_and_error(&relvars);
    Row {
        name: name.to_string(),
        relvar,
        error,
        sdguide: None,
        seconds,
    }
}

fn main() {
    let args = <Args as clap::Parser>::parse();
    let protocol = Protocol {
        seed: args.seed,
        ..Protocol::default()
    };
    println!(
        "directional protocol: {} iterations of {} samples (½ uniform, ½ from the lobes), relvar of the learned distribution alone at {} held-out points, {}² quadrature\n",
        protocol.iterations, protocol.samples, args.positions, args.resolution
    );
    let mut rows = Vec::new();
    let l2 = GuidingConfig::default();
    let l1 = GuidingConfig {
        rule: LeafRule::L1,
        ..l2.clone()
    };
    // One region: no library splits space, so each learns one distribution from every sample.
    let one_region = |config: GuidingConfig| GuidingConfig {
        spatial_threshold: 1.0e12,
        ..config
    };
    let finer = GuidingConfig {
        gain_threshold: 0.1 * l2.gain_threshold,
        ..l2.clone()
    };
    let by_gain = GuidingConfig {
        spatial_split: SpatialSplit::Gain,
        ..l2.clone()
    };
    let variants = [
        (
            "one region",
            vec![
                ("L1", one_region(l1.clone())),
                ("L2", one_region(l2.clone())),
                ("L2, τ/10", one_region(finer)),
            ],
        ),
        (
            "own subdivision",
            vec![
                ("L1", l1),
                ("L2", l2),
                ("L2, spatial splits by gain", by_gain),
            ],
        ),
    ];
    for (spatial, configs) in variants {
        for (rule, config) in configs {
            let name = format!("sdguide {rule}, {spatial}");
            rows.push(sdguide_row(&protocol, &args, &name, config));
        }
        #[cfg(feature = "openpgl")]
        {
            use sdguide_render::openpgl::{Arguments, Directional};
            let leaf = if spatial == "one region" {
                usize::MAX / 4
            } else {
                Arguments::default().max_samples_per_leaf
            };
            for (name, directional) in [
                ("Open PGL VMM", Directional::Vmm),
                ("Open PGL parallax-aware VMM", Directional::ParallaxAwareVmm),
                ("Open PGL quadtree", Directional::QuadTree),
            ] {
                let arguments = Arguments {
                    directional,
                    max_samples_per_leaf: leaf,
                };
                rows.push(open_pgl_row(
                    &protocol,
                    &args,
                    &format!("{name}, {spatial}"),
                    arguments,
                ));
            }
        }
    }
    println!(
        "| guide | relvar | ± (1σ over points) | oracle on sdguide's partition | sdguide's regions | directional leaves per region | training (s) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for row in rows {
        let partition = match &row.sdguide {
            Some(p) => format!("{:.4} | {} | {:.0}", p.oracle, p.regions, p.leaves),
            None => "– | – | –".to_string(),
        };
        println!(
            "| {} | {:.4} | {:.4} | {} | {:.1} |",
            row.name, row.relvar, row.error, partition, row.seconds
        );
    }
}
