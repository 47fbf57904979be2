//! The path recorder against paths computed by hand: incident values, second moments with
//! roulette and splitting, zero-valued records below the surface, delta vertices, and bad
//! input.

use sdguide::glam::Vec3;
use sdguide::{Aabb, GuidingConfig, GuidingField, PathRecord, PathRecorder, PathVertex, VertexId};

fn lum(v: Vec3) -> f32 {
    v.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-5 * a.abs().max(b.abs()).max(1.0)
}

/// A vertex at height `i` drawing straight up with `f·cos` `f` and pdf `q`.
fn vertex(i: f32, f: f32, q: f32) -> PathVertex {
    PathVertex::new(Vec3::new(0.5, i, 0.5), Vec3::Y, Vec3::splat(f), q)
        .with_normal(Vec3::Y)
        .with_mixture(q, 0.5 * q)
}

fn records(path: &PathRecorder) -> Vec<PathRecord> {
    path.records().collect()
}

fn record_of(path: &PathRecorder, id: VertexId) -> PathRecord {
    path.records().find(|r| r.id == id).expect("a record")
}

#[test]
fn a_three_vertex_path_records_what_arrived_at_each_vertex() {
    // Camera → x1 (NEE 0.5) → x2 (NEE 0.25, emission 2 hit from x1) → x3 → lamp 4.
    let mut path = PathRecorder::new();
    let camera = path.start();
    path.add_radiance(camera, Vec3::splat(0.1)); // the first hit glows faintly
    path.add_radiance(camera, Vec3::splat(0.5)); // next event at x1
    let v1 = path.push(camera, vertex(0.1, 0.3, 0.6)); // f/q = 0.5
    path.add_radiance(v1, Vec3::splat(2.0)); // what v1's ray hit glows (MIS-weighed)
    path.add_radiance(v1, Vec3::splat(0.25)); // next event at x2
    let v2 = path.push(v1, vertex(0.2, 0.2, 0.8)); // f/q = 0.25
    path.add_radiance(v2, Vec3::splat(4.0));
    let estimate = path.finish();

    let l2 = 4.0;
    let l1 = 2.0 + 0.25 + 0.25 * l2;
    let camera_value = 0.1 + 0.5 + 0.5 * l1;
    assert!(close(estimate.x, camera_value), "{estimate}");
    let r = records(&path);
    assert_eq!(r.len(), 2);
    // Children before parents.
    assert_eq!((r[0].id, r[1].id), (v2, v1));
    let (s1, s2) = (r[1].sample, r[0].sample);
    assert!(close(s1.value, l1) && close(s2.value, l2));
    // No roulette: the square is the value's.
    assert_eq!(s1.second_moment, Some(s1.value * s1.value));
    // Mixture terms: the integrand is f·cos·L.
    let m = s1.mixture.unwrap();
    assert!(close(m.integrand, 0.3 * l1));
    assert_eq!((m.bsdf_pdf, m.guide_pdf), (0.6, 0.3));
    assert_eq!(
        (s1.pdf, s1.normal, s1.direction),
        (0.6, Some(Vec3::Y), Vec3::Y)
    );
    // The continuation: what the vertex reflects, f/q times what arrived.
    assert!(close(r[1].continuation.value, 0.5 * l1));
    assert!(close(lum(Vec3::splat(l1)), l1));
}

#[test]
fn roulette_weighs_what_follows_and_the_square_leaves_it_out() {
    // x1 gathers A = 0.5 by next event; the path along it then survives a roulette of 0.25
    // and finds B = 2 (times 1/0.25).
    let (a, b, s) = (0.5f32, 2.0f32, 0.25f32);
    let run = |survived: bool| {
        let mut path = PathRecorder::new();
        let camera = path.start();
        let v = path.push(camera, vertex(0.1, 0.5, 0.5)); // f/q = 1
        path.add_radiance(v, Vec3::splat(a));
        path.split(v, s, u32::from(survived));
        if survived {
            let w = path.push(v, vertex(0.2, 1.0, 1.0));
            path.add_radiance(w, Vec3::splat(b));
        }
        path.finish();
        record_of(&path, v).sample
    };
    let (lived, died) = (run(true), run(false));
    assert!(close(lived.value, a + b / s), "{}", lived.value);
    assert!(close(died.value, a));
    // Over the coin, the square's estimate has the expectation (A + B)², whatever s.
    let mean = s * lived.second_moment.unwrap() + (1.0 - s) * died.second_moment.unwrap();
    assert!(close(mean, (a + b) * (a + b)), "{mean}");
    // The value's square would not: its expectation is A² + 2AB + B²/s.
    let naive = s * lived.value * lived.value + (1.0 - s) * died.value * died.value;
    assert!(naive > 1.5 * (a + b) * (a + b));

    // The same roulette played on a direction after it was drawn (pbrt's place): nothing
    // arrives before it.
    let run = |survived: bool| {
        let mut path = PathRecorder::new();
        let camera = path.start();
        let v = path.push(camera, vertex(0.1, 0.5, 0.5));
        path.roulette(v, s, survived);
        if survived {
            path.add_radiance(v, Vec3::splat(b));
        }
        path.finish();
        record_of(&path, v).sample
    };
    let (lived, died) = (run(true), run(false));
    assert!(close(lived.value, b / s) && died.value == 0.0);
    let mean = s * lived.second_moment.unwrap() + (1.0 - s) * died.second_moment.unwrap();
    assert!(close(mean, b * b), "{mean}");
}

#[test]
fn a_roulette_deeper_down_sets_the_square_of_every_vertex_above_it() {
    // camera → v1 → v2, each gathering 1 by next event; at v2's hit the path survives
    // roulette 0.5 and finds 3. Seen from v1, A = 1 + (f/q)·1 with f/q = 2 at v2.
    let mut path = PathRecorder::new();
    let camera = path.start();
    let v1 = path.push(camera, vertex(0.1, 0.5, 0.5));
    path.add_radiance(v1, Vec3::ONE);
    let v2 = path.push(v1, vertex(0.2, 1.0, 0.5));
    path.add_radiance(v2, Vec3::ONE);
    path.split(v2, 0.5, 1);
    let v3 = path.push(v2, vertex(0.3, 1.0, 1.0));
    path.add_radiance(v3, Vec3::splat(3.0));
    path.finish();
    let value2 = 1.0 + 3.0 / 0.5;
    let value1 = 1.0 + 2.0 * value2;
    let s1 = record_of(&path, v1).sample;
    assert!(close(s1.value, value1));
    let (a, s) = (1.0 + 2.0 * 1.0, 0.5);
    let y = a + s * (value1 - a);
    assert!(close(
        s1.second_moment.unwrap(),
        (y * y - (1.0 - s) * a * a) / s
    ));
}

#[test]
fn a_split_vertex_weighs_each_continuation_and_tracks_no_roulette_below() {
    let mut path = PathRecorder::new();
    let camera = path.start();
    let v = path.push(camera, vertex(0.1, 0.5, 0.5));
    path.add_radiance(v, Vec3::splat(0.5));
    path.split(v, 2.5, 3);
    let children: Vec<VertexId> = [1.0f32, 2.0, 4.0]
        .iter()
        .map(|&l| {
            let c = path.push(v, vertex(0.2, 0.5, 1.0)); // f/q = 0.5
            path.add_radiance(c, Vec3::splat(l));
            path.add_cost(c, 2.0);
            c
        })
        .collect();
    path.add_cost(v, 1.0);
    path.finish();
    let r = records(&path);
    assert_eq!(
        r.iter().map(|r| r.id).collect::<Vec<_>>()[..3],
        children[..]
    );
    let s = record_of(&path, v);
    let expected = 0.5 + (0.5 * 1.0 + 0.5 * 2.0 + 0.5 * 4.0) / 2.5;
    assert!(close(s.sample.value, expected), "{}", s.sample.value);
    assert_eq!(
        s.sample.second_moment,
        Some(s.sample.value * s.sample.value)
    );
    // Its continuation includes the split weights below it (its children's 1/2.5).
    assert!(close(s.continuation.value, 1.0 * expected));
    // A continuation costs its subtree: its own ray and its three children's.
    assert_eq!(s.continuation.cost, 1.0 + 3.0 * 2.0);
    // Each child's continuation leaves out the split weight it was traced with.
    assert!(close(
        record_of(&path, children[2]).continuation.value,
        0.5 * 4.0
    ));
}

#[test]
fn a_direction_below_the_surface_records_zero() {
    let mut path = PathRecorder::new();
    let camera = path.start();
    let v = path.push(
        camera,
        PathVertex::new(Vec3::splat(0.5), -Vec3::Y, Vec3::ZERO, 0.3)
            .with_normal(Vec3::Y)
            .with_mixture(0.0, 0.6),
    );
    assert_eq!(path.finish(), Vec3::ZERO);
    let r = record_of(&path, v);
    assert_eq!((r.sample.value, r.sample.second_moment), (0.0, Some(0.0)));
    assert_eq!(r.sample.mixture.unwrap().integrand, 0.0);
    let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())
        .expect("a field");
    assert_eq!(path.record(&field), 1);
    assert_eq!(field.stats().rejected.total(), 0);
}

#[test]
fn a_delta_vertex_passes_its_weight_on_and_records_nothing() {
    let mut path = PathRecorder::new();
    let camera = path.start();
    let v = path.push(camera, vertex(0.1, 0.5, 0.5));
    let glass = path.push_delta(v, Vec3::new(0.5, 0.3, 0.5), Vec3::new(0.9, 0.8, 0.7));
    let w = path.push(glass, vertex(0.5, 1.0, 0.5));
    path.add_radiance(w, Vec3::ONE);
    path.finish();
    let ids: Vec<VertexId> = path.records().map(|r| r.id).collect();
    assert_eq!(ids, [w, v]);
    let expected = lum(Vec3::new(0.9, 0.8, 0.7) * 2.0);
    assert!(close(record_of(&path, v).sample.value, expected));
}

#[test]
fn records_go_into_a_field_samples_and_continuations() {
    let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())
        .expect("a field");
    let mut path = PathRecorder::new();
    for _ in 0..20 {
        let camera = path.start();
        let v = path.push(camera, vertex(0.1, 0.5, 0.5));
        path.add_cost(v, 1.0);
        path.add_radiance(v, Vec3::ONE);
        path.finish();
        assert_eq!(path.record(&field), 1);
    }
    assert_eq!(field.stats().samples_recorded, 20);
    let mut field = field;
    field.refine();
    let c = field.continuation(Vec3::new(0.5, 0.1, 0.5));
    assert_eq!(c.count, 20);
    assert_eq!(c.mean(), Some(1.0));
    assert_eq!(c.mean_cost(), Some(1.0));
}

#[test]
fn bad_input_is_dropped_and_counted_never_a_panic() {
    let mut path = PathRecorder::new();
    // Radiance that is not finite or negative: ignored.
    let camera = path.start();
    let v = path.push(camera, vertex(0.1, 0.5, 0.5));
    path.add_radiance(v, Vec3::new(f32::NAN, 1.0, 1.0));
    path.add_radiance(v, Vec3::new(-1.0, 1.0, 1.0));
    path.add_radiance(v, Vec3::splat(f32::INFINITY));
    path.add_radiance(v, Vec3::ONE);
    path.add_cost(v, f32::NAN);
    path.roulette(v, 0.0, true);
    path.roulette(v, f32::NAN, true);
    path.roulette(v, 1.5, true);
    path.split(v, -1.0, 1);
    path.split(v, f32::INFINITY, 1);
    assert!(close(path.finish().x, 1.0));
    assert_eq!(path.stats().bad_values, 9);
    assert_eq!(record_of(&path, v).sample.value, 1.0);

    // A vertex with NaN weight, a zero pdf or a zero direction records nothing and passes
    // nothing on; the rest of the path is recorded.
    for bad in [
        PathVertex::new(Vec3::splat(0.5), Vec3::Y, Vec3::splat(f32::NAN), 0.5),
        PathVertex::new(Vec3::splat(0.5), Vec3::Y, Vec3::ONE, 0.0),
        PathVertex::new(Vec3::splat(0.5), Vec3::ZERO, Vec3::ONE, 0.5),
        PathVertex::new(Vec3::splat(f32::NAN), Vec3::Y, Vec3::ONE, 0.5),
        vertex(0.5, 1.0, 1.0).with_mixture(f32::NAN, 1.0),
    ] {
        let camera = path.start();
        let v = path.push(camera, vertex(0.1, 0.5, 0.5));
        path.add_radiance(v, Vec3::ONE);
        let b = path.push(v, bad);
        path.add_radiance(b, Vec3::splat(100.0));
        let w = path.push(b, vertex(0.2, 0.5, 0.5));
        path.add_radiance(w, Vec3::ONE);
        assert!(close(path.finish().x, 1.0), "{bad:?}");
        let ids: Vec<VertexId> = path.records().map(|r| r.id).collect();
        assert_eq!(ids, [w, v], "{bad:?}");
    }
    assert_eq!(path.stats().bad_vertices, 5);

    // Calls after finish and on handles of another path change nothing.
    let before = path.finish();
    let id = path.records().next().expect("a record").id;
    path.add_radiance(id, Vec3::ONE);
    assert_eq!(path.finish(), before);
}

#[test]
fn a_path_longer_than_the_capacity_records_nothing_and_says_so() {
    let mut path = PathRecorder::with_max_vertices(8);
    let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())
        .expect("a field");
    let mut v = path.start();
    for i in 0..1000 {
        v = path.push(v, vertex((i % 10) as f32 / 10.0, 0.5, 0.5));
        path.add_radiance(v, Vec3::ONE);
        path.split(v, 0.5, 1);
        path.roulette(v, 0.5, true);
        path.add_cost(v, 1.0);
    }
    let estimate = path.finish();
    assert!(estimate.is_finite());
    assert_eq!(path.records().count(), 0);
    assert_eq!(path.record(&field), 0);
    let stats = path.stats();
    assert_eq!(
        (stats.truncated_paths, stats.dropped_vertices),
        (1, 1000 - 7)
    );
    // The next path starts clean.
    let camera = path.start();
    let v = path.push(camera, vertex(0.1, 0.5, 0.5));
    path.add_radiance(v, Vec3::ONE);
    path.finish();
    assert_eq!(path.record(&field), 1);
    // Without a start, nothing is recorded and nothing panics.
    let mut fresh = PathRecorder::new();
    assert_eq!(fresh.finish(), Vec3::ZERO);
    fresh.add_radiance(v, Vec3::ONE);
    assert_eq!(fresh.records().count(), 0);
}
