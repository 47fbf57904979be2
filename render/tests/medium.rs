//! Participating media: the furnace filled with a medium that scatters without absorbing
//! (`medium_furnace`) has the radiance `emission / (1 − albedo)` everywhere, so a render must
//! converge to it — unguided, and guided by volume guides (free flights, transmittance in
//! next-event estimation, the phase function's sampling mixed with the guide's product with
//! it, MIS with the mixture pdf at medium vertices, recording and refining), with classic
//! roulette and with efficiency-aware roulette and splitting.

use sdguide::{GuidingConfig, GuidingField, LeafRule, SplittingMode};
use sdguide_render::image::Image;
use sdguide_render::integrator::Roulette;
use sdguide_render::scene::Scene;
use sdguide_render::scenes::medium_furnace;

mod common;
use common::{render_in, trained_with_config};

const ALBEDO: f32 = 0.3;
const EMISSION: f32 = 1.0;
#[cfg(feature = "openpgl")]
const SIZE: (usize, usize) = (40, 30);

/// A field with volume guides trained on `scene` (see [`trained_with_config`]), with classic
/// roulette or with `mode` roulette and splitting.
fn trained(scene: &Scene, rule: LeafRule, mode: Option<SplittingMode>) -> GuidingField {
    let config = GuidingConfig {
        rule,
        spatial_threshold: 1000.0,
        volumes: true,
        ..GuidingConfig::default()
    };
    trained_with_config(scene, config, Roulette::Classic, mode).0
}

fn assert_converges(image: &Image, what: &str) {
    // Paths are cut after 200 events; each wall bounce keeps 0.3 of the weight, and a path
    // meets a wall at least every few events, so the part lost is far below the error.
    let expected = f64::from(EMISSION / (1.0 - ALBEDO));
    common::assert_converges(image, expected, what);
    // And within 3σ, the bound the volume work was asked to show.
    let (mean, error) = common::mean_and_error(image);
    let z = (mean - expected) / error;
    eprintln!("{what}: mean {mean:.5}, expected {expected:.5}, z = {z:+.2}");
    assert!(z.abs() < 3.0, "{what}: z = {z}");
}

#[test]
fn unguided_medium_furnace_converges_to_the_analytic_radiance() {
    let scene = medium_furnace(ALBEDO, EMISSION);
    assert_converges(&render_in(&scene, None::<&GuidingField>, 7), "unguided");
}

#[test]
fn guided_medium_furnace_converges_to_the_analytic_radiance() {
    let scene = medium_furnace(ALBEDO, EMISSION);
    for (rule, mode) in [
        (LeafRule::L2, None),
        (LeafRule::L1, None),
        (LeafRule::L2, Some(SplittingMode::RouletteAndSplitting)),
    ] {
        let field = trained(&scene, rule, mode);
        let stats = field.stats();
        assert_eq!(stats.rejected.total(), 0, "{stats:?}");
        // The medium vertices trained the volume guides, which are used.
        assert!(stats.volume_directional_nodes > 0, "{stats:?}");
        let at = glam::Vec3::new(0.3, -0.2, 0.4);
        assert!(field.volume_distribution(at).guide_probability() > 0.0);
        assert_converges(
            &render_in(&scene, Some(&field), 7),
            &format!("{rule:?}, {mode:?}"),
        );
    }
}

/// The peer's volume guiding is wired without bias too: Open PGL's field trained on the
/// medium furnace, its volume distributions times the phase function at medium vertices.
#[cfg(feature = "openpgl")]
#[test]
fn open_pgl_guided_medium_furnace_converges_to_the_analytic_radiance() {
    use sdguide_render::method::field_bounds;
    use sdguide_render::openpgl;
    use sdguide_render::render::training_pass;
    let scene = medium_furnace(ALBEDO, EMISSION);
    let mut guide = openpgl::Guide::new(field_bounds(&scene), true, 2).unwrap();
    for pass in 0..5 {
        training_pass(&scene, &mut guide, SIZE, 1 << pass, 3, pass, None);
    }
    // The volume field has learned a distribution, so medium vertices below are guided.
    let at = glam::Vec3::new(0.3, -0.2, 0.4);
    assert!(
        guide
            .volume_distribution(at, glam::Vec3::X, 0.5, 0.5)
            .is_some()
    );
    assert_converges(&render_in(&scene, Some(&guide), 7), "Open PGL");
}
