//! Tests of the integrator's roulette and of what it hands a backend to record.

use super::*;
use crate::backend::NoGuide;
use std::sync::Mutex;

/// A backend that guides nowhere and keeps every segment it is given.
#[derive(Default)]
struct Spy(Mutex<Vec<(f32, Segment)>>);

impl Backend for Spy {
    type Vertex<'a> = NoGuide;
    fn at(&self, _: Vec3, _: Vec3, _: f32) -> Option<NoGuide> {
        None
    }
    fn in_medium(&self, _: Vec3, _: Vec3, _: f32, _: f32) -> Option<NoGuide> {
        None
    }
    fn record(&self, sample: &sdguide::Sample, segment: Segment) {
        self.0.lock().unwrap().push((sample.value, segment));
    }
    fn refine(&mut self) {}
}

#[test]
fn every_recorded_vertex_knows_its_way_back_and_its_reach() {
    let scene = crate::scenes::door();
    let mut spy = Spy::default();
    crate::render::training_pass(&scene, &mut spy, (16, 12), 4, 1, 0, None);
    let segments = spy.0.into_inner().unwrap();
    // Classic roulette ends some paths at a vertex: those vertices too lead back along
    // their path, and reach nothing.
    assert!(segments.iter().any(|(_, s)| s.distance.is_infinite()));
    for (value, s) in &segments {
        assert!((s.outgoing.length() - 1.0).abs() < 1e-4, "{s:?}");
        assert!(s.distance > 0.0 || *value == 0.0, "{s:?}");
    }
}

#[test]
fn guided_survival_is_open_pgls_weight_window() {
    // β̄ = 0.2, A = 0.5, Ĩ = 1: the window's lower bound is 2·(1/0.5)/6 = 2/3, and the
    // path survives with 0.2/(2/3) = 0.3.
    let beta = Vec3::new(0.1, 0.2, 0.3);
    assert!((guided_survival(beta, 0.5, 1.0) - 0.3).abs() < 1e-6);
    // Within [0.1, 1].
    assert_eq!(guided_survival(beta, 1e-6, 1.0), 0.1);
    assert_eq!(guided_survival(Vec3::splat(5.0), 0.5, 1.0), 1.0);
    // No adjoint, or no pixel estimate: no roulette.
    for adjoint in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert_eq!(guided_survival(beta, adjoint, 1.0), 1.0);
    }
    assert_eq!(guided_survival(beta, 0.5, 0.0), 1.0);
    assert_eq!(guided_survival(Vec3::splat(f32::NAN), 0.5, 1.0), 1.0);
}
