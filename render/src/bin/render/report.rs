//! The report: the run's settings, one table per scene and seed, the summary over seeds, and
//! the probe and cost reports of a trained cache.

use crate::cli::Args;
use sdguide::GuidingField;
use sdguide_render::cost::paired_cost;
use sdguide_render::method::{Method, Outcome, RECOMMENDED};
use sdguide_render::reference;
use sdguide_render::scene::Scene;
use std::fmt::Write as _;

/// One seed's renders of a scene, one per method, and each one's error.
pub struct Run {
    pub seed: u64,
    pub reference: Option<reference::Description>,
    pub outcomes: Vec<Rendered>,
}

/// One method's render, and its error against the reference.
pub struct Rendered {
    pub outcome: Outcome,
    /// Whether its field came from `--cache`.
    pub reused: bool,
    /// The final image's relMSE, and its mean's deviation in standard errors.
    pub error: Option<(f64, f64)>,
    /// relMSE of the image combined with the training passes (equal to the final image's for
    /// unguided).
    pub combined_error: Option<f64>,
}

impl Run {
    /// Method `i`'s time per spp over method `base`'s.
    fn cost(&self, i: usize, base: usize) -> f64 {
        let (b, o) = (&self.outcomes[base].outcome, &self.outcomes[i].outcome);
        o.time_per_spp().as_secs_f64() / b.time_per_spp().as_secs_f64().max(1e-12)
    }

    /// Method `i`'s (relMSE of the combined image, relMSE × spp of the final one, time per
    /// spp), each over unguided's.
    fn ratios(&self, i: usize) -> Option<(f64, f64, f64)> {
        self.ratios_to(i, 0)
    }

    /// Method `i`'s relMSE × spp over that of unguided with the same roulette (without
    /// splitting, the peer's), when the run has it.
    fn per_sample_same_roulette(&self, i: usize) -> Option<f64> {
        Some(self.ratios_to(i, self.same_roulette(i)?)?.1)
    }

    /// The unguided method with method `i`'s roulette and splitting, when the run has it.
    fn same_roulette(&self, i: usize) -> Option<usize> {
        let rrs = self.outcomes[i].outcome.rrs;
        self.outcomes
            .iter()
            .position(|r| r.outcome.method == Method::Unguided && r.outcome.rrs == rrs)
    }

    /// [`Run::ratios`] over method `base`'s instead of unguided's.
    fn ratios_to(&self, i: usize, base: usize) -> Option<(f64, f64, f64)> {
        let (b, o) = (&self.outcomes[base].outcome, &self.outcomes[i].outcome);
        let combined = (
            self.outcomes[i].combined_error,
            self.outcomes[base].combined_error,
        );
        match (self.outcomes[i].error, self.outcomes[base].error, combined) {
            // relMSE falls as 1/spp, so relMSE × spp compares methods per sample.
            (Some((e, _)), Some((e0, _)), (Some(c), Some(c0))) => Some((
                c / c0,
                (e * o.spp as f64) / (e0 * b.spp.max(1) as f64),
                self.cost(i, base),
            )),
            _ => None,
        }
    }
}

/// The probe table: at the first surface behind each of nine pixels, where the trained guide's
/// draws go, plain and times the clamped cosine.
pub fn probe_report(scene: &Scene, field: &GuidingField, args: &Args) -> String {
    const DRAWS: u32 = 100_000;
    let aspect = args.width as f32 / args.height as f32;
    let mut r = format!(
        "# Probes of a trained field in `{}` ({DRAWS} draws per distribution and point)\n\n\
         | film | position | normal | below surface: plain | times cosine | to a light: plain | \
         times cosine |\n|---|---|---|---:|---:|---:|---:|\n",
        scene.name
    );
    for p in sdguide_render::probe::probe(scene, field, aspect, DRAWS) {
        let v = |v: glam::Vec3| format!("({:.2}, {:.2}, {:.2})", v.x, v.y, v.z);
        let _ = writeln!(
            r,
            "| ({:.1}, {:.1}) | {} | {} | {:.1}% | {:.2}% | {:.1}% | {:.1}% |",
            p.film.x,
            p.film.y,
            v(p.position),
            v(p.normal),
            100.0 * p.plain_below,
            100.0 * p.surface_below,
            100.0 * p.plain_to_light,
            100.0 * p.surface_to_light
        );
    }
    r
}

pub fn cost_report(
    scene: &Scene,
    field: &GuidingField,
    path: &std::path::Path,
    args: &Args,
) -> String {
    const SPP: u32 = 2;
    let cost = paired_cost(scene, field, (args.width, args.height), SPP, args.rounds);
    let stats = field.stats();
    let mut r = format!(
        "# What a guided sample costs in `{}`, guided by {}\n\n\
         {} rounds of two passes of {SPP} spp at {}×{} on {} threads, one unguided and one \
         guided by the cache (its learned guide probabilities, classic roulette; the guide off \
         in {} of its {} spatial cells), the unguided one first in every other round.\n\n",
        scene.name,
        path.display(),
        args.rounds,
        args.width,
        args.height,
        rayon::current_num_threads(),
        stats.guides_off,
        stats.spatial_leaves,
    );
    if let Some([lo, q1, median, q3, hi]) = cost.spread() {
        let mut unguided: Vec<f64> = cost.unguided.iter().map(|t| t.as_secs_f64()).collect();
        unguided.sort_by(f64::total_cmp);
        let samples = f64::from(args.rounds) * f64::from(SPP) * (args.width * args.height) as f64;
        let _ = writeln!(
            r,
            "Guided pass ÷ unguided pass of the same round: median **{median:.3}** (quartiles \
             {q1:.3}–{q3:.3}, range {lo:.3}–{hi:.3}). Unguided pass: {:.3} s (median). Rays per \
             sample: unguided {:.2}, guided {:.2}.",
            unguided[unguided.len() / 2],
            cost.rays[0] / samples,
            cost.rays[1] / samples,
        );
    }
    r
}

/// What the report says of the peer's wiring.
#[cfg(feature = "openpgl")]
const PEER_SETTINGS: &str = concat!(
    "Peer: Intel Open PGL ",
    env!("OPENPGL_VERSION"),
    " built with its radiance caches, its default field (a kd-tree of parallax-aware VMMs, at \
     most 32000 samples per leaf, deterministic), the surface sampling distribution at every \
     vertex (`openpgl-cos`: with its cosine product), guide probability ½ unless fixed, the \
     same mixture, MIS, recorded radiance and training schedule as sdguide's methods. `-grr`: \
     its guided Russian roulette from the second vertex, the adjoint from its radiance cache \
     and the pixel estimate from the passes so far (the demo's, as sdguide's roulette gets it: \
     Open PGL's image-space guiding buffer needs Open Image Denoise, not built here)."
);
#[cfg(not(feature = "openpgl"))]
const PEER_SETTINGS: &str = "";

/// The report's title and settings.
pub fn header(args: &Args, command: &str) -> String {
    let mut r = String::new();
    let budget = match args.budget.time {
        Some(t) => format!("{:.0} s per method", t.as_secs_f32()),
        None => "no time limit".into(),
    };
    let names: Vec<String> = args.scenes.iter().map(|s| format!("`{s}`")).collect();
    let seeds = match args.seeds {
        1 => format!("seed {}", args.seed),
        n => format!("seeds {}–{}", args.seed, args.seed + n - 1),
    };
    let _ = writeln!(r, "# sdguide render: {}\n", names.join(", "));
    let _ = writeln!(
        r,
        "{}×{}, {budget}{}, training share {}, guide probability {}, next-event estimation {}, \
         {} threads, {seeds}. Command: `{command}`\n",
        args.width,
        args.height,
        args.budget
            .spp
            .map_or(String::new(), |n| format!(", at most {n} spp")),
        args.budget.training_share,
        args.guide_probability.map_or(
            format!(
                "learned up to {}, off where it does not pay {}",
                args.max_guide_probability,
                args.guide_cost
                    .map_or("(never)".into(), |c| format!("a cost of {c}"))
            ),
            |p| format!("fixed at {p}")
        ),
        if args.nee { "on" } else { "off" },
        rayon::current_num_threads(),
    );
    if !args.peers.is_empty() {
        let _ = writeln!(r, "{}\n", PEER_SETTINGS);
    }
    r
}

/// A scene's section: its reference, and one table per seed.
pub fn scene_report(scene: &Scene, args: &Args, runs: &[Run]) -> String {
    let mut r = String::new();
    if args.scenes.len() > 1 {
        let _ = writeln!(r, "## `{}`\n", scene.name);
    }
    match runs.first().and_then(|run| run.reference.as_ref()) {
        Some(d) => {
            let _ = writeln!(
                r,
                "Reference: {} spp, fingerprint {:016x} (matches the scene), rendered from \
                 seed {} (streams of its own).\n",
                d.spp,
                d.fingerprint,
                d.seed.unwrap_or_default()
            );
        }
        None => {
            let _ = writeln!(
                r,
                "No reference for this scene and resolution: no errors.\n"
            );
        }
    }
    for run in runs {
        if runs.len() > 1 {
            let _ = writeln!(r, "Seed {}:\n", run.seed);
        }
        r += &seed_table(run);
    }
    r
}

fn seed_table(run: &Run) -> String {
    let mut r = String::from(
        "| method | spp | training | total time | relMSE | with training passes | relMSE vs \
         unguided | per sample vs unguided | per sample vs unguided, same roulette | time per \
         spp vs unguided | mean vs reference |\n\
         |---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (i, rendered) in run.outcomes.iter().enumerate() {
        let o = &rendered.outcome;
        let training = match (o.training_spp, rendered.reused) {
            (0, false) => "—".to_string(),
            (_, true) => "from cache".to_string(),
            _ => format!(
                "{:.1} s, {} spp",
                o.training_time.as_secs_f32(),
                o.training_spp
            ),
        };
        let cost = run.cost(i, 0);
        let (error, deviation) = match rendered.error {
            Some((e, z)) => (format!("{e:.5}"), format!("{z:+.1}σ")),
            None => ("—".into(), "—".into()),
        };
        let combined = rendered
            .combined_error
            .map_or("—".into(), |e| format!("{e:.5}"));
        let (ratio, per_sample) = match run.ratios(i) {
            Some((ratio, per_sample, _)) => (format!("{ratio:.3}×"), format!("{per_sample:.3}×")),
            None => ("—".into(), "—".into()),
        };
        let same = run
            .per_sample_same_roulette(i)
            .map_or("—".into(), |x| format!("{x:.3}×"));
        let _ = writeln!(
            r,
            "| {} | {} | {training} | {:.1} s | {error} | {combined} | {ratio} | {per_sample} | \
             {same} | {cost:.2}× | {deviation} |",
            o.name(),
            o.spp,
            o.total_time.as_secs_f32(),
        );
    }
    r.push('\n');
    r
}

/// The mean of ratios over seeds, with their range when there are several; `—` for none.
fn spread(v: &[f64]) -> String {
    if v.is_empty() {
        return "—".to_string();
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    if v.len() == 1 {
        format!("{mean:.3}×")
    } else {
        format!("{mean:.3}× ({lo:.3}–{hi:.3})")
    }
}

/// The report's opening line: per scene, what the recommended configuration ([`RECOMMENDED`]:
/// the l2m rule with efficiency-aware roulette and splitting) bought at equal time, training
/// included, against unguided path tracing with classic roulette and with the same roulette
/// and splitting (mean and range over seeds). Empty when the run has no such method.
pub fn verdict(scenes: &[(String, Vec<Run>)]) -> String {
    let mut lines = Vec::new();
    for (name, runs) in scenes {
        let (mut classic, mut same) = (Vec::new(), Vec::new());
        for run in runs {
            let Some(i) = run
                .outcomes
                .iter()
                .position(|r| (r.outcome.method, r.outcome.rrs) == RECOMMENDED)
            else {
                continue;
            };
            classic.extend(run.ratios(i).map(|r| r.0));
            same.extend(
                run.same_roulette(i)
                    .and_then(|base| run.ratios_to(i, base))
                    .map(|r| r.0),
            );
        }
        if classic.is_empty() {
            continue;
        }
        let image = match runs.len() {
            1 => format!("`{name}-compare.png`"),
            _ => format!("`{name}-compare-seed<N>.png`"),
        };
        lines.push(format!(
            "on `{name}`, **{}** the relMSE of unguided path tracing with classic roulette, {} \
             that of unguided with the same roulette and splitting ({image})",
            spread(&classic),
            spread(&same),
        ));
    }
    if lines.is_empty() {
        return String::new();
    }
    format!(
        "**Verdict.** Guided by sdguide (the l2 rule for the guide–BSDF mixture, with its \
         efficiency-aware roulette and splitting), at equal time, training included: {}.\n\n",
        lines.join("; ")
    )
}

/// Mean and range over the seeds of each scene's ratios to unguided, per method.
pub fn summary(scenes: &[(String, Vec<Run>)]) -> String {
    let seeds = scenes.first().map_or(0, |(_, runs)| runs.len());
    let mut r = format!(
        "## Summary over {seeds} seed{}: mean (min–max) of the ratios to unguided\n\n\
         | scene | method | relMSE vs unguided | per sample vs unguided | per sample vs \
         unguided, same roulette | time per spp vs unguided |\n|---|---|---:|---:|---:|---:|\n",
        if seeds == 1 { "" } else { "s" }
    );
    for (name, runs) in scenes {
        let methods = runs.first().map_or(0, |run| run.outcomes.len());
        for i in 1..methods {
            let ratios: Vec<(f64, f64, f64)> =
                runs.iter().filter_map(|run| run.ratios(i)).collect();
            let column = |of: fn(&(f64, f64, f64)) -> f64| {
                spread(&ratios.iter().map(of).collect::<Vec<_>>())
            };
            let same: Vec<f64> = runs
                .iter()
                .filter_map(|run| run.per_sample_same_roulette(i))
                .collect();
            let _ = writeln!(
                r,
                "| {name} | {} | {} | {} | {} | {} |",
                runs[0].outcomes[i].outcome.name(),
                column(|t| t.0),
                column(|t| t.1),
                spread(&same),
                column(|t| t.2)
            );
        }
    }
    r.push('\n');
    r
}

pub fn footnotes() -> String {
    "relMSE: the final render's. With training passes: the final render and the training \
     passes combined by inverse variance; relMSE vs unguided compares these, what each \
     method's whole budget bought. Per sample: the final render's relMSE × spp over \
     unguided's (with classic roulette; same roulette: over unguided's with the method's \
     roulette and splitting, the peer's without splitting). Time per spp: the final render's, \
     training excluded. Mean vs reference: the image mean's distance from the reference's in \
     standard errors of the pixel differences (|z| ≤ 3 for an unbiased render).\n\n\
     Images: `<scene>-<method>.png` (tone-mapped) and `.exr` (linear), `-seed<N>` added when \
     several seeds run; `<scene>-compare.png`: reference and methods on top, per-pixel relative \
     squared error below (log scale, 10⁻⁴ black to 10 yellow; the ramp is under the \
     reference).\n"
        .to_string()
}
