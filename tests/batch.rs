//! The batch calls (structure of arrays, for wavefront renderers): every lane equal to the
//! one-vertex call to the bit, with and without normals and across chunk boundaries; slices of
//! the wrong length refused before anything is written; `record_batch` records what `record`
//! does.

mod common;

use common::trained;
use glam::{Vec2, Vec3};
use sdguide::{BATCH_CHUNK, BatchError, GuidingConfig, GuidingField, LeafRule, Sample};
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{LightField, Workload, room_bounds, room_vertex};

/// Lanes at the room's vertices (with their normals) and inside it, a few of them outside the
/// bounds or with a zero normal; more than two chunks, the last one partial.
fn lanes(n: usize) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec2>) {
    let mut rng = Rng::new(5);
    let (mut positions, mut normals, mut u) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..n {
        let (x, normal) = room_vertex([rng.next_f32(), rng.next_f32(), rng.next_f32()]);
        let (x, normal) = match i % 97 {
            0 => (x + Vec3::splat(3.0), normal),
            1 => (x, Vec3::ZERO),
            _ => (x, normal),
        };
        positions.push(x);
        normals.push(normal);
        u.push(rng.next_vec2());
    }
    (positions, normals, u)
}

#[test]
fn every_lane_is_the_one_vertex_call_to_the_bit() {
    let field = trained(LeafRule::L2, 20, 4, 50_000);
    let n = 2 * BATCH_CHUNK + 123;
    let (positions, normals, u) = lanes(n);
    for normals in [None, Some(normals.as_slice())] {
        let (mut directions, mut pdfs) = (vec![Vec3::NAN; n], vec![f32::NAN; n]);
        field
            .sample_batch(&positions, normals, &u, &mut directions, &mut pdfs)
            .unwrap();
        let mut back = vec![f32::NAN; n];
        field
            .pdf_batch(&positions, normals, &directions, &mut back)
            .unwrap();
        for i in 0..n {
            let dist = field.distribution(positions[i]);
            let (d, p, q) = match normals {
                Some(normals) => {
                    let surface = dist.at_surface(normals[i]);
                    let (d, p) = surface.sample(u[i]);
                    (d, p, surface.pdf(d))
                }
                None => {
                    let (d, p) = dist.sample(u[i]);
                    (d, p, dist.pdf(d))
                }
            };
            let lane = (
                directions[i].to_array().map(f32::to_bits),
                pdfs[i].to_bits(),
            );
            assert_eq!(
                lane,
                (d.to_array().map(f32::to_bits), p.to_bits()),
                "lane {i}"
            );
            assert_eq!(back[i].to_bits(), q.to_bits(), "lane {i}");
        }
    }
    let mut a = vec![f32::NAN; n];
    field.guide_probability_batch(&positions, &mut a).unwrap();
    for (x, a) in positions.iter().zip(&a) {
        assert_eq!(
            a.to_bits(),
            field.distribution(*x).guide_probability().to_bits()
        );
    }
}

#[test]
fn slices_of_the_wrong_length_are_refused_untouched() {
    let field = GuidingField::new(room_bounds(), GuidingConfig::default()).unwrap();
    let (positions, normals, u) = lanes(10);
    let (mut directions, mut pdfs) = (vec![Vec3::NAN; 10], vec![f32::NAN; 10]);
    let mismatch = |slice, found| BatchError::LengthMismatch {
        slice,
        lanes: 10,
        found,
    };
    assert_eq!(
        field.sample_batch(&positions, None, &u[..9], &mut directions, &mut pdfs),
        Err(mismatch("u", 9))
    );
    assert_eq!(
        field.sample_batch(
            &positions,
            Some(&normals[..3]),
            &u,
            &mut directions,
            &mut pdfs
        ),
        Err(mismatch("normals", 3))
    );
    assert_eq!(
        field.sample_batch(&positions, None, &u, &mut directions[..2], &mut pdfs),
        Err(mismatch("directions", 2))
    );
    assert_eq!(
        field.pdf_batch(&positions, None, &directions, &mut pdfs[..0]),
        Err(mismatch("pdfs", 0))
    );
    assert_eq!(
        field.guide_probability_batch(&positions, &mut pdfs[..4]),
        Err(mismatch("probabilities", 4))
    );
    assert!(directions.iter().all(|d| d.is_nan()) && pdfs.iter().all(|p| p.is_nan()));
    // No lanes is a batch like any other.
    field
        .sample_batch(&[], None, &[], &mut [], &mut [])
        .unwrap();
}

#[test]
fn record_batch_records_what_record_does() {
    let workload = Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 3,
        bsdf: None,
    };
    let field = GuidingField::new(room_bounds(), GuidingConfig::default()).unwrap();
    let mut rng = Rng::new(9);
    let mut samples: Vec<Sample> = (0..5000).map(|_| workload.draw(&field, &mut rng)).collect();
    // Every hundredth sample is bad: a NaN value.
    for s in samples.iter_mut().step_by(100) {
        s.value = f32::NAN;
    }
    let (one, batch) = (field.clone(), field.clone());
    for s in &samples {
        one.record(s);
    }
    assert_eq!(batch.record_batch(&samples), 50);
    let (a, b) = (one.stats(), batch.stats());
    assert_eq!(
        (a.samples_recorded, a.rejected),
        (b.samples_recorded, b.rejected)
    );
    assert_eq!(b.rejected.bad_value, 50);
    // The same cells saw the same samples: their counts agree (their sums only to rounding,
    // as the threads' order of adding is theirs).
    for (x, y) in one.cells().zip(batch.cells()) {
        let counts = |m: Vec<(sdguide::DirectionalCell, sdguide::Moments)>| {
            m.iter().map(|(_, m)| m.count).collect::<Vec<_>>()
        };
        assert_eq!(counts(x.recorded()), counts(y.recorded()));
    }
}
