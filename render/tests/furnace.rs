//! The white furnace: inside a closed, uniformly emitting, diffusely reflecting cube the radiance
//! is `emission / (1 − albedo)` everywhere, so every pixel's expectation is known exactly. A
//! render must converge to it with and without guiding — unbiasedness through the whole wiring
//! (mixture sampling with the surface-aware guide, its pdf in the estimator and in MIS,
//! next-event estimation or none, Russian roulette, roulette and splitting by the field's
//! continuation estimates, recording and refining). A glass sphere in
//! the furnace leaves its radiance as it was: energy is conserved through the dielectric, and
//! paths through it are weighed right.

use sdguide::{GuidingConfig, GuidingField, LeafRule, Splitting, SplittingMode};
use sdguide_render::backend::{Backend, Unguided};
use sdguide_render::image::Image;
use sdguide_render::integrator::{Continuations, Continuing, Guiding, Roulette};
use sdguide_render::passes::{PassImage, splitting};
use sdguide_render::render::{render_pass, render_pass_image};
use sdguide_render::scene::Scene;
use sdguide_render::scenes::{furnace, furnace_sized, glass_furnace};

mod common;
use common::{render_in, trained_with_config};

const ALBEDO: f32 = 0.3;
const EMISSION: f32 = 1.0;
const SIZE: (usize, usize) = (40, 30);
const SPP: u32 = 32;

fn render_furnace<B: Backend>(field: Option<&B>) -> Image {
    render_in(&furnace(ALBEDO, EMISSION), field, 7)
}

/// A field trained on `scene` with `rule`: five passes of 1, 2, …, 16 spp, cells split early.
fn trained_in(scene: &Scene, rule: LeafRule) -> GuidingField {
    trained_with(scene, rule, Roulette::Classic, None).0
}

/// A field trained on `scene` with `rule` as [`trained_in`]'s, its paths playing `roulette`,
/// or with `mode` roulette and splitting by the field's own estimates; and the training passes'
/// images.
///
/// The guide never turns off (`guide_cost: None`): in the furnace it never pays (below), and
/// these tests are of the guided estimator.
fn trained_with(
    scene: &Scene,
    rule: LeafRule,
    roulette: Roulette,
    mode: Option<SplittingMode>,
) -> (GuidingField, Vec<PassImage>) {
    trained_with_config(
        scene,
        GuidingConfig {
            rule,
            spatial_threshold: 1000.0,
            guide_cost: None,
            ..GuidingConfig::default()
        },
        roulette,
        mode,
    )
}

fn assert_converges(image: &Image, what: &str) {
    // Paths are cut after 10 bounces: the part lost, albedo¹¹·L ≈ 2.5e-6, is far below the
    // statistical error.
    common::assert_converges(image, f64::from(EMISSION / (1.0 - ALBEDO)), what);
}

#[test]
fn unguided_furnace_converges_to_the_analytic_radiance() {
    assert_converges(&render_furnace(None::<&Unguided>), "unguided");
}

/// A 0.4 m furnace: every light sample lies within a metre of its shading point, where shadow
/// rays must still reach the light (a shadow ray that ends behind the light is blocked by it,
/// and that energy is lost: MIS still counts on next-event estimation to find it).
#[test]
fn a_small_furnace_converges_too() {
    let scene = furnace_sized(ALBEDO, EMISSION, 0.2);
    let mut sum = Image::new(SIZE.0, SIZE.1);
    render_pass(&scene, None::<Guiding<Unguided>>, &mut sum, SPP, 7, 0);
    sum.pixels.iter_mut().for_each(|p| *p /= SPP as f32);
    assert_converges(&sum, "small furnace");
}

#[test]
fn guided_furnace_converges_to_the_analytic_radiance() {
    let scene = furnace(ALBEDO, EMISSION);
    for rule in [LeafRule::L1, LeafRule::L2] {
        let field = trained_in(&scene, rule);
        let stats = field.stats();
        assert_eq!(stats.rejected.total(), 0, "{stats:?}");
        assert!(
            stats.samples_recorded_total > 0 && stats.spatial_leaves > 1,
            "{stats:?}"
        );
        // The learned distributions are not uniform, and the guide is used.
        let dist = field.distribution(glam::Vec3::new(0.5, -0.9, 0.2));
        assert!(dist.leaves().len() > 1);
        assert!(dist.guide_probability() > 0.0);
        assert_converges(&render_furnace(Some(&field)), &format!("{rule:?}"));
    }
}

/// The furnace's radiance is the same from every direction, so BSDF sampling alone already
/// draws in proportion to the integrand (the cosine): a guide cannot lower the variance there,
/// and with the demo's measured cost it turns off. The render, BSDF sampling where the guide is off,
/// converges all the same.
#[test]
fn in_the_furnace_the_guide_does_not_pay_and_turns_off() {
    let scene = furnace(ALBEDO, EMISSION);
    let config = GuidingConfig {
        spatial_threshold: 1000.0,
        guide_cost: Some(sdguide_render::method::GUIDE_COST),
        ..GuidingConfig::default()
    };
    let (field, _) = trained_with_config(&scene, config, Roulette::Classic, None);
    let stats = field.stats();
    assert!(
        2 * stats.guides_off > stats.spatial_leaves,
        "{} of {} guides off",
        stats.guides_off,
        stats.spatial_leaves
    );
    assert_converges(&render_furnace(Some(&field)), "guides off");
}

/// Without roulette every path goes on to the longest depth: trained and rendered that way, the
/// guided furnace converges, and so does the unguided one; and each spends more rays per sample
/// than with classic roulette, which ends some paths early.
#[test]
fn furnace_without_roulette_converges_guided_and_not() {
    let scene = furnace(ALBEDO, EMISSION);
    let (field, _) = trained_with(&scene, LeafRule::default(), Roulette::Off, None);
    assert_eq!(field.stats().rejected.total(), 0);
    let guided = |record| Guiding {
        field: &field,
        record,
        guide_probability: None,
    };
    let mut dark = scene.clone();
    dark.next_event = false;
    for (name, guiding) in [("unguided", None), ("guided", Some(guided(false)))] {
        let mut rays = Vec::new();
        for roulette in [Roulette::Classic, Roulette::Off] {
            let mut image = PassImage::new(SIZE.0, SIZE.1);
            let continuing = Continuing {
                roulette,
                ..Continuing::CLASSIC
            };
            render_pass_image(&scene, guiding, &continuing, &mut image, (SPP, 11, 0));
            assert_converges(&image.mean(), &format!("{name}, {roulette:?}"));
            // Without light samples a path's rays are its intersections: in the closed
            // furnace without roulette a path traces its camera ray and 10 bounces, with it
            // fewer. Without roulette a path ends early only at a direction with f = 0 (at the
            // horizon, or below the surface for the guide times the cosine), which is rare.
            let mut image = PassImage::new(SIZE.0, SIZE.1);
            render_pass_image(&dark, guiding, &continuing, &mut image, (SPP, 12, 0));
            rays.push(image.rays / (SIZE.0 * SIZE.1) as f64 / f64::from(SPP));
        }
        assert!((10.99..=11.0).contains(&rays[1]), "{name}: {rays:?}");
        assert!(rays[0] < 0.9 * rays[1], "{name}: {rays:?}");
    }
}

/// Without next-event estimation the emission a path hits counts in full (no MIS weight), and
/// the surface-aware guide must still find all of it: guided and unguided, l1 and l2.
#[test]
fn furnace_without_next_event_estimation_converges_guided_and_not() {
    let mut scene = furnace(ALBEDO, EMISSION);
    scene.next_event = false;
    assert_converges(&render_in(&scene, None::<&Unguided>, 9), "unguided, no NEE");
    for rule in [LeafRule::L1, LeafRule::L2] {
        let field = trained_in(&scene, rule);
        assert!(field.stats().spatial_leaves > 1);
        assert_converges(
            &render_in(&scene, Some(&field), 9),
            &format!("{rule:?}, no NEE"),
        );
    }
}

/// Paths are cut after 10 scattering events, glass ones included: a path that reaches the cut
/// through `k` crossings of the sphere has met at least `10 − 2k` diffuse walls, and the sphere
/// fills a small part of every wall's view, so the part lost stays far below the statistical
/// error.
#[test]
fn a_glass_sphere_leaves_the_furnace_radiance_as_it_was() {
    for next_event in [true, false] {
        let mut scene = glass_furnace(ALBEDO, EMISSION);
        scene.next_event = next_event;
        let what = format!("glass, NEE {next_event}");
        assert_converges(
            &render_in(&scene, None::<&Unguided>, 11),
            &format!("{what}, unguided"),
        );
        let field = trained_in(&scene, LeafRule::L2);
        let stats = field.stats();
        assert_eq!(stats.rejected.total(), 0, "{stats:?}");
        assert!(stats.spatial_leaves > 1, "{stats:?}");
        assert_converges(
            &render_in(&scene, Some(&field), 11),
            &format!("{what}, guided"),
        );
    }
}

/// The glass furnace's camera sees the sphere: a sizeable share of the pixels' paths go
/// through glass, so the test above tests it.
#[test]
fn the_glass_furnace_camera_sees_the_sphere() {
    let scene = glass_furnace(ALBEDO, EMISSION);
    let aspect = SIZE.0 as f32 / SIZE.1 as f32;
    let mut through = 0;
    for j in 0..SIZE.1 {
        for i in 0..SIZE.0 {
            let film = glam::Vec2::new(
                (i as f32 + 0.5) / SIZE.0 as f32,
                (j as f32 + 0.5) / SIZE.1 as f32,
            );
            let hit = scene.intersect(&scene.camera.ray(film, aspect)).unwrap();
            through += usize::from(scene.material(&hit).is_dielectric());
        }
    }
    let share = through as f64 / (SIZE.0 * SIZE.1) as f64;
    assert!(share > 0.1 && share < 0.9, "{share}");
}

/// The peer's wiring is unbiased too: Open PGL's field, trained on the furnace, with and without
/// its cosine product.
#[cfg(feature = "openpgl")]
#[test]
fn open_pgl_guided_furnace_converges_to_the_analytic_radiance() {
    use sdguide_render::method::field_bounds;
    use sdguide_render::openpgl;
    use sdguide_render::render::training_pass;
    let scene = furnace(ALBEDO, EMISSION);
    for cosine_product in [false, true] {
        let mut guide = openpgl::Guide::new(field_bounds(&scene), cosine_product, 2).unwrap();
        for pass in 0..5 {
            training_pass(&scene, &mut guide, SIZE, 1 << pass, 3, pass, None);
        }
        assert_eq!(guide.iteration(), 5);
        // The field has learned a distribution, so the render below is guided.
        let at = glam::Vec3::new(0.5, -0.9, 0.2);
        assert!(guide.distribution(at, glam::Vec3::Y, 0.5).is_some());
        assert_converges(
            &render_furnace(Some(&guide)),
            &format!("Open PGL, cosine product {cosine_product}"),
        );
    }
}

/// Open PGL's guided Russian roulette, from its radiance cache and the training passes' pixel
/// estimates, keeps the furnace unbiased, in training and in the final render, and ends paths
/// (in the furnace a vertex's adjoint is `a·L` and the pixel `L`, so a path survives its second
/// vertex with about `3·a·β = 3a²`, `a` = 0.3).
#[cfg(feature = "openpgl")]
#[test]
fn open_pgl_guided_roulette_keeps_the_furnace_unbiased() {
    use sdguide_render::method::field_bounds;
    use sdguide_render::openpgl;
    use sdguide_render::render::{TrainingPass, training_pass_with};
    let scene = furnace(ALBEDO, EMISSION);
    let mut guide = openpgl::Guide::new(field_bounds(&scene), true, 2).unwrap();
    let mut passes: Vec<PassImage> = Vec::new();
    for iteration in 0..5 {
        let pass = TrainingPass {
            size: SIZE,
            spp: 1 << iteration,
            seed: 5,
            iteration,
            guide_probability: None,
            roulette: Roulette::Guided,
        };
        let image = training_pass_with(&scene, &mut guide, &pass, (None, &passes[..]));
        // Every training pass is an unbiased estimate of the furnace.
        let (mean, error) = common::mean_and_error(&image.mean());
        let expected = f64::from(EMISSION / (1.0 - ALBEDO));
        assert!(
            (mean - expected).abs() < 4.0 * error,
            "training pass {iteration}: {mean} vs {expected} ± {error}"
        );
        passes.push(image);
    }
    let refs: Vec<&PassImage> = passes.iter().collect();
    let estimates = splitting(&refs, SplittingMode::Roulette).expect("passes of 4 spp and more");
    let guiding = Some(Guiding {
        field: &guide,
        record: false,
        guide_probability: None,
    });
    let mut rays = Vec::new();
    for roulette in [Roulette::Guided, Roulette::Off] {
        let continuing = Continuing {
            roulette,
            continuations: None,
            pixels: &estimates.pixels,
        };
        let mut image = PassImage::new(SIZE.0, SIZE.1);
        render_pass_image(&scene, guiding, &continuing, &mut image, (SPP, 9, 0));
        assert_converges(&image.mean(), &format!("Open PGL, {roulette:?}"));
        rays.push(image.rays);
    }
    assert!(rays[0] < 0.5 * rays[1], "{rays:?}");
}

/// Roulette and splitting by the field's continuation estimates keep the furnace unbiased,
/// guided and not: with the policy the training passes give, forced to split wherever the
/// demo lets a vertex split (to the ray bound of a camera sample), and forced to kill at a
/// survival floor.
#[test]
fn furnace_with_roulette_and_splitting_converges() {
    let scene = furnace(ALBEDO, EMISSION);
    let mode = SplittingMode::RouletteAndSplitting;
    let (field, passes) = trained_with(&scene, LeafRule::default(), Roulette::Classic, Some(mode));
    let estimated = field
        .cells()
        .filter(|c| field.continuation(c.bounds.center()).count >= 16)
        .count();
    assert!(
        estimated > 1,
        "{estimated} cells with continuation estimates"
    );
    let refs: Vec<&PassImage> = passes.iter().collect();
    let estimates = splitting(&refs, mode).expect("passes of 4 spp and more");
    let forced = |variance, floor| {
        Splitting::new(mode, variance, 10.0)
            .with_bounds(floor, 3.0)
            .unwrap()
    };
    let mut rays = Vec::new();
    for (name, policy, guide_probability) in [
        ("the image's policy", estimates.splitting, None),
        (
            "the image's policy, unguided",
            estimates.splitting,
            Some(0.0),
        ),
        ("splitting", forced(1e-9, 0.05), None),
        ("killing", forced(1e9, 0.5), None),
    ] {
        let continuing = Continuing {
            roulette: Roulette::Classic,
            continuations: Some(Continuations {
                field: &field,
                splitting: Some(policy),
                record: false,
            }),
            pixels: &estimates.pixels,
        };
        let guiding = Guiding {
            field: &field,
            record: false,
            guide_probability,
        };
        let mut image = PassImage::new(SIZE.0, SIZE.1);
        render_pass_image(&scene, Some(guiding), &continuing, &mut image, (SPP, 7, 0));
        assert_converges(&image.mean(), name);
        rays.push(image.rays);
    }
    // The forced policies did what they force.
    assert!(rays[2] > 3.0 * rays[0] && rays[3] < rays[0], "{rays:?}");
}
