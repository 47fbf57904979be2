//! Training is deterministic: the same samples give the same cache bytes whatever the number
//! of threads, the order the samples arrive in, or how a farm splits an iteration over workers
//! (threads or OS processes) and merges their fields, in any order.
//!
//! The samples carry every statistic a field keeps: noisy values (moments, quadrant sums),
//! mixture terms (guide-selection sums and the guide-off verdicts), continuations in half the
//! room, and normals from eight planar faces — more than the four a spatial cell tallies.

use glam::Vec3;
use sdguide::{
    Continuation, DirectionalFilter, GuidingConfig, GuidingField, Sample, SpatialFilter,
    SpatialSplit,
};
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{Bsdf, LightField, Workload, room_bounds};
use std::process::Command;

/// The configurations under test: the default, and one with the stochastic spatial filter
/// (its jitter comes from the sample), the deferred directional filter (its pending sums
/// travel through caches and merges) and spatial splits by gain (their signatures too).
fn configs() -> [GuidingConfig; 2] {
    let base = GuidingConfig {
        spatial_threshold: 2_000.0,
        guide_cost: Some(0.5),
        ..GuidingConfig::default()
    };
    [
        base.clone(),
        GuidingConfig {
            spatial_filter: SpatialFilter::Stochastic,
            directional_filter: DirectionalFilter::DeferredBox,
            spatial_split: SpatialSplit::Gain,
            ..base
        },
    ]
}

/// The room's six walls and two faces of boxes turned about the vertical: a point on face
/// `face` at `(u, v)`, and the face's normal (into the room).
fn face_vertex(face: u64, u: f32, v: f32) -> (Vec3, Vec3) {
    let (a, b) = (0.05 + 0.9 * u, 0.05 + 0.9 * v);
    match face {
        0 => (Vec3::new(a, 0.0, b), Vec3::Y),
        1 => (Vec3::new(a, 1.0, b), -Vec3::Y),
        2 => (Vec3::new(0.0, a, b), Vec3::X),
        3 => (Vec3::new(1.0, a, b), -Vec3::X),
        4 => (Vec3::new(a, b, 0.0), Vec3::Z),
        5 => (Vec3::new(a, b, 1.0), -Vec3::Z),
        _ => {
            let turn = if face == 6 { 0.4f32 } else { -1.1 };
            let n = Vec3::new(turn.cos(), 0.0, turn.sin());
            let along = Vec3::new(-turn.sin(), 0.0, turn.cos());
            let centre = Vec3::new(0.5, 0.3, 0.5);
            (
                centre + 0.25 * (a - 0.5) * along + Vec3::new(0.0, 0.3 * b, 0.0),
                n,
            )
        }
    }
}

/// What a renderer records at one vertex: the sample (with its mixture terms and normal), and
/// in half the room a continuation.
fn draw(field: &GuidingField, work: &Workload, rng: &mut Rng) -> (Sample, Option<Continuation>) {
    let (x, n) = face_vertex(rng.next_u64() % 8, rng.next_f32(), rng.next_f32());
    let bsdf = Bsdf {
        axis: n,
        kappa: 3.0,
    };
    let sample = work.draw_at(field, (x, n), Some(bsdf), rng);
    let continuation = (x.x < 0.5).then(|| Continuation {
        position: x,
        value: 0.3 * sample.value,
        cost: 1.0 + rng.next_f32(),
    });
    (sample, continuation)
}

type Vertex = (Sample, Option<Continuation>);

/// Iteration `k`'s vertices, drawn from `field` (the same in every run: the field is).
fn iteration(field: &GuidingField, k: u64, n: usize) -> Vec<Vertex> {
    let work = Workload {
        light: LightField::standard(),
        lobe_noise: 4.0,
        seed: 3,
        bsdf: None,
    };
    let mut rng = Rng::new(0xD5 ^ k << 32);
    (0..n).map(|_| draw(field, &work, &mut rng)).collect()
}

fn record(field: &GuidingField, vertices: &[Vertex]) {
    for (s, c) in vertices {
        field.record(s);
        if let Some(c) = c {
            field.record_continuation(c);
        }
    }
}

/// The vertices in an order shuffled by `seed`.
fn shuffled(vertices: &[Vertex], seed: u64) -> Vec<Vertex> {
    let mut v = vertices.to_vec();
    let mut rng = Rng::new(seed);
    for i in (1..v.len()).rev() {
        v.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
    }
    v
}

/// Records `vertices` from `threads` threads at once, each a contiguous share.
fn record_from_threads(field: &GuidingField, vertices: &[Vertex], threads: usize) {
    std::thread::scope(|s| {
        for part in vertices.chunks(vertices.len().div_ceil(threads)) {
            s.spawn(move || record(field, part));
        }
    });
}

/// Every ordering of `0..n`.
fn permutations(n: usize) -> Vec<Vec<usize>> {
    if n == 0 {
        return vec![vec![]];
    }
    let mut out = Vec::new();
    for p in permutations(n - 1) {
        for i in 0..=p.len() {
            let mut q = p.clone();
            q.insert(i, n - 1);
            out.push(q);
        }
    }
    out
}

const ITERATIONS: u64 = 3;
const SAMPLES: usize = 470_000;

#[test]
fn threads_orders_and_merged_workers_give_the_same_bytes() {
    for config in configs() {
        let mut reference = GuidingField::new(room_bounds(), config.clone()).unwrap();
        let mut others: Vec<GuidingField> = vec![reference.clone(); 4];
        for k in 0..ITERATIONS {
            let vertices = iteration(&reference, k, SAMPLES);
            let start = reference.clone();
            record(&reference, &vertices);
            for (t, (field, threads)) in others.iter().zip([1, 2, 8, 32]).enumerate() {
                record_from_threads(field, &shuffled(&vertices, 17 + t as u64), threads);
            }
            // Four workers, each a random shard, merged in every order.
            let mut rng = Rng::new(100 + k);
            let mut shards: Vec<Vec<Vertex>> = vec![Vec::new(); 4];
            for v in &vertices {
                shards[(rng.next_u64() % 4) as usize].push(*v);
            }
            let workers: Vec<GuidingField> = shards
                .iter()
                .map(|shard| {
                    let w = start.clone();
                    record_from_threads(&w, shard, 2);
                    w
                })
                .collect();
            let expected = reference.to_bytes();
            for order in permutations(4) {
                let mut merged = workers[order[0]].clone();
                for &i in &order[1..] {
                    merged.merge(&workers[i]).unwrap();
                }
                assert!(
                    merged.to_bytes() == expected,
                    "iteration {k}, merge order {order:?}"
                );
            }
            for (field, threads) in others.iter().zip([1, 2, 8, 32]) {
                assert!(
                    field.to_bytes() == expected,
                    "iteration {k}, {threads} threads"
                );
            }
            reference.refine();
            let expected = reference.to_bytes();
            for (field, threads) in others.iter_mut().zip([1, 2, 8, 32]) {
                field.refine();
                assert!(
                    field.to_bytes() == expected,
                    "refined {k}, {threads} threads"
                );
            }
        }
        // What the trainings learned is not trivial: several cells, stored products, guides
        // turned off by their cost somewhere, continuation estimates.
        let stats = reference.stats();
        assert!(stats.spatial_leaves > 8, "{stats:?}");
        assert!(stats.surface_products > 4, "{stats:?}");
        assert!(stats.guides_off > 0, "{stats:?}");
    }
}

/// The environment variable that makes [`separate_processes_train_like_one_process`] a
/// worker: `config index;iteration;worker index;workers;cache in;cache out`.
const WORKER: &str = "SDGUIDE_DETERMINISM_WORKER";
const FARM_SAMPLES: usize = 60_000;

/// One worker process: loads the broadcast cache, records its shard of the iteration (every
/// `workers`-th vertex), saves.
fn work_as_farm_worker(job: &str) {
    let parts: Vec<&str> = job.split(';').collect();
    let [_, k, index, workers, input, output] = parts[..] else {
        panic!("bad job {job}");
    };
    let (k, index, workers): (u64, usize, usize) = (
        k.parse().unwrap(),
        index.parse().unwrap(),
        workers.parse().unwrap(),
    );
    let field = GuidingField::load_from_path(input).unwrap();
    let vertices = iteration(&field, k, FARM_SAMPLES);
    let shard: Vec<Vertex> = vertices.into_iter().skip(index).step_by(workers).collect();
    record_from_threads(&field, &shard, 2);
    field.save_to_path(output).unwrap();
}

#[test]
fn separate_processes_train_like_one_process() {
    if let Ok(job) = std::env::var(WORKER) {
        work_as_farm_worker(&job);
        return;
    }
    let dir = std::env::temp_dir().join(format!("sdguide-farm-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let workers = 3;
    for (c, config) in configs().into_iter().enumerate() {
        let mut one = GuidingField::new(room_bounds(), config).unwrap();
        let mut coordinator = one.clone();
        for k in 0..ITERATIONS {
            record(&one, &iteration(&one, k, FARM_SAMPLES));
            one.refine();
            // The coordinator broadcasts its field; each worker process records a shard.
            let broadcast = dir.join(format!("broadcast-{c}-{k}.sdgc"));
            coordinator.save_to_path(&broadcast).unwrap();
            let outputs: Vec<_> = (0..workers)
                .map(|i| dir.join(format!("worker-{c}-{k}-{i}.sdgc")))
                .collect();
            let children: Vec<_> = outputs
                .iter()
                .enumerate()
                .map(|(i, out)| {
                    let job = format!(
                        "{c};{k};{i};{workers};{};{}",
                        broadcast.display(),
                        out.display()
                    );
                    Command::new(std::env::current_exe().unwrap())
                        .args(["--exact", "separate_processes_train_like_one_process"])
                        .env(WORKER, job)
                        .stdout(std::process::Stdio::null())
                        .spawn()
                        .unwrap()
                })
                .collect();
            for mut child in children {
                assert!(child.wait().unwrap().success());
            }
            // Merged in an order other than the workers', and refined.
            let mut fields: Vec<GuidingField> = outputs
                .iter()
                .rev()
                .map(|p| GuidingField::load_from_path(p).unwrap())
                .collect();
            let first = fields.remove(0);
            coordinator = fields.iter().fold(first, |mut merged, f| {
                merged.merge(f).unwrap();
                merged
            });
            coordinator.refine();
            assert!(
                coordinator.to_bytes() == one.to_bytes(),
                "configuration {c}, iteration {k}"
            );
        }
        assert!(one.stats().spatial_leaves > 1);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
