//! The methods the demo compares at equal time — unguided path tracing, and guided path
//! tracing that first trains its backend's field (training time counts against the budget) —
//! and what one method's render produced.

use crate::backend::{Backend, Unguided};
use crate::image::Image;
use crate::integrator::{Guiding, Roulette};
use crate::passes::{POLICY_SPP, PassImage, combine};
use crate::render::{TrainingPass, continuing, render_pass_image, training_pass_with};
use crate::scene::Scene;
use glam::Vec3;
use sdguide::{Aabb, GuidingConfig, GuidingField, LeafRule, SplittingMode};
use std::time::{Duration, Instant};

/// What a guided vertex costs in this renderer, relative to one that samples only the BSDF:
/// the library leaves `guide_cost` off unless the renderer measured it, and this is the demo's
/// measurement (`render --cost` on `door`: a guided vertex 1.2–1.3× an unguided one). Its
/// methods pass it unless `--guide-cost` says otherwise.
pub const GUIDE_COST: f32 = 0.25;

/// The guided method the demo recommends, and its report's verdict reads: the l2 rule for the
/// guide–BSDF mixture's estimator (a renderer samples the guide in that mixture), with the
/// library's efficiency-aware roulette and splitting. Per sample it is ahead of the l1 and
/// plain l2 rules on every scene with that roulette (docs/render.md, "The rule inside the
/// mixture"); plain l2, the library's default rule, is for throughput roulette.
pub const RECOMMENDED: (Method, Rrs) = (Method::Guided(LeafRule::L2Mixture), Rrs::Ears);

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
    /// Intel Open PGL's guided Russian roulette, from its radiance cache's adjoint and the
    /// image's pixel estimates ([`Roulette::Guided`]): the peer's own; sdguide's methods and
    /// unguided ones have no radiance cache and do not run it.
    Guided,
}

impl Rrs {
    /// The library's splitting mode (`None`: none, [`Rrs::roulette`] decides).
    pub fn mode(self) -> Option<SplittingMode> {
        match self {
            Rrs::Classic | Rrs::None | Rrs::Guided => None,
            Rrs::Ear => Some(SplittingMode::Roulette),
            Rrs::Ears => Some(SplittingMode::RouletteAndSplitting),
        }
    }

    /// The roulette where no splitting policy decides (before a splitting render's first
    /// estimates, and in the peer's paths).
    pub fn roulette(self) -> Roulette {
        match self {
            Rrs::None => Roulette::Off,
            Rrs::Guided => Roulette::Guided,
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
            Rrs::Guided => "-grr",
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
    /// Path guiding with Intel Open PGL's field, with or without its cosine product (the demo
    /// built with the `openpgl` feature).
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
            Method::OpenPgl {
                cosine_product: false,
            } => "openpgl",
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
    /// Guided roulette (`grr`) is the peer's alone.
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
    let rrs = training.rrs;
    if rrs == Rrs::Guided && !matches!(method, Method::OpenPgl { .. }) {
        return Err("guided roulette (`grr`) is Open PGL's: it needs its radiance cache".into());
    }
    let mut schedule = Schedule {
        start,
        budget,
        size: (width, height),
        seed,
        guide_probability: training.guide_probability,
        mode: rrs.mode(),
        roulette: rrs.roulette(),
    };
    // A scene with media guides its medium vertices with volume guides.
    let new_field = |config: GuidingConfig| {
        let volumes = config.volumes || !scene.media.is_empty();
        GuidingField::new(field_bounds(scene), GuidingConfig { volumes, ..config })
            .map_err(|e| e.to_string())
    };
    let (rendered, field) = match method {
        Method::Unguided if schedule.mode.is_none() => (
            schedule.finish(scene, None::<&Unguided>, Trained::default(), progress),
            None,
        ),
        Method::Unguided => {
            // A field that only learns continuations: its guide is never drawn.
            let mut field = new_field(training.config.clone())?;
            schedule.guide_probability = Some(0.0);
            let trained = schedule.train(scene, &mut field, progress);
            (
                schedule.finish(scene, Some(&field), trained, progress),
                Some(field),
            )
        }
        Method::Guided(rule) => {
            let (field, trained) = match training.cache {
                Some(cached) => (cached, Trained::default()),
                None => {
                    let mut field = new_field(GuidingConfig {
                        rule,
                        ..training.config.clone()
                    })?;
                    let trained = schedule.train(scene, &mut field, progress);
                    (field, trained)
                }
            };
            (
                schedule.finish(scene, Some(&field), trained, progress),
                Some(field),
            )
        }
        Method::OpenPgl { cosine_product } => {
            // The peer has no splitting: it plays classic roulette instead, or its own.
            schedule.mode = None;
            (peer(scene, &schedule, cosine_product, progress)?, None)
        }
    };
    Ok(Outcome {
        method,
        rrs: if schedule.mode == rrs.mode() {
            rrs
        } else {
            Rrs::Classic
        },
        image: rendered.image,
        combined: rendered.combined,
        spp: rendered.spp,
        training_spp: rendered.training_spp,
        training_time: rendered.training_time,
        total_time: start.elapsed(),
        field,
    })
}

/// Trains and renders with Intel Open PGL's field.
#[cfg(feature = "openpgl")]
fn peer(
    scene: &Scene,
    schedule: &Schedule,
    cosine_product: bool,
    progress: Progress<'_>,
) -> Result<Finished, String> {
    let threads = rayon::current_num_threads();
    let mut guide = crate::openpgl::Guide::new(field_bounds(scene), cosine_product, threads)?;
    let trained = schedule.train(scene, &mut guide, progress);
    Ok(schedule.finish(scene, Some(&guide), trained, progress))
}

/// Without the `openpgl` feature there is no peer to render with.
#[cfg(not(feature = "openpgl"))]
fn peer(_: &Scene, _: &Schedule, _: bool, _: Progress<'_>) -> Result<Finished, String> {
    Err("Open PGL needs the demo built with `--features openpgl`".into())
}

/// What a method's render produced, before its field is handed back.
struct Finished {
    image: Image,
    combined: Image,
    spp: u32,
    training_spp: u32,
    training_time: Duration,
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
    fn train<B: Backend>(&self, scene: &Scene, field: &mut B, progress: Progress<'_>) -> Trained {
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
            let image = training_pass_with(scene, field, &pass, (self.mode, images.as_slice()));
            images.push(image);
            spp_total += spp;
            last = began.elapsed();
            last_spp = spp;
            progress(
                &format!("training, pass {}", iteration + 1),
                self.fraction(0),
                spp_total,
            );
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

impl Schedule {
    /// The fraction of the budget used, `spp` samples per pixel into the final render.
    fn fraction(&self, spp: u32) -> f32 {
        match (self.budget.time, self.budget.spp) {
            (Some(t), _) => self.start.elapsed().as_secs_f32() / t.as_secs_f32(),
            (None, Some(n)) => spp as f32 / n as f32,
            (None, None) => 1.0,
        }
    }

    /// The final render, with `backend` frozen (or none), until the budget is spent; combined
    /// with the training passes' images by inverse variance.
    fn finish<B: Backend>(
        &self,
        scene: &Scene,
        backend: Option<&B>,
        trained: Trained,
        progress: Progress<'_>,
    ) -> Finished {
        let Trained {
            spp: training_spp,
            time: training_time,
            mut passes,
        } = trained;
        let (budget, seed) = (self.budget, self.seed);
        let guiding = backend.map(|field| Guiding {
            field,
            record: false,
            guide_probability: self.guide_probability,
        });
        let continuation_field = backend
            .and_then(Backend::as_field)
            .filter(|_| self.mode.is_some());
        let mut image = PassImage::new(self.size.0, self.size.1);
        let mut estimates = None;
        loop {
            let done = match (budget.time, budget.spp) {
                (Some(t), cap) => self.start.elapsed() >= t || cap.is_some_and(|n| image.spp >= n),
                (None, Some(n)) => image.spp >= n,
                (None, None) => true,
            };
            if done {
                break;
            }
            let pass = image.spp;
            // The image's estimates so far, for this pass's roulette and splitting, renewed
            // each time the final image's samples double: they combine every pass's image on
            // one thread, which after every 1-spp pass took 2.0 s of an unguided `glossy-box`
            // render's 14 s final render, and later samples move them less.
            if pass == 0 || pass.is_power_of_two() {
                let all: Vec<&PassImage> = passes.iter().chain([&image]).collect();
                estimates = crate::render::estimates(&all, self.mode, self.roulette);
            }
            let continuing =
                continuing(self.roulette, continuation_field, estimates.as_ref(), false);
            render_pass_image(scene, guiding, &continuing, &mut image, (1, seed, pass));
            progress("rendering", self.fraction(image.spp), image.spp);
        }
        let spp = image.spp;
        let final_image = image.mean();
        passes.push(image);
        let combined = combine(&passes).unwrap_or_else(|| final_image.clone());
        Finished {
            image: final_image,
            combined,
            spp,
            training_spp,
            training_time,
        }
    }
}
