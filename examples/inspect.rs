//! Inspect a guiding cache: print its summary and draw what it learned at a position.
//!
//! ```text
//! cargo run --release --example inspect -- CACHE [--at X Y Z] [--png OUT.png] [--size PIXELS]
//! ```
//!
//! The heat map shows the directional distribution at the position on the equal-area square
//! (the octahedral map: +z at the centre, −z at the corners, ±x at the middles of the right and
//! left sides, ±y at the top and bottom), coloured by log₁₀ of the density relative to uniform,
//! with the quadtree's leaf borders drawn in grey.

use glam::{Vec2, Vec3};
use sdguide::GuidingField;
use sdguide::sphere::{INV_SPHERE_AREA, square_to_direction};
use std::process::ExitCode;

struct Args {
    cache: String,
    at: Option<Vec3>,
    png: Option<String>,
    size: u32,
}

fn usage() -> ExitCode {
    eprintln!("usage: inspect CACHE [--at X Y Z] [--png OUT.png] [--size PIXELS]");
    ExitCode::from(2)
}

fn parse() -> Option<Args> {
    let mut argv = std::env::args().skip(1);
    let mut args = Args {
        cache: argv.next()?,
        at: None,
        png: None,
        size: 512,
    };
    while let Some(flag) = argv.next() {
        let mut number = || argv.next()?.parse::<f32>().ok();
        match flag.as_str() {
            "--at" => args.at = Some(Vec3::new(number()?, number()?, number()?)),
            "--size" => args.size = (number()? as u32).clamp(16, 4096),
            "--png" => args.png = Some(argv.next()?),
            _ => return None,
        }
    }
    Some(args)
}

fn main() -> ExitCode {
    let Some(args) = parse() else {
        return usage();
    };
    let field = match GuidingField::load_from_path(&args.cache) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("{}: {e}", args.cache);
            return ExitCode::FAILURE;
        }
    };
    let c = field.config();
    let s = field.stats();
    let b = field.bounds();
    println!("{}", args.cache);
    println!("  iteration          {}", s.iteration);
    println!("  leaf rule          {:?}", c.rule);
    println!("  bounds             {} .. {}", b.min, b.max);
    println!(
        "  spatial tree       {} nodes, {} leaves, depth {}",
        s.spatial_nodes, s.spatial_leaves, s.spatial_depth
    );
    println!(
        "  directional trees  {} nodes, {} leaves, depth {}",
        s.directional_nodes, s.directional_leaves, s.directional_depth
    );
    println!(
        "  samples            {} this iteration, {} in all, {} rejected",
        s.samples_recorded,
        s.samples_recorded_total,
        s.rejected.total()
    );
    println!("  memory             {} bytes", s.bytes);
    println!(
        "  surface products   {} ({} nodes)",
        s.surface_products, s.surface_product_nodes
    );
    if c.volumes {
        println!(
            "  volume guides      {} nodes, {} medium samples this iteration",
            s.volume_directional_nodes, s.volume_samples_recorded
        );
    }

    let at = args.at.unwrap_or(b.center());
    let cell = field.cell_at(at);
    let dist = cell.distribution();
    let leaves = dist.leaves();
    let (lo, hi) = leaves.iter().fold((f32::MAX, 0.0f32), |(lo, hi), (c, p)| {
        let density = p / c.area() as f32;
        (lo.min(density), hi.max(density))
    });
    println!("at {at}");
    println!(
        "  spatial cell       {} .. {} (depth {})",
        cell.bounds.min, cell.bounds.max, cell.depth
    );
    println!(
        "  distribution       {} leaves, density {:.3}× to {:.1}× uniform",
        leaves.len(),
        lo,
        hi
    );

    if let Some(path) = &args.png {
        if let Err(e) = heat_map(&dist, args.size, path) {
            eprintln!("{path}: {e}");
            return ExitCode::FAILURE;
        }
        println!("  heat map           {path}");
    }
    ExitCode::SUCCESS
}

/// Renders the distribution on the unit square: colour by log density, leaf borders in grey.
fn heat_map(
    dist: &sdguide::DirectionalDistribution<'_>,
    size: u32,
    path: &str,
) -> Result<(), Box<dyn std::error::Error>> {
    let n = size as usize;
    let mut rgb = vec![0u8; n * n * 3];
    // Rows top to bottom are s.y from 1 down to 0; columns are s.x from 0 to 1.
    for row in 0..n {
        for col in 0..n {
            let s = Vec2::new(
                (col as f32 + 0.5) / n as f32,
                1.0 - (row as f32 + 0.5) / n as f32,
            );
            let relative = dist.pdf(square_to_direction(s)) / INV_SPHERE_AREA;
            // log10 from −2 (a hundredth of uniform) to +3 (a thousand times) over the ramp.
            let t = ((relative.log10() + 2.0) / 5.0).clamp(0.0, 1.0);
            rgb[(row * n + col) * 3..][..3].copy_from_slice(&ramp(t));
        }
    }
    for (cell, _) in dist.leaves() {
        let px = |v: f32| ((v * n as f32).round() as usize).min(n - 1);
        let (x0, x1) = (px(cell.origin.x), px(cell.origin.x + cell.size));
        let (y1, y0) = (
            n - 1 - px(cell.origin.y),
            n - 1 - px(cell.origin.y + cell.size),
        );
        if x1 - x0 < 3 {
            continue; // too small to outline at this size
        }
        let mut put = |x: usize, y: usize| rgb[(y * n + x) * 3..][..3].copy_from_slice(&[96; 3]);
        for x in x0..=x1 {
            put(x, y0);
            put(x, y1);
        }
        for y in y0..=y1 {
            put(x0, y);
            put(x1, y);
        }
    }
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut encoder = png::Encoder::new(file, size, size);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header()?.write_image_data(&rgb)?;
    Ok(())
}

/// A dark-to-bright colour ramp (black, violet, red, orange, pale yellow).
fn ramp(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 0.02],
        [0.34, 0.06, 0.43],
        [0.73, 0.21, 0.33],
        [0.98, 0.55, 0.04],
        [0.99, 1.0, 0.64],
    ];
    let x = t * (STOPS.len() - 1) as f32;
    let i = (x as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    std::array::from_fn(|k| ((STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f) * 255.0) as u8)
}
