//! `render`: renders a scene with unguided path tracing and with guiding (l1 and l2 rules, and
//! Intel Open PGL when built with the `openpgl` feature) in the same wall-clock budget each, and
//! reports the error of each against a stored reference.
//!
//! ```text
//! cargo run --release -p sdguide-render -- [--scene door] [--time 40] [--spp N] [--rule both]
//!     [--out out/render] [--threads N] [--seed 1] [--cache FILE] [--width 320 --height 240]
//!     [--training-share 0.3] [--guide-probability F] [--refinement gain|flux]
//!     [--filter box|deferred|nearest] [--spatial-threshold N] [--peer none|plain|cos|both]
//!     [--nee on|off]
//! cargo run --release -p sdguide-render -- --scene door --probe out/render/door-guided-l2.sdgc
//! cargo run --release -p sdguide-render -- --scene door --reference --spp 8192 --time 0
//! ```

use indicatif::{ProgressBar, ProgressStyle};
use sdguide::{DirectionalFilter, GuidingConfig, GuidingField, LeafRule, Refinement};
use sdguide_render::image::{Image, side_by_side, write_png};
use sdguide_render::reference;
use sdguide_render::render::{Budget, Method, Outcome, Training, render};
use sdguide_render::scene::Scene;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

const USAGE: &str = "usage: render [--scene door|glossy-box|uplight|furnace] [--time SECONDS (0: none)] \
[--spp N] [--rule l1|l2|both] [--out DIR] [--threads N] [--seed N] [--cache FILE] \
[--width N] [--height N] [--training-share F] [--guide-probability F] [--refinement gain|flux] \
[--filter box|deferred|nearest] [--spatial-threshold N] [--peer none|plain|cos|both] \
[--nee on|off] [--reference] [--probe CACHE]";

struct Args {
    scene: String,
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
    refinement: Refinement,
    directional_filter: DirectionalFilter,
    spatial_threshold: f32,
    /// Next-event estimation (light sampling at every vertex).
    nee: bool,
    /// A trained cache to probe instead of rendering.
    probe: Option<PathBuf>,
    /// The Open PGL methods to run: with the cosine product or not.
    peers: Vec<bool>,
}

fn number<T: std::str::FromStr>(flag: &str, value: &str) -> Result<T, String> {
    value
        .parse()
        .map_err(|_| format!("bad value for {flag}: {value}"))
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        scene: "door".into(),
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
        refinement: Refinement::default(),
        directional_filter: DirectionalFilter::default(),
        spatial_threshold: GuidingConfig::default().spatial_threshold,
        nee: true,
        probe: None,
        peers: if cfg!(feature = "openpgl") {
            vec![false, true]
        } else {
            Vec::new()
        },
    };
    let mut argv = std::env::args().skip(1);
    while let Some(flag) = argv.next() {
        if flag == "--reference" {
            a.make_reference = true;
            continue;
        }
        let value = argv.next().ok_or(format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--scene" => a.scene = value.clone(),
            "--time" => {
                let secs: f32 = number(&flag, &value)?;
                if !(secs.is_finite() && (0.0..=1e6).contains(&secs)) {
                    return Err(format!("bad value for --time: {value}"));
                }
                a.budget.time = (secs > 0.0).then(|| Duration::from_secs_f32(secs));
            }
            "--spp" => a.budget.spp = Some(number(&flag, &value)?),
            "--rule" => {
                a.rules = match value.as_str() {
                    "l1" => vec![LeafRule::L1],
                    "l2" => vec![LeafRule::L2],
                    "both" => vec![LeafRule::L1, LeafRule::L2],
                    _ => return Err(format!("bad value for --rule: {value}")),
                }
            }
            "--out" => a.out = PathBuf::from(&value),
            "--threads" => a.threads = Some(number(&flag, &value)?),
            "--seed" => a.seed = number(&flag, &value)?,
            "--probe" => a.probe = Some(PathBuf::from(value)),
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
    method: Method,
    args: &Args,
    cache: Option<GuidingField>,
) -> Result<Outcome, String> {
    let bar = progress_bar(method.name());
    let progress = |phase: &str, fraction: f32, spp: u32| {
        bar.set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
        bar.set_message(format!("{phase}, {spp} spp"));
    };
    let outcome = render(
        scene,
        method,
        (args.width, args.height),
        args.budget,
        args.seed,
        Training {
            config: &GuidingConfig {
                refinement: args.refinement,
                directional_filter: args.directional_filter,
                spatial_threshold: args.spatial_threshold,
                ..GuidingConfig::default()
            },
            cache,
            guide_probability: args.guide_probability,
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
    let mut scene = Scene::by_name(&args.scene).ok_or(format!(
        "unknown scene {}; the scenes are {:?}",
        args.scene,
        Scene::NAMES
    ))?;
    scene.next_event = args.nee;
    let command_line: Vec<String> = std::env::args().skip(1).collect();
    let mut command = "cargo run --release -p sdguide-render".to_string();
    if !command_line.is_empty() {
        command = format!("{command} -- {}", command_line.join(" "));
    }

    if let Some(path) = &args.probe {
        let field = GuidingField::load_from_path(path)
            .map_err(|e| format!("cannot load the cache {}: {e}", path.display()))?;
        print!("{}", probe_report(&scene, &field, &args));
        return Ok(());
    }

    if args.make_reference {
        // Streams of its own, independent of every run compared with it.
        let args = Args {
            seed: reference::seed(args.seed),
            ..args
        };
        let outcome = run_method(&scene, Method::Guided(LeafRule::L2), &args, None)?;
        let path = reference::store(
            &reference::directory(),
            &scene,
            &outcome.image,
            outcome.spp,
            args.seed,
            &command,
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
        return Ok(());
    }

    let reference = match reference::load(
        &reference::directory(),
        &scene,
        args.width,
        args.height,
        args.seed,
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
    std::fs::create_dir_all(&args.out).map_err(|e| e.to_string())?;

    let mut methods = vec![Method::Unguided];
    methods.extend(args.rules.iter().map(|&r| Method::Guided(r)));
    #[cfg(feature = "openpgl")]
    methods.extend(
        args.peers
            .iter()
            .map(|&cosine_product| Method::OpenPgl { cosine_product }),
    );
    let mut outcomes = Vec::new();
    for &method in &methods {
        let reuse = match (method, &cache) {
            (Method::Guided(rule), Some(c)) if c.config().rule == rule => cache.take(),
            _ => None,
        };
        let reused = reuse.is_some();
        let outcome = run_method(&scene, method, &args, reuse)?;
        let stem = args.out.join(format!("{}-{}", scene.name, method.name()));
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
        outcomes.push((outcome, reused));
    }

    let report = report(&scene, &args, &command, &outcomes, reference.as_ref());
    print!("{report}");
    std::fs::write(args.out.join("report.md"), &report).map_err(|e| e.to_string())?;
    if let Some((reference, _)) = &reference {
        let images: Vec<&Image> = outcomes.iter().map(|(o, _)| &o.image).collect();
        let (w, h, sheet) = side_by_side(reference, &images, scene.exposure);
        write_png(
            &args.out.join(format!("{}-compare.png", scene.name)),
            w,
            h,
            &sheet,
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
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

fn report(
    scene: &Scene,
    args: &Args,
    command: &str,
    outcomes: &[(Outcome, bool)],
    reference: Option<&(Image, reference::Description)>,
) -> String {
    let mut r = String::new();
    let budget = match args.budget.time {
        Some(t) => format!("{:.0} s per method", t.as_secs_f32()),
        None => "no time limit".into(),
    };
    let _ = writeln!(r, "# sdguide render: `{}`\n", scene.name);
    let _ = writeln!(
        r,
        "{}×{}, {budget}{}, training share {}, guide probability {}, next-event estimation {}, \
         {} threads, seed {}. Command: `{command}`\n",
        args.width,
        args.height,
        args.budget
            .spp
            .map_or(String::new(), |n| format!(", at most {n} spp")),
        args.budget.training_share,
        args.guide_probability
            .map_or("learned".to_string(), |p| format!("fixed at {p}")),
        if args.nee { "on" } else { "off" },
        rayon::current_num_threads(),
        args.seed
    );
    match reference {
        Some((_, d)) => {
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
    if !args.peers.is_empty() {
        let _ = writeln!(r, "{}\n", PEER_SETTINGS);
    }
    let _ = writeln!(
        r,
        "| method | spp | training | total time | relMSE | relMSE vs unguided | per sample vs \
         unguided | time per spp vs unguided | mean vs reference |\n\
         |---|---:|---|---:|---:|---:|---:|---:|---:|"
    );
    let errors: Vec<Option<f64>> = outcomes
        .iter()
        .map(|(o, _)| reference.map(|(img, _)| o.image.rel_mse(img)))
        .collect();
    let base = &outcomes[0].0;
    for ((o, reused), error) in outcomes.iter().zip(&errors) {
        let training = match (o.method, reused) {
            (Method::Unguided, _) => "—".to_string(),
            (_, true) => "from cache".to_string(),
            _ => format!(
                "{:.1} s, {} spp",
                o.training_time.as_secs_f32(),
                o.training_spp
            ),
        };
        // relMSE falls as 1/spp, so relMSE × spp compares methods per sample.
        let (error, ratio, per_sample) = match (error, errors[0]) {
            (Some(e), Some(e0)) => (
                format!("{e:.5}"),
                format!("{:.3}×", e / e0),
                format!("{:.3}×", (e * o.spp as f64) / (e0 * base.spp.max(1) as f64)),
            ),
            _ => ("—".into(), "—".into(), "—".into()),
        };
        let cost = o.time_per_spp().as_secs_f64() / base.time_per_spp().as_secs_f64().max(1e-12);
        let deviation = reference.map_or("—".to_string(), |(img, _)| {
            format!("{:+.1}σ", o.image.mean_deviation(img))
        });
        let _ = writeln!(
            r,
            "| {} | {} | {training} | {:.1} s | {error} | {ratio} | {per_sample} | {cost:.2}× | \
             {deviation} |",
            o.method.name(),
            o.spp,
            o.total_time.as_secs_f32(),
        );
    }
    let _ = writeln!(
        r,
        "\nPer sample: relMSE × spp over unguided's. Time per spp: the final render's, training \
         excluded. Mean vs reference: the image mean's distance from the reference's in \
         standard errors of the pixel differences (|z| ≤ 3 for an unbiased render)."
    );
    let _ = writeln!(
        r,
        "\nImages: `{0}-<method>.png` (tone-mapped) and `.exr` (linear); `{0}-compare.png`: \
         reference and methods on top, per-pixel relative squared error below (log scale, \
         10⁻⁴ black to 10 yellow; the ramp is under the reference).",
        scene.name
    );
    r
}
