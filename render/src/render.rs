//! Rendering passes: the image in tiles with rayon, one random stream per pixel and pass, with
//! any guiding backend; and training passes, which record every path and refine the backend.
//! What a method renders within its budget is [`method`](crate::method)'s.

use crate::backend::Backend;
use crate::image::Image;
use crate::integrator::{Continuations, Guiding, Roulette, Scratch, path_sample};
use crate::material::luminance;
use crate::passes::{PassImage, PixelEstimates, splitting};
use crate::rng::Rng;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sdguide::{GuidingField, SplittingMode};

/// Tile edge, pixels.
const TILE: usize = 16;

/// Pass numbers at and above this are training passes (the final render counts from 0).
pub(crate) const TRAINING_PASS: u32 = 1 << 31;

/// Renders `spp` samples per pixel into `sum` (added, not averaged), pass `pass` of a render
/// seeded by `seed`. With `guiding`, paths sample the field (and record into it if asked).
pub fn render_pass<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    sum: &mut Image,
    spp: u32,
    seed: u64,
    pass: u32,
) {
    let size = (sum.width, sum.height);
    render_samples(
        scene,
        guiding,
        (Roulette::Classic, None),
        size,
        (spp, seed, pass),
        |pixel, l, _| {
            sum.pixels[pixel] += l;
        },
    );
}

/// [`render_pass`] into a [`PassImage`], which also keeps each pixel's squared luminance (for
/// the pass's variance) and the rays traced; with roulette and splitting by `continuations`
/// when given.
pub fn render_pass_image<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    continuations: (Roulette, Option<&Continuations<'_>>),
    image: &mut PassImage,
    (spp, seed, pass): (u32, u64, u32),
) {
    let size = (image.sum.width, image.sum.height);
    let rays = render_samples(
        scene,
        guiding,
        continuations,
        size,
        (spp, seed, pass),
        |pixel, l, squares| {
            image.sum.pixels[pixel] += l;
            image.squares[pixel] += squares;
        },
    );
    image.spp += spp;
    image.rays += rays;
}

/// Renders `spp` samples of every pixel of a `width × height` image (pass `pass` of a render
/// seeded by `seed`) and hands each pixel's sums to `add`: its index, the sum of its samples
/// and the sum of their squared luminance. Returns the rays traced.
fn render_samples<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    (roulette, continuations): (Roulette, Option<&Continuations<'_>>),
    (width, height): (usize, usize),
    (spp, seed, pass): (u32, u64, u32),
    mut add: impl FnMut(usize, Vec3, f64),
) -> f64 {
    let aspect = width as f32 / height as f32;
    // One random stream per pixel and pass: the key `pass·2³² + pixel`, salted by the seed.
    // Salting with a pseudo-random function of the seed (not the seed itself) keeps renders with
    // different seeds independent; a render does not depend on how tiles meet threads.
    let salt = Rng::new(seed).next_u64();
    let tiles: Vec<(usize, usize)> = (0..height.div_ceil(TILE))
        .flat_map(|ty| (0..width.div_ceil(TILE)).map(move |tx| (tx * TILE, ty * TILE)))
        .collect();
    let rendered: Vec<(Vec<(Vec3, f64)>, f64)> = tiles
        .par_iter()
        .map(|&(x0, y0)| {
            let mut out = Vec::with_capacity(TILE * TILE);
            let mut scratch = Scratch::default();
            let mut rays = 0.0;
            for y in y0..(y0 + TILE).min(height) {
                for x in x0..(x0 + TILE).min(width) {
                    let index = y * width + x;
                    let pixel = index as u64;
                    let mut rng = Rng::new(salt ^ ((pass as u64) << 32 | pixel));
                    let (mut c, mut squares) = (Vec3::ZERO, 0.0);
                    for _ in 0..spp {
                        let film = (Vec2::new(x as f32, y as f32) + rng.next_vec2())
                            / Vec2::new(width as f32, height as f32);
                        let ray = scene.camera.ray(film, aspect);
                        let sample = path_sample(
                            scene,
                            guiding,
                            (roulette, continuations.map(|c| (c, index))),
                            ray,
                            (&mut rng, &mut scratch),
                        );
                        rays += f64::from(sample.rays);
                        let l = sample.radiance;
                        // A NaN or infinite path would poison the pixel; none should occur, and
                        // a debug build says so.
                        debug_assert!(l.is_finite(), "non-finite radiance {l}");
                        if l.is_finite() {
                            c += l;
                            squares += f64::from(luminance(l)).powi(2);
                        }
                    }
                    out.push((c, squares));
                }
            }
            (out, rays)
        })
        .collect();
    let mut rays = 0.0;
    for (&(x0, y0), (tile, tile_rays)) in tiles.iter().zip(rendered) {
        rays += tile_rays;
        let mut sums = tile.into_iter();
        for y in y0..(y0 + TILE).min(height) {
            for x in x0..(x0 + TILE).min(width) {
                let (c, squares) = sums.next().unwrap_or_default();
                add(y * width + x, c, squares);
            }
        }
    }
    rays
}

/// One training pass: renders `spp` samples per pixel at `size`, recording every path into
/// `field`, then refines the field; returns the pass's image (an unbiased estimate, for
/// [`combine`](crate::passes::combine)). Training passes draw from random streams of their
/// own, numbered by `iteration`; `guide_probability` fixes the guide's share (`None`: the
/// field's learned one, or the peer's fixed one).
pub fn training_pass<B: Backend>(
    scene: &Scene,
    field: &mut B,
    size: (usize, usize),
    spp: u32,
    seed: u64,
    iteration: u32,
    guide_probability: Option<f32>,
) -> PassImage {
    let pass = TrainingPass {
        size,
        spp,
        seed,
        iteration,
        guide_probability,
        roulette: Roulette::Classic,
    };
    training_pass_with(scene, field, &pass, None)
}

/// What a training pass renders.
#[derive(Clone, Copy, Debug)]
pub struct TrainingPass {
    /// Image size.
    pub size: (usize, usize),
    /// Samples per pixel.
    pub spp: u32,
    /// The render's seed.
    pub seed: u64,
    /// The pass's number among the training passes.
    pub iteration: u32,
    /// A fixed guide probability (`None`: the field's learned one, or the peer's).
    pub guide_probability: Option<f32>,
    /// The roulette where no splitting policy decides.
    pub roulette: Roulette,
}

/// [`training_pass`], and with `rrs` — a splitting mode and the render's passes so far — with
/// efficiency-aware roulette and splitting, every traced continuation recorded into the field
/// (an sdguide field; the peer's paths keep classic roulette).
pub fn training_pass_with<B: Backend>(
    scene: &Scene,
    field: &mut B,
    pass: &TrainingPass,
    rrs: Option<(SplittingMode, &[PassImage])>,
) -> PassImage {
    let guiding = Guiding {
        field: &*field,
        record: true,
        guide_probability: pass.guide_probability,
    };
    let mut image = PassImage::new(pass.size.0, pass.size.1);
    let estimates =
        rrs.and_then(|(mode, passes)| splitting(&passes.iter().collect::<Vec<_>>(), mode));
    let continuations = match (rrs, field.as_field()) {
        (Some(_), Some(f)) => Some(continuations_of(f, estimates.as_ref(), true)),
        _ => None,
    };
    render_pass_image(
        scene,
        Some(guiding),
        (pass.roulette, continuations.as_ref()),
        &mut image,
        (pass.spp, pass.seed, TRAINING_PASS | pass.iteration),
    );
    field.refine();
    image
}

/// The continuation policy of a pass: `field`'s estimates, and the image's when there are any.
pub(crate) fn continuations_of<'a>(
    field: &'a GuidingField,
    estimates: Option<&'a PixelEstimates>,
    record: bool,
) -> Continuations<'a> {
    Continuations {
        field,
        splitting: estimates.map(|e| e.splitting),
        pixels: estimates.map_or(&[], |e| &e.pixels),
        record,
    }
}
