//! What several of the demo's tests train on, and how they measure an image.
#![allow(dead_code)]

use sdguide::{GuidingConfig, GuidingField, SplittingMode};
use sdguide_render::backend::Backend;
use sdguide_render::image::Image;
use sdguide_render::integrator::Guiding;
use sdguide_render::integrator::Roulette;
use sdguide_render::method::field_bounds;
use sdguide_render::passes::PassImage;
use sdguide_render::render::{TrainingPass, render_pass, training_pass, training_pass_with};
use sdguide_render::scene::Scene;
use sdguide_render::scenes::door;

/// `door`, and a field trained on it with the defaults: four passes of 2, 4, 8, 16 spp at
/// 48 × 36, seed 11.
pub fn trained_door() -> (Scene, GuidingField) {
    let scene = door();
    let mut field = GuidingField::new(field_bounds(&scene), GuidingConfig::default()).unwrap();
    for pass in 0..4 {
        training_pass(&scene, &mut field, (48, 36), 2 << pass, 11, pass, None);
    }
    (scene, field)
}

/// Mean of the pixels and its standard error (pixels are independent estimates).
pub fn mean_and_error(image: &Image) -> (f64, f64) {
    let values: Vec<f64> = image
        .pixels
        .iter()
        .map(|p| (p.x as f64 + p.y as f64 + p.z as f64) / 3.0)
        .collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// A field trained on `scene` with `config`: five passes of 1, 2, …, 16 spp at 40 × 30, its
/// paths playing `roulette`, or with `mode` roulette and splitting by the field's own
/// estimates; and the training passes' images.
pub fn trained_with_config(
    scene: &Scene,
    config: GuidingConfig,
    roulette: Roulette,
    mode: Option<SplittingMode>,
) -> (GuidingField, Vec<PassImage>) {
    let mut field = GuidingField::new(field_bounds(scene), config).unwrap();
    let mut passes = Vec::new();
    for iteration in 0..5 {
        let pass = TrainingPass {
            size: (40, 30),
            spp: 1 << iteration,
            seed: 3,
            iteration,
            guide_probability: None,
            roulette,
        };
        let image = training_pass_with(scene, &mut field, &pass, (mode, &passes[..]));
        passes.push(image);
    }
    (field, passes)
}

/// Asserts that `image`'s mean is within 4 standard errors of `expected`, and that the error is
/// below 1% of it (the render is long enough to tell).
pub fn assert_converges(image: &Image, expected: f64, what: &str) {
    let (mean, error) = mean_and_error(image);
    assert!(
        error > 0.0 && error < 0.01 * expected,
        "{what}: error {error}"
    );
    assert!(
        (mean - expected).abs() < 4.0 * error,
        "{what}: mean {mean} vs {expected} (standard error {error})"
    );
}

/// The mean of 32 samples per pixel of `scene` at 40 × 30, guided by `field` when given (not
/// recording), from `seed`.
pub fn render_in<B: Backend>(scene: &Scene, field: Option<&B>, seed: u64) -> Image {
    const SPP: u32 = 32;
    let mut sum = Image::new(40, 30);
    let guiding = field.map(|field| Guiding {
        field,
        record: false,
        guide_probability: None,
    });
    render_pass(scene, guiding, &mut sum, SPP, seed, 0);
    sum.pixels.iter_mut().for_each(|p| *p /= SPP as f32);
    sum
}
