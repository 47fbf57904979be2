//! Rendering: passes over the image in tiles with rayon, and the three methods compared at equal
//! time — unguided path tracing, and guided path tracing that first trains its field (training
//! time counts against the budget).

use crate::image::Image;
use crate::integrator::{Continuations, Guide, Guiding, Roulette, path_sample};
use crate::material::luminance;
use crate::passes::{POLICY_SPP, PassImage, PixelEstimates, combine, splitting};
use crate::rng::Rng;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use sdguide::{Aabb, GuidingConfig, GuidingField, LeafRule, SplittingMode};
use std::time::{Duration, Instant};

/// Tile edge, pixels.
const TILE: usize = 16;

/// Pass numbers at and above this are training passes (the final render counts from 0).
const TRAINING_PASS: u32 = 1 << 31;

/// Renders `spp` samples per pixel into `sum` (added, not averaged), pass `pass` of a render
/// seeded by `seed`. With `guiding`, paths sample the field (and record into it if asked).
pub fn render_pass(
    scene: &Scene,
    guiding: Option<Guiding<'_>>,
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
pub fn render_pass_image(
    scene: &Scene,
    guiding: Option<Guiding<'_>>,
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
fn render_samples(
    scene: &Scene,
    guiding: Option<Guiding<'_>>,
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
                            &mut rng,
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

/// A guiding field the demo can train: sdguide's, or the peer's.
pub trait Trainable {
    /// The field as the integrator samples and records it.
    fn guide(&self) -> Guide<'_>;
    /// Rebuilds the sampling distributions from what was recorded (between passes).
    fn refine(&mut self);
    /// The field as an sdguide field, whose cells also learn continuation estimates for
    /// roulette and splitting (`None` for the peer's).
    fn continuation_field(&self) -> Option<&GuidingField> {
        None
    }
}

impl Trainable for GuidingField {
    fn guide(&self) -> Guide<'_> {
        Guide::Sdguide(self)
    }

    fn continuation_field(&self) -> Option<&GuidingField> {
        Some(self)
    }

    fn refine(&mut self) {
        GuidingField::refine(self);
    }
}

#[cfg(feature = "openpgl")]
impl Trainable for crate::openpgl::Guide {
    fn guide(&self) -> Guide<'_> {
        Guide::OpenPgl(self)
    }

    fn refine(&mut self) {
        self.update();
    }
}

/// One training pass: renders `spp` samples per pixel at `size`, recording every path into
/// `field`, then refines the field; returns the pass's image (an unbiased estimate, for
/// [`combine`]). Training passes draw from random streams of their own, numbered by
/// `iteration`; `guide_probability` fixes the guide's share (`None`: the field's learned one,
/// or the peer's fixed one).
pub fn training_pass(
    scene: &Scene,
    field: &mut impl Trainable,
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
pub fn training_pass_with(
    scene: &Scene,
    field: &mut impl Trainable,
    pass: &TrainingPass,
    rrs: Option<(SplittingMode, &[PassImage])>,
) -> PassImage {
    let guiding = Guiding {
        field: field.guide(),
        record: true,
        guide_probability: pass.guide_probability,
    };
    let mut image = PassImage::new(pass.size.0, pass.size.1);
    let estimates =
        rrs.and_then(|(mode, passes)| splitting(&passes.iter().collect::<Vec<_>>(), mode));
    let continuations = match (rrs, field.continuation_field()) {
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
fn continuations_of<'a>(
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

/// How a method decides how many continuations to trace from a vertex.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Rrs {
    /// Classic Russian roulette by path throughput, from the third bounce.
    #[default]
    Classic,
    /// Efficiency-aware Russian roulette (no splitting).
    Ear,
    /// Efficiency-aware Russian roulette and splitting.
    Ears,
    /// No roulette: paths go on to the longest path's depth.
    None,
}

impl Rrs {
    /// The library's splitting mode (`None`: none, [`Rrs::roulette`] decides).
    pub fn mode(self) -> Option<SplittingMode> {
        match self {
            Rrs::Classic | Rrs::None => None,
            Rrs::Ear => Some(SplittingMode::Roulette),
            Rrs::Ears => Some(SplittingMode::RouletteAndSplitting),
        }
    }

    /// The roulette where no splitting policy decides (before a splitting render's first
    /// estimates, and in the peer's paths).
    pub fn roulette(self) -> Roulette {
        match self {
            Rrs::None => Roulette::Off,
            _ => Roulette::Classic,
        }
    }

    /// The suffix of a method's name in reports and file names.
    pub fn suffix(self) -> &'static str {
        match self {
            Rrs::Classic => "",
            Rrs::Ear => "-ear",
            Rrs::Ears => "-ears",
            Rrs::None => "-no-rr",
        }
    }
}

/// A rendering method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Path tracing with BSDF sampling and next-event estimation.
    Unguided,
    /// Path guiding with the given leaf rule.
    Guided(LeafRule),
    /// Path guiding with Intel Open PGL's field, with or without its cosine product.
    #[cfg(feature = "openpgl")]
    OpenPgl {
        /// Whether each vertex's distribution is multiplied by the clamped cosine.
        cosine_product: bool,
    },
}

impl Method {
    /// The method's name in reports and file names.
    pub fn name(self) -> &'static str {
        match self {
            Method::Unguided => "unguided",
            Method::Guided(LeafRule::L1) => "guided-l1",
            Method::Guided(LeafRule::L2) => "guided-l2",
            Method::Guided(LeafRule::L2Mixture) => "guided-l2m",
            Method::Guided(_) => "guided",
            #[cfg(feature = "openpgl")]
            Method::OpenPgl {
                cosine_product: false,
            } => "openpgl",
            #[cfg(feature = "openpgl")]
            Method::OpenPgl {
                cosine_product: true,
            } => "openpgl-cos",
        }
    }
}

/// How long a method may run.
#[derive(Clone, Copy, Debug)]
pub struct Budget {
    /// Wall-clock budget, training included (`None`: unlimited, then `spp` must be set).
    pub time: Option<Duration>,
    /// Cap on the final render's samples per pixel.
    pub spp: Option<u32>,
    /// Share of the time budget training may use (guided methods).
    pub training_share: f32,
    /// Training passes when there is no time budget (samples 1, 2, 4, …).
    pub training_iterations: u32,
}

impl Default for Budget {
    fn default() -> Self {
        Budget {
            time: Some(Duration::from_secs(40)),
            spp: None,
            training_share: 0.3,
            training_iterations: 7,
        }
    }
}

/// What a method produced.
pub struct Outcome {
    /// The method.
    pub method: Method,
    /// Its roulette and splitting.
    pub rrs: Rrs,
    /// The final image (average of the final render's samples).
    pub image: Image,
    /// The final image and the training passes' combined by inverse variance: what the
    /// method's whole budget bought (the final image for unguided and a reused cache).
    pub combined: Image,
    /// Samples per pixel of the final render.
    pub spp: u32,
    /// Samples per pixel spent on training.
    pub training_spp: u32,
    /// Time spent training (zero for unguided or a reused cache).
    pub training_time: Duration,
    /// Total wall-clock time.
    pub total_time: Duration,
    /// The trained field, for sdguide's guided methods.
    pub field: Option<GuidingField>,
}

impl Outcome {
    /// The method's name with its roulette and splitting, in reports and file names.
    pub fn name(&self) -> String {
        format!("{}{}", self.method.name(), self.rrs.suffix())
    }

    /// Wall-clock time of the final render per sample per pixel (training excluded).
    pub fn time_per_spp(&self) -> Duration {
        (self.total_time.saturating_sub(self.training_time)) / self.spp.max(1)
    }
}

/// Called after every pass with (phase, fraction of the budget used, samples per pixel so far).
pub type Progress<'a> = &'a (dyn Fn(&str, f32, u32) + Sync);

/// The guiding field's bounds for a scene: its bounding box, slightly enlarged.
pub fn field_bounds(scene: &Scene) -> Aabb {
    let (lo, hi) = scene.bounds();
    let pad = (hi - lo) * 0.01 + Vec3::splat(1e-3);
    Aabb::new(lo - pad, hi + pad)
}

/// How a guided method gets its field.
pub struct Training<'a> {
    /// The configuration of a newly trained field (its `rule` is the method's).
    pub config: &'a GuidingConfig,
    /// A trained field to use instead of training one.
    pub cache: Option<GuidingField>,
    /// A fixed probability of sampling the guide instead of the BSDF; `None` uses the field's
    /// learned one.
    pub guide_probability: Option<f32>,
    /// Roulette and splitting. With splitting (`ear`, `ears`), unguided methods too train a
    /// field (which learns only the continuation estimates: the guide is never drawn), sdguide's
    /// guided methods learn them in the field they train, and the peer plays classic roulette.
    pub rrs: Rrs,
}

/// Renders `scene` with `method` at `width × height` within `budget`. A guided method trains a
/// new field — passes of 1, 2, 4, … samples per pixel, each followed by `refine`, while the
/// next pass still fits in the training share — unless `training` brings a trained one; then it
/// renders with the field frozen until the budget is spent.
///
/// # Errors
///
/// A message when the guide cannot be made: a configuration sdguide refuses, or Open PGL
/// failing to create its field.
pub fn render(
    scene: &Scene,
    method: Method,
    (width, height): (usize, usize),
    budget: Budget,
    seed: u64,
    training: Training<'_>,
    progress: Progress<'_>,
) -> Result<Outcome, String> {
    let start = Instant::now();
    let fraction = |spp: u32| match (budget.time, budget.spp) {
        (Some(t), _) => start.elapsed().as_secs_f32() / t.as_secs_f32(),
        (None, Some(n)) => spp as f32 / n as f32,
        (None, None) => 1.0,
    };
    let rrs = training.rrs;
    let mode = rrs.mode();
    let mut schedule = Schedule {
        start,
        budget,
        size: (width, height),
        seed,
        guide_probability: training.guide_probability,
        mode,
        roulette: rrs.roulette(),
    };
    let training_progress = |pass: u32, spp: u32| {
        progress(&format!("training, pass {pass}"), fraction(0), spp);
    };
    let mut field = None;
    #[cfg(feature = "openpgl")]
    let mut peer = None;
    let mut trained = Trained::default();
    match method {
        Method::Unguided if mode.is_none() => {}
        Method::Unguided => {
            // A field that only learns continuations: its guide is never drawn.
            let mut new = GuidingField::new(field_bounds(scene), training.config.clone())
                .map_err(|e| e.to_string())?;
            schedule.guide_probability = Some(0.0);
            trained = schedule.train(scene, &mut new, &training_progress);
            field = Some(new);
        }
        Method::Guided(rule) => {
            field = Some(match training.cache {
                Some(cached) => cached,
                None => {
                    let config = GuidingConfig {
                        rule,
                        ..training.config.clone()
                    };
                    let mut new = GuidingField::new(field_bounds(scene), config)
                        .map_err(|e| e.to_string())?;
                    trained = schedule.train(scene, &mut new, &training_progress);
                    new
                }
            });
        }
        #[cfg(feature = "openpgl")]
        Method::OpenPgl { cosine_product } => {
            schedule.mode = None;
            let threads = rayon::current_num_threads();
            let mut new = crate::openpgl::Guide::new(field_bounds(scene), cosine_product, threads)?;
            trained = schedule.train(scene, &mut new, &training_progress);
            peer = Some(new);
        }
    }
    let Trained {
        spp: training_spp,
        time: training_time,
        mut passes,
    } = trained;
    let guide = field.as_ref().map(Guide::Sdguide);
    #[cfg(feature = "openpgl")]
    let guide = guide.or(peer.as_ref().map(Guide::OpenPgl));
    let guiding = guide.map(|field| Guiding {
        field,
        record: false,
        guide_probability: schedule.guide_probability,
    });
    let continuation_field = field.as_ref().filter(|_| schedule.mode.is_some());
    let mut image = PassImage::new(width, height);
    let mut estimates = None;
    loop {
        let done = match (budget.time, budget.spp) {
            (Some(t), cap) => start.elapsed() >= t || cap.is_some_and(|n| image.spp >= n),
            (None, Some(n)) => image.spp >= n,
            (None, None) => true,
        };
        if done {
            break;
        }
        let pass = image.spp;
        // The image's estimates so far, for this pass's roulette and splitting, renewed each
        // time the final image's samples double: they combine every pass's image on one thread,
        // which after every 1-spp pass took 2.0 s of an unguided `glossy-box` render's 14 s
        // final render, and later samples move them less.
        if pass == 0 || pass.is_power_of_two() {
            estimates = schedule.mode.and_then(|mode| {
                let all: Vec<&PassImage> = passes.iter().chain([&image]).collect();
                splitting(&all, mode)
            });
        }
        let continuations =
            continuation_field.map(|f| continuations_of(f, estimates.as_ref(), false));
        render_pass_image(
            scene,
            guiding,
            (schedule.roulette, continuations.as_ref()),
            &mut image,
            (1, seed, pass),
        );
        progress("rendering", fraction(image.spp), image.spp);
    }
    let spp = image.spp;
    let final_image = image.mean();
    passes.push(image);
    let combined = combine(&passes).unwrap_or_else(|| final_image.clone());
    Ok(Outcome {
        method,
        // The peer drops splitting and keeps classic roulette.
        rrs: if schedule.mode == mode {
            rrs
        } else {
            Rrs::Classic
        },
        image: final_image,
        combined,
        spp,
        training_spp,
        training_time,
        total_time: start.elapsed(),
        field,
    })
}

/// What training produced: samples per pixel, time, and the passes' images.
#[derive(Default)]
struct Trained {
    spp: u32,
    time: Duration,
    passes: Vec<PassImage>,
}

/// The training schedule every guided method follows, whichever its field.
struct Schedule {
    start: Instant,
    budget: Budget,
    size: (usize, usize),
    seed: u64,
    guide_probability: Option<f32>,
    /// Roulette and splitting (`None`: `roulette`).
    mode: Option<SplittingMode>,
    /// The roulette where no splitting policy decides.
    roulette: Roulette,
}

impl Schedule {
    /// Trains `field` in passes of 1, 2, 4, … spp; returns the training spp, time and images.
    /// With a time budget, passes continue while the next one — twice the samples, so about
    /// twice the time — still fits in the training share; then a last, smaller pass fills what
    /// is left of the share, if at least half the previous pass's samples fit (at most
    /// 2¹⁶ − 1 spp in all). With roulette and splitting, the first pass that splits takes the
    /// samples of the pass before it instead of twice them: its policy comes from a few
    /// classic samples per pixel, whose heavy-tailed variance they mostly underestimate, which
    /// makes every factor too large (on `caustic`, 4.6× classic's time per sample); the
    /// doubling resumes under a policy set by a splitting pass.
    fn train(
        &self,
        scene: &Scene,
        field: &mut impl Trainable,
        progress: &dyn Fn(u32, u32),
    ) -> Trained {
        let passes = if self.budget.time.is_some() {
            16
        } else {
            self.budget.training_iterations
        };
        let (mut spp_total, mut last) = (0, Duration::ZERO);
        let mut images: Vec<PassImage> = Vec::new();
        let mut last_spp: u32 = 0;
        for iteration in 0..passes {
            let with_policy = images.iter().filter(|p| p.spp >= POLICY_SPP).count();
            let first_split = self.mode.is_some() && with_policy == 1;
            let mut spp = match iteration {
                0 => 1,
                _ if first_split => last_spp,
                _ => 2 * last_spp,
            };
            let mut filler = false;
            if let Some(t) = self.budget.time {
                let share = t.mul_f32(self.budget.training_share);
                // The next pass, at the last one's time per sample.
                let expected = last.mul_f64(f64::from(spp) / f64::from(last_spp.max(1)));
                if self.start.elapsed() + expected > share {
                    // The next pass does not fit: a last one of the samples that do, at the
                    // last pass's time per sample, if that is at least half the last pass (a
                    // pass's time per sample changes as roulette and splitting learn).
                    let left = share.saturating_sub(self.start.elapsed()).as_secs_f64();
                    let per_spp = last.as_secs_f64() / f64::from(last_spp.max(1));
                    let fits = (left / per_spp.max(1e-9)).floor().min(f64::from(spp)) as u32;
                    if fits < last_spp.div_ceil(2).max(1) {
                        break;
                    }
                    (spp, filler) = (fits, fits < spp);
                }
            }
            let began = Instant::now();
            let pass = TrainingPass {
                size: self.size,
                spp,
                seed: self.seed,
                iteration,
                guide_probability: self.guide_probability,
                roulette: self.roulette,
            };
            let rrs = self.mode.map(|mode| (mode, images.as_slice()));
            let image = training_pass_with(scene, field, &pass, rrs);
            images.push(image);
            spp_total += spp;
            last = began.elapsed();
            last_spp = spp;
            progress(iteration + 1, spp_total);
            if filler {
                break;
            }
        }
        Trained {
            spp: spp_total,
            time: self.start.elapsed(),
            passes: images,
        }
    }
}
