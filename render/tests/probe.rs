//! The probe mode's claim: on a trained `door`, the surface-aware guide the integrator samples
//! sends at most 5% of its draws below the surface at every probe, where the plain guide sends
//! far more.

mod common;

use common::trained_door;
use sdguide_render::probe::probe;

#[test]
fn the_surface_aware_guide_keeps_its_draws_above_the_surface() {
    let (scene, field) = trained_door();
    let draws = 20_000;
    let probes = probe(&scene, &field, 4.0 / 3.0, draws);
    assert_eq!(probes.len(), 9);
    // A share of at most 5% seen in 20,000 draws: the 5-sigma binomial margin on top.
    let margin = 5.0 * (0.05 * 0.95 / f64::from(draws)).sqrt();
    let mut plain = 0.0;
    for p in &probes {
        assert!(p.surface_below <= 0.05 + margin, "{p:?}");
        plain += p.plain_below;
    }
    // The plain guide learns from every surface in a cell, facing all ways.
    assert!(plain / 9.0 > 0.1, "plain guide below: {}", plain / 9.0);
}
