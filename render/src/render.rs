//! Rendering passes: the image in tiles with rayon, one random stream per pixel and pass, with
//! any guiding backend; and training passes, which record every path and refine the backend.
//! What a method renders within its budget is [`method`](crate::method)'s.

use crate::backend::Backend;
use crate::image::Image;
use crate::integrator::{Continuations, Continuing, Guiding, Roulette, Scratch, path_sample};
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
        &Continuing::CLASSIC,
        size,
        (spp, seed, pass),
        |pixel, l, _| {
            sum.pixels[pixel] += l;
        },
    );
}

/// [`render_pass`] into a [`PassImage`], which also keeps each pixel's squared luminance (for
/// the pass's variance) and the rays traced; the paths continuing as `continuing` says.
pub fn render_pass_image<B: Backend>(
    scene: &Scene,
    guiding: Option<Guiding<'_, B>>,
    continuing: &Continuing<'_>,
    image: &mut PassImage,
    (spp, seed, pass): (u32, u64, u32),
) {
    let size = (image.sum.width, image.sum.height);
    let rays = render_samples(
        scene,
        guiding,
        continuing,
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
    continuing: &Continuing<'_>,
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
                            (continuing, index),
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
    training_pass_with(scene, field, &pass, (None, &[]))
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

/// [`training_pass`] given the render's passes so far: with a splitting mode, efficiency-aware
/// roulette and splitting, every traced continuation recorded into the field (an sdguide
/// field; the peer's paths play their roulette); under guided roulette, the passes' pixel
/// estimates.
pub fn training_pass_with<B: Backend>(
    scene: &Scene,
    field: &mut B,
    pass: &TrainingPass,
    (mode, passes): (Option<SplittingMode>, &[PassImage]),
) -> PassImage {
    let guiding = Guiding {
        field: &*field,
        record: true,
        guide_probability: pass.guide_probability,
    };
    let mut image = PassImage::new(pass.size.0, pass.size.1);
    let passes: Vec<&PassImage> = passes.iter().collect();
    let estimates = estimates(&passes, mode, pass.roulette);
    let continuation_field = mode.and(field.as_field());
    let continuing = continuing(pass.roulette, continuation_field, estimates.as_ref(), true);
    render_pass_image(
        scene,
        Some(guiding),
        &continuing,
        &mut image,
        (pass.spp, pass.seed, TRAINING_PASS | pass.iteration),
    );
    field.refine();
    image
}

/// What the passes so far say about the image, where a pass's paths need it: for roulette and
/// splitting by `mode`, or for guided roulette (then the policy is roulette's, unused).
pub(crate) fn estimates(
    passes: &[&PassImage],
    mode: Option<SplittingMode>,
    roulette: Roulette,
) -> Option<PixelEstimates> {
    let mode = match (mode, roulette) {
        (Some(mode), _) => mode,
        (None, Roulette::Guided) => SplittingMode::Roulette,
        (None, _) => return None,
    };
    splitting(passes, mode)
}

/// How a pass's paths continue: by `roulette`, and with efficiency-aware roulette and splitting
/// by `field`'s continuation estimates where there is a field and the image's estimates.
pub(crate) fn continuing<'a>(
    roulette: Roulette,
    field: Option<&'a GuidingField>,
    estimates: Option<&'a PixelEstimates>,
    record: bool,
) -> Continuing<'a> {
    Continuing {
        roulette,
        continuations: field.map(|field| Continuations {
            field,
            splitting: estimates.map(|e| e.splitting),
            record,
        }),
        pixels: estimates.map_or(&[], |e| &e.pixels),
    }
}
