//! `render`: renders a scene with unguided path tracing and with guiding (l1 and l2 rules, and
//! Intel Open PGL when built with the `openpgl` feature) in the same wall-clock budget each, and
//! reports the error of each against a stored reference. `render --help` lists the options.
//!
//! ```text
//! cargo run --release -p sdguide-render -- [--scene door|…|all] [--seeds 1] [--time 40] [--rrs classic,ears]
//! cargo run --release -p sdguide-render -- --scene door --probe out/render/door-guided-l2.sdgc
//! cargo run --release -p sdguide-render -- --scene door --cost out/render/door-guided-l2.sdgc [--rounds 30]
//! cargo run --release -p sdguide-render -- --scene door --reference --spp 8192 --time 0
//! ```

mod cli;
mod report;

use cli::Args;
use indicatif::{ProgressBar, ProgressStyle};
use report::{Rendered, Run};
use sdguide::{GuidingField, LeafRule};
use sdguide_render::image::{Image, side_by_side, write_png};
use sdguide_render::method::{Method, Outcome, Rrs, Training, render};
use sdguide_render::reference;
use sdguide_render::scene::Scene;
use sdguide_render::scenes;
use std::process::ExitCode;

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
            config: &args.config(),
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
    let args = cli::parse()?;
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| e.to_string())?;
    }
    let mut scenes = Vec::new();
    for name in &args.scenes {
        let mut scene = scenes::by_name(name).ok_or(format!("unknown scene {name}"))?;
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
        print!("{}", report::probe_report(scene, &field, &args));
        return Ok(());
    }

    if let Some(path) = &args.cost {
        let [scene] = &scenes[..] else {
            return Err("--cost needs a single scene".into());
        };
        let field = GuidingField::load_from_path(path)
            .map_err(|e| format!("cannot load the cache {}: {e}", path.display()))?;
        print!("{}", report::cost_report(scene, &field, path, &args));
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

    let methods = args.methods();
    let mut body = String::new();
    let mut summaries = Vec::new();
    for scene in &scenes {
        let mut runs = Vec::new();
        for seed in args.seed..args.seed + args.seeds {
            runs.push(render_scene(scene, &methods, &args, seed)?);
        }
        body += &report::scene_report(scene, &args, &runs);
        summaries.push((scene.name.clone(), runs));
    }
    let mut report = report::header(&args, &command);
    report += &report::verdict(&summaries);
    report += &body;
    if summaries.len() > 1 || args.seeds > 1 {
        report += &report::summary(&summaries);
    }
    report += &report::footnotes();
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
