//! Combining a render's passes by inverse variance (the library's `pass_weights` applied to
//! the demo's colour images): the combination weighs passes by their variances, and a guided
//! render's combined image converges to the furnace's analytic radiance (training passes are
//! unbiased estimates, and so is their combination); and the training schedule a render
//! follows.

use glam::Vec3;
use sdguide::GuidingConfig;
use sdguide_render::method::{Budget, Method, Outcome, Rrs, Training, render};
use sdguide_render::passes::{PassImage, combine};
use sdguide_render::scenes::furnace;

/// A one-pixel pass whose samples are the grey values `values`.
fn pass_of(values: &[f32]) -> PassImage {
    let mut p = PassImage::new(1, 1);
    for &v in values {
        p.add(0, Vec3::splat(v));
    }
    p.spp = values.len() as u32;
    p
}

#[test]
fn passes_are_weighed_by_their_inverse_variance() {
    // The last pass: mean 2, variance 1 (its own estimate). An earlier one: mean 5, variance
    // 4 by its own samples, but 3² − 1 = 8 by its distance from the last, which counts.
    // Weights 1/8 and 1: (5/8 + 2) / (9/8) = 7/3.
    let low = pass_of(&[1.0, 3.0]);
    let high = pass_of(&[3.0, 7.0]);
    let combined = combine(&[high.clone(), low.clone()]).unwrap();
    assert!(
        (combined.pixels[0].x - 7.0 / 3.0).abs() < 1e-5,
        "{}",
        combined.pixels[0]
    );
    // An earlier pass close to the last keeps its own estimate: mean 2.5, variance 1 by its
    // samples (distance 0.25 − 1 < 1): equal weights, (2.5 + 2) / 2.
    let near = pass_of(&[1.5, 3.5]);
    let combined = combine(&[near, low.clone()]).unwrap();
    assert!((combined.pixels[0].x - 2.25).abs() < 1e-5);
    // The last pass alone, by its own estimate, whatever the earlier ones.
    let combined = combine(&[low.clone(), high]).unwrap();
    // Last: mean 5, variance 4; earlier: mean 2, own variance 1, distance 9 − 4 = 5.
    // Weights 1/5 and 1/4: (2/5 + 5/4) / (9/20) = 11/3.
    assert!((combined.pixels[0].x - 11.0 / 3.0).abs() < 1e-5);
    // A pass without an estimate, or with a zero one, is left out; none left, no image.
    let combined = combine(&[pass_of(&[100.0]), low, pass_of(&[9.0, 9.0])]).unwrap();
    assert!((combined.pixels[0].x - 2.0).abs() < 1e-6);
    assert!(combine(&[pass_of(&[1.0])]).is_none());
    assert!(combine(&[]).is_none());
}

/// The furnace's albedo.
const ALBEDO: f32 = 0.3;

/// Renders the furnace (albedo [`ALBEDO`]) with five training passes and `spp` final samples, at no
/// time budget, with `method` and `rrs`.
fn furnace_render(method: Method, rrs: Rrs, spp: u32, size: (usize, usize), seed: u64) -> Outcome {
    let scene = furnace(ALBEDO, 1.0);
    let config = GuidingConfig {
        spatial_threshold: 1000.0,
        ..GuidingConfig::default()
    };
    let budget = Budget {
        time: None,
        spp: Some(spp),
        training_share: 0.3,
        training_iterations: 5,
    };
    let training = Training {
        config: &config,
        cache: None,
        guide_probability: None,
        rrs,
    };
    render(&scene, method, size, budget, seed, training, &|_, _, _| {}).unwrap()
}

#[test]
fn a_guided_render_with_its_training_passes_converges_in_the_furnace() {
    let guided = Method::Guided(sdguide::LeafRule::L2);
    let outcome = furnace_render(guided, Rrs::Classic, 16, (40, 30), 5);
    assert_eq!((outcome.spp, outcome.training_spp), (16, 31));
    // The combined image holds more samples than the final one: a smaller pixel spread.
    let spread = |pixels: &[Vec3]| {
        let n = pixels.len() as f64;
        let mean = pixels.iter().map(|p| p.x as f64).sum::<f64>() / n;
        let var = pixels
            .iter()
            .map(|p| (p.x as f64 - mean).powi(2))
            .sum::<f64>()
            / (n - 1.0);
        (mean, (var / n).sqrt())
    };
    let (_, final_error) = spread(&outcome.image.pixels);
    let (mean, error) = spread(&outcome.combined.pixels);
    assert!(error < final_error, "{error} vs {final_error}");
    let expected = 1.0 / (1.0 - ALBEDO) as f64;
    assert!(
        (mean - expected).abs() < 4.0 * error,
        "{mean} vs {expected} ± {error}"
    );
}

#[test]
fn the_first_splitting_pass_repeats_the_pass_before_it() {
    // Without a time budget, five training passes: 1, 2, 4, 8, 16 spp with classic roulette;
    // with splitting the policy is set by the 4-spp pass, so the first pass that splits takes
    // 4 spp again and the doubling resumes after it: 1, 2, 4, 4, 8.
    let trained =
        |method: Method, rrs: Rrs| furnace_render(method, rrs, 4, (16, 12), 3).training_spp;
    let guided = Method::Guided(sdguide::LeafRule::L2);
    assert_eq!(trained(guided, Rrs::Classic), 31);
    assert_eq!(trained(guided, Rrs::Ears), 19);
    assert_eq!(trained(Method::Unguided, Rrs::Ears), 19);
    // Unguided with classic roulette does not train.
    assert_eq!(trained(Method::Unguided, Rrs::Classic), 0);
}
