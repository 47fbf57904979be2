//! The one-vertex query rate: what the Python package's batch calls are measured against.
//!
//! ```text
//! cargo run --release --example vertex_rate -- CACHE LANES THREADS ROUNDS
//! ```
//!
//! Loads the field at `CACHE` and the lanes at `LANES` (little-endian `f32`: per lane a
//! position, a normal and two uniform numbers, 8 numbers), then times, `ROUNDS` times, one pass
//! over every lane calling `distribution(x).at_surface(n).sample(u)` and `.pdf(ω)` one vertex at
//! a time, from `THREADS` threads (the lanes split evenly, as a renderer's threads would take
//! them). Prints the best round's rate, lanes per second, and a checksum of the pdfs so that
//! the caller can check it computed what the batch calls compute.

use glam::{Vec2, Vec3};
use sdguide::GuidingField;
use std::process::ExitCode;
use std::time::Instant;

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [cache, lanes, threads, rounds] = args.as_slice() else {
        return Err("usage: vertex_rate CACHE LANES THREADS ROUNDS".into());
    };
    let field = GuidingField::load_from_path(cache).map_err(|e| e.to_string())?;
    let bytes = std::fs::read(lanes).map_err(|e| format!("{lanes}: {e}"))?;
    let numbers: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let lanes: Vec<(Vec3, Vec3, Vec2)> = numbers
        .chunks_exact(8)
        .map(|c| {
            (
                Vec3::new(c[0], c[1], c[2]),
                Vec3::new(c[3], c[4], c[5]),
                Vec2::new(c[6], c[7]),
            )
        })
        .collect();
    let threads: usize = threads.parse().map_err(|_| "THREADS: a number")?;
    let rounds: usize = rounds.parse().map_err(|_| "ROUNDS: a number")?;
    let per_thread = lanes.len().div_ceil(threads.max(1));
    let mut best = f64::INFINITY;
    let mut checksum = 0.0f64;
    for _ in 0..rounds {
        let start = Instant::now();
        checksum = std::thread::scope(|scope| {
            let workers: Vec<_> = lanes
                .chunks(per_thread.max(1))
                .map(|chunk| {
                    let field = &field;
                    scope.spawn(move || {
                        let mut sum = 0.0f64;
                        for &(x, n, u) in chunk {
                            let surface = field.distribution(x).at_surface(n);
                            let (direction, pdf) = surface.sample(u);
                            sum += f64::from(pdf) + f64::from(surface.pdf(direction));
                        }
                        sum
                    })
                })
                .collect();
            workers
                .into_iter()
                .map(|w| w.join().unwrap_or(f64::NAN))
                .sum()
        });
        best = best.min(start.elapsed().as_secs_f64());
    }
    println!(
        "{:.6e} {checksum:.9e}",
        lanes.len() as f64 / best.max(f64::MIN_POSITIVE)
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}
