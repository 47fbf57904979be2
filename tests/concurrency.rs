//! Recording from many threads loses nothing: per-leaf moments equal a serial recording's, to
//! the bit.

use sdguide::{DirectionalFilter, GuidingConfig, GuidingField, Moments, Sample};
use sdguide_lab::rng::Rng;
use sdguide_lab::synthetic::{LightField, Workload};

/// A field with a non-trivial topology (several spatial leaves, deep quadtrees).
fn pretrained(workload: &Workload, directional_filter: DirectionalFilter) -> GuidingField {
    let config = GuidingConfig {
        directional_filter,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(sdguide_lab::synthetic::room_bounds(), config).unwrap();
    workload.train(&mut field, 3, 100_000);
    field
}

fn moments(field: &GuidingField) -> Vec<Moments> {
    field
        .cells()
        .flat_map(|c| c.recorded().into_iter().map(|(_, m)| m))
        .collect()
}

#[test]
fn concurrent_recording_equals_serial_recording() {
    let workload = Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 99,
        bsdf: None,
    };
    for filter in [
        DirectionalFilter::Nearest,
        DirectionalFilter::Box,
        DirectionalFilter::DeferredBox,
    ] {
        compare_serial_and_concurrent(&pretrained(&workload, filter), &workload, filter);
    }
}

fn compare_serial_and_concurrent(
    base: &GuidingField,
    workload: &Workload,
    filter: DirectionalFilter,
) {
    let per_thread = 1_000_000usize;
    for threads in [2usize, 4, 8] {
        let batches: Vec<Vec<Sample>> = (0..threads)
            .map(|t| {
                let mut rng = Rng::new(1000 + t as u64);
                (0..per_thread)
                    .map(|_| workload.draw(base, &mut rng))
                    .collect()
            })
            .collect();
        let serial = base.clone();
        for b in &batches {
            serial.record_all(b);
        }
        let concurrent = base.clone();
        std::thread::scope(|s| {
            for b in &batches {
                let field = &concurrent;
                s.spawn(move || field.record_all(b));
            }
        });
        let (a, b) = (moments(&serial), moments(&concurrent));
        assert_eq!(a.len(), b.len());
        assert!(
            a.len() > 100,
            "the topology should be non-trivial: {} leaves",
            a.len()
        );
        let total: u64 = b.iter().map(|m| m.count).sum();
        assert_eq!(total, (threads * per_thread) as u64, "{threads} threads");
        // The sums are exact integers: every leaf's moments equal, to the bit, whatever the
        // order the threads interleaved in.
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x, y, "{filter:?}, {threads} threads");
        }
    }
}
