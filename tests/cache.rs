//! The cache: round trips exactly, refuses every malformed input with an error (never a
//! panic), keeps reading old files, and merges workers' statistics exactly.

use common::{assemble, parts};
use glam::Vec3;
use sdguide::MAX_GUIDE_PROBABILITY;
use sdguide::{
    CacheError, Continuation, ContinuationEstimate, DirectionalFilter, GuidingConfig, GuidingField,
    MergeError, Refinement, Sample, SpatialSplit,
};
use sdguide_lab::rng::Rng;

mod common;
use sdguide_lab::synthetic::{Bsdf, LightField, Workload, room_bounds, room_vertex};

fn workload() -> Workload {
    Workload {
        light: LightField::standard(),
        lobe_noise: 1.0,
        seed: 5,
        bsdf: None,
    }
}

/// A small but real field: a few spatial leaves, trees several levels deep, continuation
/// estimates, and statistics recorded in the current iteration.
fn small_field() -> GuidingField {
    small_field_with(DirectionalFilter::default())
}

/// [`small_field`] with another directional filter. Under the deferred box filter the current
/// iteration's sums are still pending when the field is saved or merged.
fn small_field_with(directional_filter: DirectionalFilter) -> GuidingField {
    let config = GuidingConfig {
        spatial_threshold: 400.0,
        subdivision_threshold: 0.05,
        directional_filter,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(room_bounds(), config).unwrap();
    workload().train(&mut field, 1, 8_000);
    record_continuations(&field, 1, 4_000);
    workload().record_iteration(&field, 1, 16_000);
    field.refine();
    workload().record_iteration(&field, 2, 300);
    record_continuations(&field, 2, 500);
    field.record(&Sample {
        position: Vec3::splat(f32::NAN),
        direction: Vec3::Z,
        value: 1.0,
        pdf: 1.0,
        ..Sample::default()
    });
    field
}

/// `n` continuations at the positions of workload samples, with values and costs that vary.
fn continuations(seed: u64, n: usize, field: &GuidingField) -> Vec<Continuation> {
    samples(seed, n, field)
        .iter()
        .enumerate()
        .map(|(i, s)| Continuation {
            position: s.position,
            value: 0.3 * s.value,
            cost: 1.0 + (i % 7) as f32,
        })
        .collect()
}

fn record_continuations(field: &GuidingField, seed: u64, n: usize) {
    for c in continuations(seed ^ 0xC0, n, field) {
        field.record_continuation(&c);
    }
}

fn samples(seed: u64, n: usize, field: &GuidingField) -> Vec<Sample> {
    let mut rng = Rng::new(seed);
    (0..n).map(|_| workload().draw(field, &mut rng)).collect()
}

/// The directional filters whose recording state the cache and `merge` must carry.
const FILTERS: [DirectionalFilter; 2] = [DirectionalFilter::Box, DirectionalFilter::DeferredBox];

/// Every query, every recorded moment and every counter of two fields agree exactly.
fn assert_same(a: &GuidingField, b: &GuidingField) {
    assert_eq!(a.stats(), b.stats());
    assert_eq!(a.config(), b.config());
    assert_eq!(a.bounds(), b.bounds());
    let mut rng = Rng::new(77);
    for _ in 0..2000 {
        let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        assert_eq!(a.continuation(x), b.continuation(x));
        let (da, db) = (a.distribution(x), b.distribution(x));
        assert_eq!(da.guide_probability(), db.guide_probability());
        let u = rng.next_vec2();
        let (dir, pdf) = da.sample(u);
        assert_eq!((dir, pdf), db.sample(u));
        assert_eq!(pdf.to_bits(), db.pdf(dir).to_bits());
        // At the room's surfaces, through the stored products where the cells have them.
        let (x, n) = room_vertex([rng.next_f32(), rng.next_f32(), rng.next_f32()]);
        let (sa, sb) = (
            a.distribution(x).at_surface(n),
            b.distribution(x).at_surface(n),
        );
        let (dir, pdf) = sa.sample(u);
        assert_eq!((dir, pdf), sb.sample(u));
        assert_eq!(pdf.to_bits(), sb.pdf(dir).to_bits());
    }
    for (ca, cb) in a.cells().zip(b.cells()) {
        assert_eq!(ca.bounds, cb.bounds);
        assert_eq!(ca.distribution().leaves(), cb.distribution().leaves());
        assert_eq!(ca.recorded(), cb.recorded());
    }
}

#[test]
fn a_loaded_field_is_the_saved_field_and_training_continues() {
    for filter in FILTERS {
        let field = small_field_with(filter);
        assert!(field.stats().spatial_leaves > 2 && field.stats().directional_depth > 2);
        let estimated = field
            .cells()
            .filter(|c| field.continuation(c.bounds.center()).count >= 16)
            .count();
        assert!(
            estimated > 2,
            "{estimated} cells with a continuation estimate"
        );
        assert!(field.stats().continuations_recorded == 500);
        let mut bytes = Vec::new();
        field.save(&mut bytes).unwrap();
        assert_eq!(bytes, field.to_bytes());
        let loaded = GuidingField::load(bytes.as_slice()).unwrap();
        assert_same(&field, &loaded);
        // Training continues identically from either.
        let (mut a, mut b) = (field, loaded);
        let more = samples(3, 5000, &a);
        a.record_all(&more);
        b.record_all(&more);
        assert_same(&a, &b);
        a.refine();
        b.refine();
        assert_same(&a, &b);
    }
}

#[test]
fn save_to_path_replaces_the_file_atomically() {
    let dir = std::env::temp_dir().join(format!("sdguide-cache-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("field.sdgc");
    let first = small_field();
    first.save_to_path(&path).unwrap();
    assert_same(&first, &GuidingField::load_from_path(&path).unwrap());
    let mut second = first.clone();
    second.refine();
    second.save_to_path(&path).unwrap();
    assert_same(&second, &GuidingField::load_from_path(&path).unwrap());
    // A save that cannot complete (the target is a directory) leaves everything as it was
    // and no temporary file behind.
    let blocked = dir.join("blocked");
    std::fs::create_dir_all(blocked.join("inside")).unwrap();
    assert!(matches!(
        first.save_to_path(&blocked),
        Err(CacheError::Io(_))
    ));
    assert!(blocked.join("inside").is_dir());
    assert_same(&second, &GuidingField::load_from_path(&path).unwrap());
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_truncation_and_every_byte_flip_is_an_error() {
    let bytes = small_field().to_bytes();
    assert!(bytes.len() > 1000, "{} bytes", bytes.len());
    eprintln!("cache of {} bytes", bytes.len());
    for len in 0..bytes.len() {
        match GuidingField::from_bytes(&bytes[..len]) {
            Err(CacheError::Truncated { found, .. }) => assert_eq!(found, len as u64),
            other => panic!("truncated to {len}: {other:?}"),
        }
    }
    let mut flipped = bytes.clone();
    for i in 0..bytes.len() {
        for mask in [0x01u8, 0x80, 0xff] {
            flipped[i] ^= mask;
            assert!(
                GuidingField::from_bytes(&flipped).is_err(),
                "byte {i} ^ {mask:#x} loaded"
            );
            flipped[i] ^= mask;
        }
    }
    assert!(GuidingField::from_bytes(&flipped).is_ok());
}

#[test]
fn newer_minor_versions_load_and_newer_majors_do_not() {
    let field = small_field();
    let bytes = field.to_bytes();
    assert_eq!(
        assemble((3, 3), &parts(&bytes)),
        bytes,
        "the test's writer matches the library's"
    );
    // Without the continuations (an optional section): it loads, with no continuation
    // estimates and everything else as saved.
    let without: Vec<_> = parts(&bytes).into_iter().filter(|p| p.0 != 6).collect();
    let older = GuidingField::from_bytes(&assemble((3, 3), &without)).unwrap();
    assert_eq!(older.stats().continuations_recorded, 0);
    assert!(
        older
            .cells()
            .all(|c| older.continuation(c.bounds.center()) == ContinuationEstimate::default())
    );
    assert_eq!(older.to_bytes().len(), bytes.len());
    // Without the surface tallies: it loads, with no stored products (queries take the
    // per-query product), and everything else as saved.
    let without: Vec<_> = parts(&bytes).into_iter().filter(|p| p.0 != 7).collect();
    let older = GuidingField::from_bytes(&assemble((3, 3), &without)).unwrap();
    assert!(field.stats().surface_products > 0);
    assert_eq!(older.stats().surface_products, 0);
    for (a, b) in field.cells().zip(older.cells()) {
        assert_eq!(a.distribution().leaves(), b.distribution().leaves());
    }
    // A 3.3 file with an optional section this reader does not know, and a longer META.
    let mut newer = parts(&bytes);
    newer[0].2.extend_from_slice(&[0xAB; 40]);
    newer.insert(1, (99, 0, vec![1, 2, 3]));
    let loaded = GuidingField::from_bytes(&assemble((3, 3), &newer)).unwrap();
    assert_same(&field, &loaded);
    // An unknown section marked required is refused.
    let mut required = parts(&bytes);
    required.push((99, 1, vec![]));
    assert!(matches!(
        GuidingField::from_bytes(&assemble((3, 3), &required)),
        Err(CacheError::Corrupt {
            section: "sections",
            ..
        })
    ));
    match GuidingField::from_bytes(&assemble((4, 0), &parts(&bytes))) {
        Err(CacheError::UnsupportedVersion { found, supported }) => {
            assert_eq!((found, supported), ((4, 0), (3, 3)));
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        GuidingField::from_bytes(b"GIF89a......"),
        Err(CacheError::BadMagic)
    ));
}

/// Replaces 4 bytes at `at` of section `kind` and reassembles with a valid checksum.
fn forge(bytes: &[u8], kind: u32, at: usize, value: [u8; 4]) -> Result<GuidingField, CacheError> {
    let mut p = parts(bytes);
    let body = &mut p.iter_mut().find(|s| s.0 == kind).unwrap().2;
    body[at..at + 4].copy_from_slice(&value);
    GuidingField::from_bytes(&assemble((3, 3), &p))
}

#[test]
fn forged_files_with_valid_checksums_are_still_refused() {
    let bytes = small_field().to_bytes();
    let corrupt = |r: Result<GuidingField, CacheError>, section: &str, words: &str| match r {
        Err(CacheError::Corrupt { section: s, detail }) => {
            assert_eq!(s, section, "{detail}");
            assert!(detail.contains(words), "{detail}");
        }
        other => panic!("expected corrupt {section}: {other:?}"),
    };
    // META: a configuration out of range.
    corrupt(
        forge(&bytes, 1, 8, 5.0f32.to_le_bytes()),
        "meta",
        "subdivision_threshold",
    );
    // SPATIAL: a node count far beyond the bytes there (no allocation is attempted).
    corrupt(
        forge(&bytes, 2, 0, u32::MAX.to_le_bytes()),
        "spatial",
        "declared",
    );
    // SPATIAL: the root's children pointing back at the root (a cycle).
    corrupt(
        forge(&bytes, 2, 4, 0u32.to_le_bytes()),
        "spatial",
        "points to",
    );
    // SURFACES: a slot with flags no version defines (tree 0's first slot, after the count
    // and the tree's two words).
    corrupt(
        forge(&bytes, 7, 4 + 8, 0xFFu32.to_le_bytes()),
        "surfaces",
        "flags",
    );
    // SURFACES: a normal that is not of unit length, in a held slot (flags, count, then the
    // words: 0, the components, 0).
    let mut p = parts(&bytes);
    let body = &mut p.iter_mut().find(|s| s.0 == 7).unwrap().2;
    body[4 + 8..4 + 12].copy_from_slice(&1u32.to_le_bytes());
    body[4 + 16..4 + 56].fill(0);
    body[4 + 24..4 + 28].copy_from_slice(&3.0f32.to_le_bytes());
    corrupt(
        GuidingField::from_bytes(&assemble((3, 3), &p)),
        "surfaces",
        "normal",
    );
    // DIRECTIONAL: a probability that is NaN.
    corrupt(
        forge(&bytes, 3, 8, f32::NAN.to_le_bytes()),
        "directional",
        "probabilities",
    );
    // DIRECTIONAL: a child index past the end of the sampling tree.
    let first_child = 4 + 4 + 24;
    corrupt(
        forge(&bytes, 3, first_child, [0xff, 0xff, 0, 0]),
        "directional",
        "points to",
    );
    // DIRECTIONAL: a sum past the range (2^126 units) in the first tree's first leaf: its
    // top word's high bits set.
    let p = parts(&bytes);
    let dir = &p[2].2;
    let ns = u32::from_le_bytes(dir[4..8].try_into().unwrap()) as usize;
    let nr_at = 8 + 32 * ns;
    let nr = u32::from_le_bytes(dir[nr_at..nr_at + 4].try_into().unwrap()) as usize;
    let first_sum = nr_at + 4 + 16 * nr + 4;
    corrupt(
        forge(&bytes, 3, first_sum + 12, [0, 0, 0, 0x80]),
        "directional",
        "range",
    );
    // META: a leaf rule this version does not define.
    corrupt(
        forge(&bytes, 1, 0, [7, 0, 0, 0]),
        "meta",
        "unknown leaf rule",
    );
    // META 1.1: a filter this version does not define, a negative prior.
    corrupt(
        forge(&bytes, 1, 180, [7, 0, 0, 0]),
        "meta",
        "spatial filter",
    );
    corrupt(
        forge(&bytes, 1, 176, (-1.0f32).to_le_bytes()),
        "meta",
        "prior_samples",
    );
    // META 1.2: a refinement this version does not define, a gain threshold out of range.
    corrupt(
        forge(&bytes, 1, 184, [7, 0, 0, 0]),
        "meta",
        "unknown refinement",
    );
    corrupt(
        forge(&bytes, 1, 188, 2.0f32.to_le_bytes()),
        "meta",
        "gain_threshold",
    );
    // META 2.4: a guide probability bound out of range; 2.6: a guide cost out of range.
    corrupt(
        forge(&bytes, 1, 192, 0.99f32.to_le_bytes()),
        "meta",
        "max_guide_probability",
    );
    for cost in [f32::NAN, 101.0, f32::INFINITY] {
        corrupt(
            forge(&bytes, 1, 196, cost.to_le_bytes()),
            "meta",
            "guide_cost",
        );
    }
    // GUIDE_COST: a count that differs from the trees', flags this version does not define, a
    // second moment past the range.
    corrupt(
        forge(&bytes, 8, 0, 999u32.to_le_bytes()),
        "guide cost",
        "declared",
    );
    corrupt(
        forge(&bytes, 8, 4, 2u32.to_le_bytes()),
        "guide cost",
        "flags",
    );
    corrupt(
        forge(&bytes, 8, 4 + 8 + 12, [0, 0, 0, 0x80]),
        "guide cost",
        "range",
    );
    // QUADRANTS: a tree count that differs from the trees', a leaf count that differs from
    // the first tree's, a sum past the range.
    corrupt(
        forge(&bytes, 5, 0, 1u32.to_le_bytes()),
        "quadrants",
        "trees",
    );
    corrupt(
        forge(&bytes, 5, 4, 1u32.to_le_bytes()),
        "quadrants",
        "leaves",
    );
    corrupt(
        forge(&bytes, 5, 8 + 12, [0, 0, 0, 0x80]),
        "quadrants",
        "range",
    );
    // SELECTION: a count that differs from the trees', a probability out of its bounds, a
    // curvature sum past the range.
    corrupt(
        forge(&bytes, 4, 0, 999u32.to_le_bytes()),
        "selection",
        "declared",
    );
    corrupt(
        forge(&bytes, 4, 4, 0.99f32.to_le_bytes()),
        "selection",
        "probability",
    );
    corrupt(
        forge(&bytes, 4, 4 + 8 + 16 + 12, [0, 0, 0, 0x80]),
        "selection",
        "range",
    );
    // CONTINUATIONS: a count that differs from the trees', a negative sum of squares in the
    // first tree's estimate, a cost in the recorded sums of a leaf that counted nothing.
    corrupt(
        forge(&bytes, 6, 0, 1u32.to_le_bytes()),
        "continuations",
        "estimates",
    );
    corrupt(
        forge(
            &bytes,
            6,
            4 + 8 + 4,
            (-1.0f64).to_bits().to_le_bytes()[4..].try_into().unwrap(),
        ),
        "continuations",
        "estimate",
    );
    let p = parts(&bytes);
    let body = &p.iter().find(|s| s.0 == 6).unwrap().2;
    // Each tree: the estimate (three f64 and a count, 32 bytes), the recorded sums (three
    // exact sums and a count, 56 bytes).
    let empty = (0..body.len().saturating_sub(4) / 88)
        .find(|&i| body[4 + 88 * i + 80..4 + 88 * i + 88] == [0; 8])
        .expect("a tree that recorded no continuation in the iteration");
    corrupt(
        forge(&bytes, 6, 4 + 88 * empty + 32 + 32, [1, 0, 0, 0]),
        "continuations",
        "recorded",
    );
}

#[test]
fn a_version_one_file_is_refused_with_a_typed_error() {
    // Written by this library at format 1.0 (kept from then). Its trees
    // are on the cylindrical map; read as 2.x they would guide toward other directions, so a
    // 2.x reader refuses the file, with the versions in the error.
    match GuidingField::load_from_path("tests/data/v1.sdgc") {
        Err(CacheError::UnsupportedVersion { found, supported }) => {
            assert_eq!((found, supported), ((1, 0), (3, 3)));
        }
        other => panic!("{other:?}"),
    }
}

/// A cache written by the 2.6 library (`f64` sums), kept in `tests/data`: `start` was saved
/// right after `refine` (every sum zero), `mid` with an iteration's samples recorded,
/// `guides-off` after training with a guide cost that turned some guides off.
fn legacy(name: &str) -> Vec<u8> {
    std::fs::read(format!("tests/data/v2.6-{name}.sdgc")).unwrap()
}

#[test]
fn a_two_six_file_saved_at_an_iteration_start_converts_exactly() {
    let bytes = legacy("start");
    let field = GuidingField::from_bytes(&bytes).unwrap();
    assert!(field.stats().spatial_leaves > 1 && field.stats().surface_products > 0);
    assert_eq!(field.stats().samples_recorded, 0);
    // Saved as 3.0, loaded again: the same field.
    let again = GuidingField::from_bytes(&field.to_bytes()).unwrap();
    assert_same(&field, &again);
    // Training continues from it.
    let mut field = field;
    workload().record_iteration(&field, 9, 3_000);
    field.refine();
    assert_eq!(field.stats().iteration, 3);
}

#[test]
fn a_two_six_file_saved_mid_iteration_is_refused_with_a_typed_error() {
    // Its sums are floating point, and almost none is a multiple of 2^-40: no exact sum of
    // 3.0 equals it, and rounding would make two workers' files disagree with one machine's.
    match GuidingField::from_bytes(&legacy("mid")) {
        Err(e @ CacheError::Inexact { section, value }) => {
            assert_eq!(section, "directional");
            assert!(value.is_finite() && value > 0.0);
            assert!(e.to_string().contains("mid-iteration"), "{e}");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_file_without_the_refinement_fields_keeps_refining_by_flux_share() {
    // META in its 1.1 layout (without the refinement fields), no quadrant sums: the reader
    // takes the fields it needs at least and defaults the rest, as for any shorter META.
    let bytes = legacy("start");
    let field = GuidingField::from_bytes(&bytes).unwrap();
    let mut old = parts(&bytes);
    old[0].2.truncate(184);
    old.retain(|p| p.0 != 5);
    let loaded = GuidingField::from_bytes(&assemble((2, 0), &old)).unwrap();
    assert_eq!(loaded.config().refinement, Refinement::FluxShare);
    assert_eq!(
        loaded.config().gain_threshold,
        GuidingConfig::default().gain_threshold
    );
    assert_eq!(loaded.stats(), field.stats());
}

#[test]
fn a_file_without_the_guide_probability_bound_keeps_the_widest() {
    // META in its 2.3 layout: the field learned its guide probabilities up to 0.95, and goes on
    // so; everything else loads as saved.
    let bytes = legacy("start");
    let field = GuidingField::from_bytes(&bytes).unwrap();
    let mut old = parts(&bytes);
    old[0].2.truncate(192);
    let loaded = GuidingField::from_bytes(&assemble((2, 3), &old)).unwrap();
    assert_eq!(loaded.config().max_guide_probability, MAX_GUIDE_PROBABILITY);
    assert_eq!(loaded.config().guide_cost, None);
    assert_eq!(
        GuidingConfig {
            max_guide_probability: field.config().max_guide_probability,
            guide_cost: field.config().guide_cost,
            ..loaded.config().clone()
        },
        *field.config()
    );
    assert_eq!(loaded.stats(), field.stats());
}

/// The workload with a BSDF beside the guide: samples carry mixture terms.
fn mixture_workload() -> Workload {
    Workload {
        bsdf: Some(Bsdf {
            axis: Vec3::Z,
            kappa: 2.0,
        }),
        ..workload()
    }
}

/// A new field whose guide cost turns some guides off on [`mixture_workload`].
fn untrained_mixture_field() -> GuidingField {
    let config = GuidingConfig {
        spatial_threshold: 400.0,
        subdivision_threshold: 0.05,
        guide_cost: Some(2.0),
        ..GuidingConfig::default()
    };
    GuidingField::new(room_bounds(), config).unwrap()
}

/// A field trained on [`mixture_workload`], some guides off, the current iteration's sums
/// recorded.
fn mixture_field() -> GuidingField {
    let work = mixture_workload();
    let mut field = untrained_mixture_field();
    work.train(&mut field, 3, 8_000);
    work.record_iteration(&field, 7, 6_000);
    field
}

#[test]
fn guides_turned_off_load_as_saved_and_older_files_never_turn_one_off() {
    let field = mixture_field();
    let stats = field.stats();
    assert!(
        stats.guides_off > 0 && stats.guides_off < stats.spatial_leaves,
        "{} of {} guides off",
        stats.guides_off,
        stats.spatial_leaves
    );
    let bytes = field.to_bytes();
    let loaded = GuidingField::from_bytes(&bytes).unwrap();
    assert_same(&field, &loaded);
    // The sums recorded since the last refine decide the same at the next one.
    let (mut a, mut b) = (field, loaded);
    a.refine();
    b.refine();
    assert_same(&a, &b);
    // A 2.5 file: no guide-cost section, META without the cost. Every guide is on (at the
    // probability it learned), and stays on.
    let bytes = legacy("guides-off");
    assert!(GuidingField::from_bytes(&bytes).unwrap().stats().guides_off > 0);
    let mut old = parts(&bytes);
    old[0].2.truncate(196);
    old.retain(|p| p.0 != 8);
    let mut older = GuidingField::from_bytes(&assemble((2, 5), &old)).unwrap();
    assert_eq!(older.config().guide_cost, None);
    assert_eq!(older.stats().guides_off, 0);
    assert!(
        older
            .cells()
            .all(|c| c.distribution().guide_probability() >= 0.05)
    );
    older.refine();
    assert_eq!(older.stats().guides_off, 0);
}

#[test]
fn cells_that_record_continuations_keep_their_guides_on() {
    // The same samples with and without a continuation recorded at each sample's position
    // (what a renderer playing efficiency-aware roulette or splitting does): without, some
    // guides turn off; with, none does.
    let train = |continuations: bool| {
        let work = mixture_workload();
        let mut field = untrained_mixture_field();
        for k in 0..3u64 {
            let mut rng = Rng::new(40 + k);
            for _ in 0..(8_000 << k) {
                let s = work.draw(&field, &mut rng);
                field.record(&s);
                if continuations {
                    field.record_continuation(&Continuation {
                        position: s.position,
                        value: s.value,
                        cost: 2.0,
                    });
                }
            }
            field.refine();
        }
        field.stats().guides_off
    };
    assert!(train(false) > 0);
    assert_eq!(train(true), 0);
}

#[test]
fn merged_workers_turn_the_same_guides_off_as_one_process() {
    let mut base = mixture_field();
    base.refine();
    let broadcast = base.to_bytes();
    let worker = || GuidingField::from_bytes(&broadcast).unwrap();
    let (mut a, b, mut union) = (worker(), worker(), worker());
    let work = mixture_workload();
    let mut rng = Rng::new(21);
    let drawn: Vec<Sample> = (0..30_000).map(|_| work.draw(&a, &mut rng)).collect();
    let (s1, s2) = drawn.split_at(14_000);
    a.record_all(s1);
    b.record_all(s2);
    union.record_all(&drawn);
    a.merge(&b).unwrap();
    a.refine();
    union.refine();
    // The same sums in two groupings decide the same (no leaf sits on its threshold to within
    // rounding), and so do the learned probabilities, to f32 rounding.
    assert_eq!(a.stats().guides_off, union.stats().guides_off);
    assert!(a.stats().guides_off > 0);
    for (ca, cu) in a.cells().zip(union.cells()) {
        let (pa, pu) = (
            ca.distribution().guide_probability(),
            cu.distribution().guide_probability(),
        );
        assert!((pa - pu).abs() <= f32::EPSILON, "{pa} vs {pu}");
    }
}

#[test]
fn merged_workers_refine_exactly_like_one_process() {
    for filter in FILTERS {
        merged_workers_refine_like_one_process(filter);
    }
}

fn merged_workers_refine_like_one_process(filter: DirectionalFilter) {
    let base = GuidingField::from_bytes(&small_field_with(filter).to_bytes()).unwrap();
    let mut base = base;
    base.refine(); // start the iteration clean, as a broadcast cache would
    let broadcast = base.to_bytes();
    let worker = || GuidingField::from_bytes(&broadcast).unwrap();
    let (mut a, b, mut union) = (worker(), worker(), worker());
    let (s1, s2) = (samples(10, 20_000, &a), samples(11, 20_000, &a));
    let (c1, c2) = (continuations(12, 3_000, &a), continuations(13, 3_000, &a));
    a.record_all(&s1);
    b.record_all(&s2);
    for (c, field) in c1.iter().map(|c| (c, &a)).chain(c2.iter().map(|c| (c, &b))) {
        field.record_continuation(c);
    }
    for c in c1.iter().chain(&c2) {
        union.record_continuation(c);
    }
    b.record(&Sample {
        position: Vec3::ZERO,
        direction: Vec3::Z,
        value: -1.0,
        pdf: 1.0,
        ..Sample::default()
    });
    union.record_all(&s1);
    union.record_all(&s2);
    union.record(&Sample {
        position: Vec3::ZERO,
        direction: Vec3::Z,
        value: -1.0,
        pdf: 1.0,
        ..Sample::default()
    });
    a.merge(&b).unwrap();
    assert_eq!(a.stats(), union.stats());
    for (ca, cu) in a.cells().zip(union.cells()) {
        for ((la, ma), (lu, mu)) in ca.recorded().iter().zip(&cu.recorded()) {
            assert_eq!((la, ma.count), (lu, mu.count));
            // The same non-negative terms summed in two groupings: each sum is within
            // (n − 1)·ε of the exact one, for n terms. A leaf's terms are not only its counted
            // samples: the box filter adds shares of samples counted elsewhere (a leaf may have
            // sums and a count of 0), at most four folded pieces per sample. (Deferred, the
            // groupings are the quadrants' sums, spread at the same points.)
            let tol = 2.0 * 4.0 * (s1.len() + s2.len() + 1) as f64 * f64::EPSILON;
            assert!((ma.sum - mu.sum).abs() <= tol * mu.sum, "{ma:?} {mu:?}");
            assert!(
                (ma.sum_sq - mu.sum_sq).abs() <= tol * mu.sum_sq,
                "{ma:?} {mu:?}"
            );
        }
    }
    a.refine();
    union.refine();
    assert_eq!(a.stats(), union.stats());
    for (ca, cu) in a.cells().zip(union.cells()) {
        // The continuation sums: the same terms in two groupings, as above.
        let x = ca.bounds.center();
        let (ea, eu) = (a.continuation(x), union.continuation(x));
        assert_eq!(ea.count, eu.count);
        let tol = 2.0 * (c1.len() + c2.len()) as f64 * f64::EPSILON;
        for (p, q) in [(ea.sum, eu.sum), (ea.sum_sq, eu.sum_sq), (ea.cost, eu.cost)] {
            assert!((p - q).abs() <= tol * q, "{ea:?} {eu:?}");
        }
        let (la, lu) = (ca.distribution().leaves(), cu.distribution().leaves());
        assert_eq!(la.len(), lu.len());
        for ((cell_a, pa), (cell_u, pu)) in la.iter().zip(&lu) {
            assert_eq!(cell_a, cell_u);
            assert!((pa - pu).abs() <= 1e-6 * pu, "{pa} vs {pu}");
        }
    }
    let mut rng = Rng::new(1);
    for _ in 0..1000 {
        let x = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let d = sdguide::sphere::square_to_direction(rng.next_vec2());
        let (pa, pu) = (a.distribution(x).pdf(d), union.distribution(x).pdf(d));
        assert!((pa - pu).abs() <= 1e-5 * pu);
    }
}

#[test]
fn merging_fields_that_did_not_start_together_is_refused_untouched() {
    let base = small_field();
    let mut ahead = base.clone();
    ahead.refine();
    let mut a = base.clone();
    assert_eq!(
        a.merge(&ahead),
        Err(MergeError::IterationDiffers { ours: 2, theirs: 3 })
    );
    let other_config = GuidingField::new(
        room_bounds(),
        GuidingConfig {
            spatial_threshold: 301.0,
            ..GuidingConfig::default()
        },
    )
    .unwrap();
    assert_eq!(a.merge(&other_config), Err(MergeError::ConfigDiffers));
    // Same configuration and iteration, different training: different trees.
    let mut other = GuidingField::new(room_bounds(), a.config().clone()).unwrap();
    Workload {
        seed: 6,
        ..workload()
    }
    .train(&mut other, 2, 2_000);
    assert!(matches!(
        a.merge(&other),
        Err(MergeError::TopologyDiffers { .. })
    ));
    assert_same(&a, &base);
}

#[test]
fn a_three_zero_file_loads_as_a_field_without_volumes() {
    // 3.0 is 3.3 without the META's last 40 bytes (flags, the medium samples' rejection
    // counters, `filter_samples`, the spatial split rule) and without volume sections; its
    // masses were the filtered sums alone.
    let field = small_field();
    let bytes = field.to_bytes();
    let mut older = parts(&bytes);
    assert!(older.iter().all(|p| p.0 < 10));
    let meta = &mut older[0].2;
    meta.truncate(meta.len() - 40);
    let loaded = GuidingField::from_bytes(&assemble((3, 0), &older)).unwrap();
    assert!(!loaded.config().volumes);
    assert_same(&field, &loaded);
    assert_eq!(loaded.to_bytes(), bytes);
}

/// `field` (whose `filter_samples` is `None`) with `filter_samples` at 128, by its bytes.
fn blended(field: GuidingField) -> GuidingField {
    assert_eq!(field.config().filter_samples, None);
    let mut p = parts(&field.to_bytes());
    assert_eq!(p[0].2[240..244], (-1.0f32).to_le_bytes());
    p[0].2[240..244].copy_from_slice(&128.0f32.to_le_bytes());
    GuidingField::from_bytes(&assemble((3, 3), &p)).unwrap()
}

#[test]
fn a_three_one_file_keeps_its_filtered_masses_and_a_three_two_file_its_blend() {
    let field = blended(small_field());
    assert_eq!(field.config().filter_samples, Some(128.0));
    let bytes = field.to_bytes();
    assert_same(&field, &GuidingField::from_bytes(&bytes).unwrap());
    // 3.1: META without its last 16 bytes. It loads with `None`, and the next refine computes
    // its masses from the filtered sums, as a 3.1 library did: it differs from the blend.
    let mut older = parts(&bytes);
    let meta = &mut older[0].2;
    meta.truncate(meta.len() - 16);
    let mut old = GuidingField::from_bytes(&assemble((3, 1), &older)).unwrap();
    assert_eq!(old.config().filter_samples, None);
    let mut expected = small_field();
    let mut blend = field;
    for f in [&mut old, &mut expected, &mut blend] {
        f.refine();
    }
    assert_same(&old, &expected);
    assert!(
        old.cells()
            .zip(blend.cells())
            .any(|(a, b)| a.distribution().leaves() != b.distribution().leaves()),
        "the blend changes some masses"
    );
    // A negative count is `None`; NaN is refused.
    for (value, ok) in [(-1.0f32, true), (f32::NAN, false), (f32::INFINITY, false)] {
        let mut p = parts(&bytes);
        p[0].2[240..244].copy_from_slice(&value.to_le_bytes());
        assert_eq!(
            GuidingField::from_bytes(&assemble((3, 3), &p)).is_ok(),
            ok,
            "{value}"
        );
    }
}

#[test]
fn a_field_split_by_gain_keeps_its_signatures_and_a_three_two_file_splits_by_count() {
    let config = GuidingConfig {
        spatial_threshold: 400.0,
        spatial_split: SpatialSplit::Gain,
        spatial_gain_threshold: 0.02,
        ..GuidingConfig::default()
    };
    let mut field = GuidingField::new(room_bounds(), config).unwrap();
    workload().train(&mut field, 1, 8_000);
    workload().record_iteration(&field, 1, 16_000);
    let bytes = field.to_bytes();
    let mut loaded = GuidingField::from_bytes(&bytes).unwrap();
    assert_same(&field, &loaded);
    assert_eq!(loaded.to_bytes(), bytes);
    // The signatures travel: the refine after loading splits as the one without.
    field.refine();
    loaded.refine();
    assert_eq!(loaded.to_bytes(), field.to_bytes());
    // Without the signatures section the iteration's signatures start at zero: nothing
    // splits by gain.
    let before = GuidingField::from_bytes(&bytes)
        .unwrap()
        .stats()
        .spatial_leaves;
    let without: Vec<_> = parts(&bytes).into_iter().filter(|p| p.0 != 15).collect();
    let mut blind = GuidingField::from_bytes(&assemble((3, 3), &without)).unwrap();
    blind.refine();
    assert_eq!(blind.stats().spatial_leaves, before);
    assert!(field.stats().spatial_leaves > before);
    // 3.2: META without its last 8 bytes: split by count.
    let mut older = parts(&bytes);
    older.retain(|p| p.0 != 15);
    let meta = &mut older[0].2;
    meta.truncate(meta.len() - 8);
    let old = GuidingField::from_bytes(&assemble((3, 2), &older)).unwrap();
    assert_eq!(old.config().spatial_split, SpatialSplit::Count);
    // An unknown rule is refused.
    let mut p = parts(&bytes);
    p[0].2[248] = 7;
    assert!(matches!(
        GuidingField::from_bytes(&assemble((3, 3), &p)),
        Err(CacheError::Corrupt {
            section: "meta",
            ..
        })
    ));
}
