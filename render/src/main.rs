//! `render`: renders a scene with unguided path tracing and with guiding (l1 and l2 rules, and
//! Intel Open PGL when built with the `openpgl` feature) in the same wall-clock budget each, and
//! reports the error of each against a stored reference.
//!
//! ```text
//! cargo run --release -p sdguide-render -- [--scene door|…|all] [--seeds 1] [--time 40]
//!     [--spp N] [--rule both] [--out out/render] [--threads N] [--seed 1] [--cache FILE] [--width 320 --height 240]
//!     [--training-share 0.3] [--guide-probability F] [--max-guide-probability F] [--guide-cost F|none] [--refinement gain|flux]
//!     [--filter box|deferred|nearest] [--spatial-threshold N] [--peer none|plain|cos|both]
//!     [--nee on|off] [--rrs classic|ear|ears|none (or a list: classic,none)]
//! cargo run --release -p sdguide-render -- --scene door --probe out/render/door-guided-l2.sdgc
//! cargo run --release -p sdguide-render -- --scene door --cost out/render/door-guided-l2.sdgc [--rounds 30]
//! cargo run --release -p sdguide-render -- --scene door --reference --spp 8192 --time 0
//! ```

use indicatif::{ProgressBar, ProgressStyle};
use sdguide::{DirectionalFilter, GuidingConfig, GuidingField, LeafRule, Refinement};
use sdguide_render::cost::paired_cost;
use sdguide_render::image::{Image, side_by_side, write_png};
use sdguide_render::reference;
use sdguide_render::render::{Budget, Method, Outcome, Rrs, Training, render};
use sdguide_render::scene::Scene;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

/// The scenes `--scene all` renders: every built-in scene with a stored reference.
const ALL_SCENES: [&str; 5] = ["door", "glossy-box", "uplight", "covered", "caustic"];

const USAGE: &str = "usage: render [--scene door|glossy-box|uplight|covered|caustic|furnace|all] \
[--seeds N] [--time SECONDS (0: none)] [--spp N] [--rule l1|l2|l2m|both|all (or a list: l1,l2m)] \
[--out DIR] [--threads N] [--seed N] [--cache FILE] \
[--width N] [--height N] [--training-share F] [--guide-probability F] [--max-guide-probability F] [--guide-cost F|none] \
[--refinement gain|flux] \
[--filter box|deferred|nearest] [--spatial-threshold N] [--peer none|plain|cos|both] \
[--nee on|off] [--rrs classic|ear|ears|none (or a list: classic,none)] [--reference] \
[--probe CACHE] [--cost CACHE [--rounds N]]";

struct Args {
    /// The scenes to render, in order.
    scenes: Vec<String>,
    /// Runs per scene, from seeds `seed, seed + 1, …`.
    seeds: u64,
    budget: Budget,
    rules: Vec<LeafRule>,
    out: PathBuf,
    threads: Option<usize>,
    seed: u64,
    cache: Option<PathBuf>,
    width: usize,
    height: usize,
    make_reference: bool,
    guide_probability: Option<f32>,
    /// The largest guide probability the field learns.
    max_guide_probability: f32,
    /// What a guided vertex costs, relative, for the field's cells to turn their guides off by
    /// (`None`: never).
    guide_cost: Option<f32>,
    refinement: Refinement,
    directional_filter: DirectionalFilter,
    spatial_threshold: f32,
    /// Next-event estimation (light sampling at every vertex).
    nee: bool,
    /// A trained cache to probe instead of rendering.
    probe: Option<PathBuf>,
    /// A trained cache whose guided sample's cost to measure instead of rendering.
    cost: Option<PathBuf>,
    /// Rounds of the cost measurement.
    rounds: u32,
    /// The Open PGL methods to run: with the cosine product or not.
    peers: Vec<bool>,
    /// Roulette and splitting variants, each run with every method (the peer: those without
    /// splitting).
    rrs: Vec<Rrs>,
}

fn number<T: std::str::FromStr>(flag: &str, value: &str) -> Result<T, String> {
    value
        .parse()
        .map_err(|_| format!("bad value for {flag}: {value}"))
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        scenes: vec!["door".into()],
        seeds: 1,
        budget: Budget::default(),
        rules: vec![LeafRule::L1, LeafRule::L2],
        out: PathBuf::from("out/render"),
        threads: None,
        seed: 1,
        cache: None,
        width: 320,
        height: 240,
        make_reference: false,
        guide_probability: None,
        max_guide_probability: GuidingConfig::default().max_guide_probability,
        guide_cost: GuidingConfig::default().guide_cost,
        refinement: Refinement::default(),
        directional_filter: DirectionalFilter::default(),
        spatial_threshold: GuidingConfig::default().spatial_threshold,
        nee: true,
        probe: None,
        cost: None,
        rounds: 30,
        peers: if cfg!(feature = "openpgl") {
            vec![false, true]
        } else {
            Vec::new()
        },
        rrs: vec![Rrs::Classic],
    };
    let mut argv = std::env::args().skip(1);
    while let Some(flag) = argv.next() {
        if flag == "--reference" {
            a.make_reference = true;
            continue;
        }
        let value = argv.next().ok_or(format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--scene" => {
                a.scenes = if value == "all" {
                    ALL_SCENES.iter().map(|s| s.to_string()).collect()
                } else {
                    vec![value.clone()]
                }
            }
            "--seeds" => {
                a.seeds = number(&flag, &value)?;
                if !(1..=1000).contains(&a.seeds) {
                    return Err(format!("bad value for --seeds: {value}"));
                }
            }
            "--time" => {
                let secs: f32 = number(&flag, &value)?;
                if !(secs.is_finite() && (0.0..=1e6).contains(&secs)) {
                    return Err(format!("bad value for --time: {value}"));
                }
                a.budget.time = (secs > 0.0).then(|| Duration::from_secs_f32(secs));
            }
            "--spp" => a.budget.spp = Some(number(&flag, &value)?),
            "--rule" => {
                a.rules = Vec::new();
                for rule in value.split(',') {
                    a.rules.extend_from_slice(match rule {
                        "l1" => &[LeafRule::L1][..],
                        "l2" => &[LeafRule::L2],
                        "l2m" => &[LeafRule::L2Mixture],
                        "both" => &[LeafRule::L1, LeafRule::L2],
                        "all" => &[LeafRule::L1, LeafRule::L2, LeafRule::L2Mixture],
                        _ => return Err(format!("bad value for --rule: {value}")),
                    });
                }
            }
            "--out" => a.out = PathBuf::from(&value),
            "--threads" => a.threads = Some(number(&flag, &value)?),
            "--seed" => a.seed = number(&flag, &value)?,
            "--probe" => a.probe = Some(PathBuf::from(value)),
            "--cost" => a.cost = Some(PathBuf::from(value)),
            "--rounds" => {
                a.rounds = number(&flag, &value)?;
                if !(1..=10_000).contains(&a.rounds) {
                    return Err(format!("bad value for --rounds: {value}"));
                }
            }
            "--nee" => {
                a.nee = match value.as_str() {
                    "on" => true,
                    "off" => false,
                    _ => return Err(format!("bad value for --nee: {value}")),
                }
            }
            "--cache" => a.cache = Some(PathBuf::from(&value)),
            "--width" => a.width = number(&flag, &value)?,
            "--height" => a.height = number(&flag, &value)?,
            "--refinement" => {
                a.refinement = match value.as_str() {
                    "gain" => Refinement::VarianceGain,
                    "flux" => Refinement::FluxShare,
                    _ => return Err(format!("bad value for --refinement: {value}")),
                }
            }
            "--spatial-threshold" => a.spatial_threshold = number(&flag, &value)?,
            "--filter" => {
                a.directional_filter = match value.as_str() {
                    "box" => DirectionalFilter::Box,
                    "deferred" => DirectionalFilter::DeferredBox,
                    "nearest" => DirectionalFilter::Nearest,
                    _ => return Err(format!("bad value for --filter: {value}")),
                }
            }
            "--rrs" => {
                a.rrs = value
                    .split(',')
                    .map(|v| match v {
                        "classic" => Ok(Rrs::Classic),
                        "ear" => Ok(Rrs::Ear),
                        "ears" => Ok(Rrs::Ears),
                        "none" => Ok(Rrs::None),
                        _ => Err(format!("bad value for --rrs: {value}")),
                    })
                    .collect::<Result<_, _>>()?;
            }
            "--peer" => {
                a.peers = match value.as_str() {
                    "none" => Vec::new(),
                    "plain" => vec![false],
                    "cos" => vec![true],
                    "both" => vec![false, true],
                    _ => return Err(format!("bad value for --peer: {value}")),
                };
                if !a.peers.is_empty() && !cfg!(feature = "openpgl") {
                    return Err("--peer needs the demo built with `--features openpgl`".into());
                }
            }
            "--guide-probability" => {
                let p: f32 = number(&flag, &value)?;
                if !(0.0..=1.0).contains(&p) {
                    return Err(format!("bad value for --guide-probability: {value}"));
                }
                a.guide_probability = Some(p);
            }
            "--max-guide-probability" => a.max_guide_probability = number(&flag, &value)?,
            "--guide-cost" => {
                a.guide_cost = match value.as_str() {
                    "none" => None,
                    _ => Some(number(&flag, &value)?),
                }
            }
            "--training-share" => {
                let share: f32 = number(&flag, &value)?;
                if !(0.0..1.0).contains(&share) {
                    return Err(format!("bad value for --training-share: {value}"));
                }
                a.budget.training_share = share;
            }
            _ => return Err(format!("unknown option {flag}")),
        }
    }
    if a.budget.time.is_none() && a.budget.spp.is_none() {
        return Err("without a time budget (--time 0), --spp is needed".into());
    }
    if a.width == 0 || a.height == 0 || a.width > 8192 || a.height > 8192 {
        return Err("the resolution must be within 1..=8192".into());
    }
    Ok(a)
}

fn progress_bar(label: &str) -> ProgressBar {
    let bar = ProgressBar::new(1000);
    bar.set_style(
        ProgressStyle::with_template("{prefix:>10} [{bar:40}] {elapsed:>4} {msg}")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    bar
}

fn run_method(
    scene: &Scene,
    (method, rrs): (Method, Rrs),
    args: &Args,
    seed: u64,
    cache: Option<GuidingField>,
) -> Result<Outcome, String> {
    let bar = progress_bar(&format!("{}{}", method.name(), rrs.suffix()));
    let progress = |phase: &str, fraction: f32, spp: u32| {
        bar.set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
        bar.set_message(format!("{phase}, {spp} spp"));
    };
    let outcome = render(
        scene,
        method,
        (args.width, args.height),
        args.budget,
        seed,
        Training {
            config: &GuidingConfig {
                refinement: args.refinement,
                directional_filter: args.directional_filter,
                spatial_threshold: args.spatial_threshold,
                max_guide_probability: args.max_guide_probability,
                guide_cost: args.guide_cost,
                ..GuidingConfig::default()
            },
            cache,
            guide_probability: args.guide_probability,
            rrs,
        },
        &progress,
    )?;
    bar.finish_and_clear();
    Ok(outcome)
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("render: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    let args = parse().map_err(|e| format!("{e}\n{USAGE}"))?;
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| e.to_string())?;
    }
    let mut scenes = Vec::new();
    for name in &args.scenes {
        let mut scene = Scene::by_name(name).ok_or(format!(
            "unknown scene {name}; the scenes are {:?} (or all)",
            Scene::NAMES
        ))?;
        scene.next_event = args.nee;
        scenes.push(scene);
    }
    let command_line: Vec<String> = std::env::args().skip(1).collect();
    let mut command = "cargo run --release -p sdguide-render".to_string();
    if !command_line.is_empty() {
        command = format!("{command} -- {}", command_line.join(" "));
    }

    if let Some(path) = &args.probe {
        let [scene] = &scenes[..] else {
            return Err("--probe needs a single scene".into());
        };
        let field = GuidingField::load_from_path(path)
            .map_err(|e| format!("cannot load the cache {}: {e}", path.display()))?;
        print!("{}", probe_report(scene, &field, &args));
        return Ok(());
    }

    if let Some(path) = &args.cost {
        let [scene] = &scenes[..] else {
            return Err("--cost needs a single scene".into());
        };
        let field = GuidingField::load_from_path(path)
            .map_err(|e| format!("cannot load the cache {}: {e}", path.display()))?;
        print!("{}", cost_report(scene, &field, path, &args));
        return Ok(());
    }

    if args.make_reference {
        for scene in &scenes {
            make_reference(scene, &args, &command)?;
        }
        return Ok(());
    }
    if args.cache.is_some() && scenes.len() > 1 {
        return Err("--cache needs a single scene".into());
    }
    std::fs::create_dir_all(&args.out).map_err(|e| e.to_string())?;

    // Every method with every roulette (unguided classic first: the baseline of the ratios).
    let mut methods: Vec<(Method, Rrs)> = Vec::new();
    for &rrs in &args.rrs {
        methods.push((Method::Unguided, rrs));
    }
    for &rule in &args.rules {
        methods.extend(args.rrs.iter().map(|&rrs| (Method::Guided(rule), rrs)));
    }
    if !methods.contains(&(Method::Unguided, Rrs::Classic)) {
        methods.insert(0, (Method::Unguided, Rrs::Classic));
    }
    methods.sort_by_key(|&(m, r)| (m != Method::Unguided || r != Rrs::Classic) as u8);
    // The peer has no splitting: it runs with each roulette asked for that has none (classic
    // if none such is).
    #[cfg(feature = "openpgl")]
    {
        let mut roulettes: Vec<Rrs> = args
            .rrs
            .iter()
            .copied()
            .filter(|r| r.mode().is_none())
            .collect();
        if roulettes.is_empty() {
            roulettes.push(Rrs::Classic);
        }
        for &cosine_product in &args.peers {
            methods.extend(
                roulettes
                    .iter()
                    .map(|&rrs| (Method::OpenPgl { cosine_product }, rrs)),
            );
        }
    }
    let mut report = header(&args, &command);
    let mut summaries = Vec::new();
    for scene in &scenes {
        let mut runs = Vec::new();
        for seed in args.seed..args.seed + args.seeds {
            runs.push(render_scene(scene, &methods, &args, seed)?);
        }
        report += &scene_report(scene, &args, &runs);
        summaries.push((scene.name.clone(), runs));
    }
    if summaries.len() > 1 || args.seeds > 1 {
        report += &summary(&summaries);
    }
    report += &footnotes();
    print!("{report}");
    std::fs::write(args.out.join("report.md"), &report).map_err(|e| e.to_string())
}

fn make_reference(scene: &Scene, args: &Args, command: &str) -> Result<(), String> {
    // Streams of its own, independent of every run compared with it.
    let seed = reference::seed(args.seed);
    let outcome = run_method(
        scene,
        (Method::Guided(LeafRule::L2), Rrs::Classic),
        args,
        seed,
        None,
    )?;
    let path = reference::store(
        &reference::directory(),
        scene,
        &outcome.image,
        outcome.spp,
        seed,
        command,
    )
    .map_err(|e| e.to_string())?;
    println!(
        "reference of `{}`: {} spp (+{} training) in {:.0} s, written to {}",
        scene.name,
        outcome.spp,
        outcome.training_spp,
        outcome.total_time.as_secs_f32(),
        path.display()
    );
    Ok(())
}

/// One seed's renders of a scene, one per method, and each one's error.
struct Run {
    seed: u64,
    reference: Option<reference::Description>,
    outcomes: Vec<Rendered>,
}

/// One method's render, and its error against the reference.
struct Rendered {
    outcome: Outcome,
    /// Whether its field came from `--cache`.
    reused: bool,
    /// The final image's relMSE, and its mean's deviation in standard errors.
    error: Option<(f64, f64)>,
    /// relMSE of the image combined with the training passes (equal to the final image's for
    /// unguided).
    combined_error: Option<f64>,
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
        let rrs = self.outcomes[i].outcome.rrs;
        let base = self
            .outcomes
            .iter()
            .position(|r| r.outcome.method == Method::Unguided && r.outcome.rrs == rrs)?;
        Some(self.ratios_to(i, base)?.1)
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

/// Renders `scene` with every method from `seed`, writing each image (and trained cache) and
/// the comparison sheet to the output directory.
fn render_scene(
    scene: &Scene,
    methods: &[(Method, Rrs)],
    args: &Args,
    seed: u64,
) -> Result<Run, String> {
    let reference = match reference::load(
        &reference::directory(),
        scene,
        args.width,
        args.height,
        seed,
    ) {
        Ok(found) => Some(found),
        Err(e) => {
            eprintln!("render: {e}; errors will not be reported");
            None
        }
    };
    // A cache given on the command line replaces training for the guided method of its rule.
    let mut cache = match &args.cache {
        Some(path) => Some(
            GuidingField::load_from_path(path)
                .map_err(|e| format!("cannot load the cache {}: {e}", path.display()))?,
        ),
        None => None,
    };
    let suffix = if args.seeds > 1 {
        format!("-seed{seed}")
    } else {
        String::new()
    };
    let mut outcomes = Vec::new();
    for &(method, rrs) in methods {
        let reuse = match (method, &cache) {
            (Method::Guided(rule), Some(c)) if c.config().rule == rule => cache.take(),
            _ => None,
        };
        let reused = reuse.is_some();
        let outcome = run_method(scene, (method, rrs), args, seed, reuse)?;
        let stem = args
            .out
            .join(format!("{}-{}{suffix}", scene.name, outcome.name()));
        outcome
            .image
            .write_png(&stem.with_extension("png"), scene.exposure)
            .and_then(|()| outcome.image.write_exr(&stem.with_extension("exr")))
            .map_err(|e| e.to_string())?;
        if let (Some(field), false) = (&outcome.field, reused) {
            let path = stem.with_extension("sdgc");
            field
                .save_to_path(&path)
                .map_err(|e| format!("cannot save the cache {}: {e}", path.display()))?;
        }
        let error = reference.as_ref().map(|(img, _)| {
            (
                outcome.image.rel_mse(img),
                outcome.image.mean_deviation(img),
            )
        });
        let combined_error = reference
            .as_ref()
            .map(|(img, _)| outcome.combined.rel_mse(img));
        outcomes.push(Rendered {
            outcome,
            reused,
            error,
            combined_error,
        });
    }
    if let Some((reference, _)) = &reference {
        let images: Vec<&Image> = outcomes.iter().map(|o| &o.outcome.image).collect();
        let (w, h, sheet) = side_by_side(reference, &images, scene.exposure);
        let path = args.out.join(format!("{}-compare{suffix}.png", scene.name));
        write_png(&path, w, h, &sheet).map_err(|e| e.to_string())?;
    }
    Ok(Run {
        seed,
        reference: reference.map(|(_, d)| d),
        outcomes,
    })
}

/// The probe table: at the first surface behind each of nine pixels, where the trained guide's
/// draws go, plain and times the clamped cosine.
fn probe_report(scene: &Scene, field: &GuidingField, args: &Args) -> String {
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

fn cost_report(scene: &Scene, field: &GuidingField, path: &std::path::Path, args: &Args) -> String {
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
    ", its default field (a kd-tree of parallax-aware VMMs, at most 32000 samples per leaf, \
     deterministic), the surface sampling distribution at every vertex (`openpgl-cos`: with its \
     cosine product), guide probability ½ unless fixed, the same mixture, MIS, recorded \
     radiance and training schedule as sdguide's methods."
);
#[cfg(not(feature = "openpgl"))]
const PEER_SETTINGS: &str = "";

/// The report's title and settings.
fn header(args: &Args, command: &str) -> String {
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
fn scene_report(scene: &Scene, args: &Args, runs: &[Run]) -> String {
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

/// Mean and range over the seeds of each scene's ratios to unguided, per method.
fn summary(scenes: &[(String, Vec<Run>)]) -> String {
    let seeds = scenes.first().map_or(0, |(_, runs)| runs.len());
    let mut r = format!(
        "## Summary over {seeds} seed{}: mean (min–max) of the ratios to unguided\n\n\
         | scene | method | relMSE vs unguided | per sample vs unguided | per sample vs \
         unguided, same roulette | time per spp vs unguided |\n|---|---|---:|---:|---:|---:|\n",
        if seeds == 1 { "" } else { "s" }
    );
    let spread = |v: &[f64]| {
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
    };
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

fn footnotes() -> String {
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
