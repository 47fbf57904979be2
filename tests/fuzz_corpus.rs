//! Replays the fuzz targets' checked-in corpus on stable, so `cargo test` keeps every input the
//! fuzzers were seeded with (and every crash they found, once added) passing.

#[path = "../fuzz/harness.rs"]
mod harness;

use std::path::Path;

fn corpus(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = Path::new("fuzz/corpus").join(target);
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| {
            let path = e.unwrap().path();
            (path.display().to_string(), std::fs::read(&path).unwrap())
        })
        .collect();
    files.sort();
    files
}

/// Runs `target` on every file of its corpus (and there must be a few).
fn replay(target: &str, run: fn(&[u8])) {
    let files = corpus(target);
    assert!(files.len() >= 3, "{target}: {} files", files.len());
    for (name, data) in files {
        eprintln!("{name}");
        run(&data);
    }
}

#[test]
fn cache_load_corpus_replays() {
    replay("cache_load", harness::cache_load);
}

#[test]
fn field_ops_corpus_replays() {
    replay("field_ops", harness::field_ops);
}

/// Writes the seed corpus: `cargo test --test fuzz_corpus -- --ignored write_seed_corpus`.
#[test]
#[ignore = "writes the checked-in seed corpus"]
fn write_seed_corpus() {
    use sdguide::{Aabb, GuidingConfig, GuidingField};
    let dir = Path::new("fuzz/corpus");
    // cache_load: a real trained cache, an empty field's cache, a truncated cache.
    let v1 = std::fs::read("tests/data/v1.sdgc").unwrap();
    std::fs::write(dir.join("cache_load/trained"), &v1).unwrap();
    let empty = GuidingField::new(
        Aabb::new(glam::Vec3::ZERO, glam::Vec3::ONE),
        GuidingConfig::default(),
    )
    .unwrap();
    std::fs::write(dir.join("cache_load/empty"), empty.to_bytes()).unwrap();
    std::fs::write(dir.join("cache_load/truncated"), &v1[..200]).unwrap();
    // A small 3.0 cache in the middle of an iteration: exact sums in every section (moments,
    // quadrants, pending sums of the deferred filter, selection and continuation sums, the
    // tally's held slots and buckets), and a 2.6 one saved at an iteration's start.
    let small = GuidingConfig {
        spatial_threshold: 300.0,
        max_directional_nodes: 24,
        directional_filter: sdguide::DirectionalFilter::DeferredBox,
        ..GuidingConfig::default()
    };
    let mut field =
        GuidingField::new(sdguide_lab::synthetic::room_bounds(), small.clone()).unwrap();
    let work = sdguide_lab::synthetic::Workload {
        light: sdguide_lab::synthetic::LightField::standard(),
        lobe_noise: 2.0,
        seed: 1,
        bsdf: Some(sdguide_lab::synthetic::Bsdf {
            axis: glam::Vec3::Z,
            kappa: 2.0,
        }),
    };
    work.train(&mut field, 2, 400);
    work.record_iteration(&field, 5, 300);
    field.record_continuation(&sdguide::Continuation {
        position: glam::Vec3::splat(0.5),
        value: 2.0,
        cost: 3.0,
    });
    // (`trained-3.0`, written by the 3.0 writer, stays as a file of that minor version.)
    std::fs::write(dir.join("cache_load/trained-3.1"), field.to_bytes()).unwrap();
    // The same workload with volume guides: a third of the samples are medium ones.
    let mut volumes = GuidingField::new(
        sdguide_lab::synthetic::room_bounds(),
        GuidingConfig {
            volumes: true,
            ..small
        },
    )
    .unwrap();
    for iteration in 0..3u64 {
        let mut rng = sdguide_lab::rng::Rng::new(iteration);
        for i in 0..400 {
            let sample = sdguide::Sample {
                volume: i % 3 == 0,
                ..work.draw(&volumes, &mut rng)
            };
            volumes.record(&sample);
        }
        if iteration < 2 {
            volumes.refine();
        }
    }
    std::fs::write(dir.join("cache_load/volumes-3.1"), volumes.to_bytes()).unwrap();
    std::fs::write(dir.join("cache_load/gain-3.3"), gain_cache()).unwrap();

    // field_ops: a training session, bad inputs, and an absurd configuration.
    let config = |c: f32, rho: f32, depth: u8, eps: f32, nodes: u16, spatial: u16, mem: u8| {
        let mut v = vec![1u8];
        for f in [c, rho] {
            v.extend_from_slice(&f.to_le_bytes());
        }
        v.push(depth);
        v.extend_from_slice(&eps.to_le_bytes());
        v.extend_from_slice(&nodes.to_le_bytes());
        v.extend_from_slice(&spatial.to_le_bytes());
        v.push(mem);
        for f in [0.0f32, 0.0, 0.0, 1.0, 1.0, 1.0] {
            v.extend_from_slice(&f.to_le_bytes());
        }
        v
    };
    let floats = |v: &mut Vec<u8>, fs: &[f32]| {
        for f in fs {
            v.extend_from_slice(&f.to_le_bytes());
        }
    };
    let mut training = config(50.0, 0.01, 20, 0.01, 8192, 4096, 64);
    for round in 0..4 {
        for i in 0..60 {
            let t = (i as f32 + 0.5) / 60.0;
            training.push(3); // query and record
            floats(
                &mut training,
                &[
                    t,
                    0.5 * t,
                    1.0 - t,
                    t,
                    (t * 7.0).fract(),
                    if i % 5 == 0 { 9.0 } else { 0.2 },
                ],
            );
        }
        training.push(if round % 2 == 0 { 2 } else { 4 }); // refine / save+load
        training.push(2);
    }
    training.push(5);
    std::fs::write(dir.join("field_ops/training"), training).unwrap();

    let mut bad = config(12000.0, 0.01, 20, 0.01, 8192, 4096, 64);
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    for (p, d, v, pdf) in [
        ([nan, 0.5, 0.5], [0.0, 0.0, 1.0], 1.0, 1.0),
        ([0.5, 0.5, 9.0], [0.0, 0.0, 1.0], 1.0, 1.0),
        ([0.5, 0.5, 0.5], [0.0, 0.0, 0.0], 1.0, 1.0),
        ([0.5, 0.5, 0.5], [inf, 0.0, 1.0], 1.0, 1.0),
        ([0.5, 0.5, 0.5], [0.0, 0.0, 1.0], -1.0, 1.0),
        ([0.5, 0.5, 0.5], [0.0, 0.0, 1.0], 1.0, 0.0),
        (
            [0.5, 0.5, 0.5],
            [0.0, 0.0, 1.0],
            f32::MAX,
            f32::from_bits(1),
        ),
    ] {
        bad.push(0);
        floats(&mut bad, &p);
        floats(&mut bad, &d);
        floats(&mut bad, &[v, pdf]);
        bad.push(3);
    }
    bad.extend_from_slice(&[2, 3]);
    floats(&mut bad, &[nan, inf, -inf, nan, nan, 1.0]);
    bad.extend_from_slice(&[4, 5]);
    std::fs::write(dir.join("field_ops/bad-input"), bad).unwrap();

    // Samples with normals (eight directions, more than a cell's four slots) and mixture terms,
    // continuations, refines and round trips: the tally's buckets and every exact sum.
    let mut normals = config(200.0, 0.01, 20, 0.01, 8192, 4096, 64);
    for round in 0..3 {
        for i in 0..80u32 {
            let t = (i as f32 + 0.5) / 80.0;
            let a = (i % 8) as f32 * 0.785;
            normals.push(0);
            floats(&mut normals, &[t, 1.0 - t, (t * 3.0).fract()]);
            floats(&mut normals, &[a.cos(), a.sin(), 0.3]);
            floats(&mut normals, &[0.5 + t, 0.3]);
            normals.push(0x80 | 0x20 | (i % 4) as u8);
            normals.push(5);
            floats(&mut normals, &[t, 0.5, 0.5, 2.0 * t, 1.5]);
        }
        normals.push(if round == 1 { 4 } else { 2 });
    }
    std::fs::write(dir.join("field_ops/normals-continuations"), normals).unwrap();

    // A field with volume guides (filters byte: bit 5, and the box filter): medium samples
    // with mixture terms, queries of the phase product, refines and round trips.
    let mut media = config(200.0, 0.01, 20, 0.01, 8192, 4096, 64);
    floats(&mut media, &[0.5]);
    media.push(0x20 | 0x04);
    for round in 0..3 {
        for i in 0..80u32 {
            let t = (i as f32 + 0.5) / 80.0;
            media.push(0);
            floats(&mut media, &[t, 1.0 - t, (t * 3.0).fract()]);
            floats(&mut media, &[-1.0, 0.2 * t, 0.1]);
            floats(&mut media, &[0.5 + t, 0.3]);
            media.push(0x80 | 0x10 | (i % 4) as u8);
            media.push(3);
            floats(&mut media, &[t, 0.5, 1.0 - t, t, 0.7, 2.0 * t - 1.0]);
        }
        media.push(if round == 1 { 4 } else { 2 });
    }
    std::fs::write(dir.join("field_ops/volumes"), media).unwrap();

    let mut absurd = config(1.0, 1e-30, 20, 1e-30, 65535, 65535, 1);
    for i in 0..100 {
        let t = i as f32 / 100.0;
        absurd.push(0);
        floats(
            &mut absurd,
            &[
                t,
                t * t,
                1.0 - t,
                (t * 13.0).sin(),
                (t * 7.0).cos(),
                t,
                1.0 + t,
                0.1,
            ],
        );
        absurd.push(200);
        if i % 20 == 19 {
            absurd.push(2);
        }
    }
    absurd.extend_from_slice(&[4, 5]);
    std::fs::write(dir.join("field_ops/absurd-config"), absurd).unwrap();
}

/// A small 3.3 cache of a field that splits spatial leaves by gain, in the middle of an
/// iteration: its signatures hold sums.
fn gain_cache() -> Vec<u8> {
    use sdguide::{GuidingConfig, GuidingField, SpatialSplit};
    let mut field = GuidingField::new(
        sdguide_lab::synthetic::room_bounds(),
        GuidingConfig {
            spatial_threshold: 300.0,
            max_directional_nodes: 24,
            spatial_split: SpatialSplit::Gain,
            spatial_gain_threshold: 0.01,
            ..GuidingConfig::default()
        },
    )
    .unwrap();
    let work = sdguide_lab::synthetic::Workload {
        light: sdguide_lab::synthetic::LightField::standard(),
        lobe_noise: 1.0,
        seed: 2,
        bsdf: None,
    };
    work.train(&mut field, 2, 1_000);
    work.record_iteration(&field, 5, 300);
    field.to_bytes()
}

/// The corpus's gain cache (written by [`gain_cache`]) is a field split by gain that loads.
#[test]
fn the_corpus_holds_a_field_split_by_gain() {
    let bytes = std::fs::read("fuzz/corpus/cache_load/gain-3.3").unwrap();
    let field = sdguide::GuidingField::from_bytes(&bytes).unwrap();
    assert_eq!(field.config().spatial_split, sdguide::SpatialSplit::Gain);
    assert!(field.stats().spatial_leaves > 1);
}
