//! The command line: every option with its default and range, parsed by clap into [`Args`].

use clap::{Parser, ValueEnum};
use sdguide::{DirectionalFilter, GuidingConfig, LeafRule, Refinement, SpatialSplit};
use sdguide_render::method::{Budget, GUIDE_COST, Method, RECOMMENDED, Rrs};
use sdguide_render::scenes;
use std::path::PathBuf;
use std::time::Duration;

/// Renders a scene unguided and guided (sdguide's l1 and l2 rules, and Intel Open PGL when
/// built with the `openpgl` feature) in the same wall-clock budget each, and reports each
/// render's error against a stored reference.
#[derive(Parser, Debug)]
#[command(name = "render", version)]
struct Cli {
    /// The scene to render: a built-in one, or `all` for every scene with a reference.
    #[arg(long, default_value = "door", value_parser = scene_names())]
    scene: String,
    /// Runs per scene, from seeds `seed, seed + 1, …`.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=1000))]
    seeds: u64,
    /// Seconds per method, training included (0: no time limit; then `--spp` is needed).
    #[arg(long, default_value_t = 40.0, value_parser = seconds)]
    time: f32,
    /// Cap on the final render's samples per pixel.
    #[arg(long)]
    spp: Option<u32>,
    /// Leaf rules of the guided methods (`both`: l1 and l2; `all`: l1, l2 and l2m). Without
    /// `--rule` and `--rrs`: the recommended comparison (unguided with classic roulette, and
    /// unguided and guided by the l2m rule with efficiency-aware roulette and splitting); with
    /// only one of them, the other is `both` or `classic`.
    #[arg(long, value_enum, value_delimiter = ',')]
    rule: Option<Vec<RuleArg>>,
    /// Where images, caches and the report go.
    #[arg(long, default_value = "out/render")]
    out: PathBuf,
    /// Render threads (default: every core).
    #[arg(long)]
    threads: Option<usize>,
    /// The first seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// A trained cache that replaces training for the guided method of its rule.
    #[arg(long)]
    cache: Option<PathBuf>,
    /// Image width, pixels.
    #[arg(long, default_value_t = 320, value_parser = clap::value_parser!(u32).range(1..=8192))]
    width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 240, value_parser = clap::value_parser!(u32).range(1..=8192))]
    height: u32,
    /// Share of the time budget training may use.
    #[arg(long, default_value_t = Budget::default().training_share, value_parser = share)]
    training_share: f32,
    /// A fixed probability of sampling the guide instead of the BSDF (default: learned).
    #[arg(long, value_parser = probability)]
    guide_probability: Option<f32>,
    /// The largest guide probability the field learns.
    #[arg(long, default_value_t = GuidingConfig::default().max_guide_probability)]
    max_guide_probability: f32,
    /// What a guided vertex costs, relative, for cells to turn their guides off by (`none`:
    /// never; the default is this renderer's measured cost).
    #[arg(long, default_value_t = OrNone(Some(GUIDE_COST)))]
    guide_cost: OrNone,
    /// How directional cells split.
    #[arg(long, value_enum, default_value = "gain")]
    refinement: RefinementArg,
    /// `τ` of `--refinement gain`: a directional cell splits where that lowers its tree's
    /// `Σ sqrt(m)` by more than `τ` of it.
    #[arg(long, default_value_t = GuidingConfig::default().gain_threshold)]
    gain_threshold: f32,
    /// The directional filter.
    #[arg(long, value_enum, default_value = "box")]
    filter: FilterArg,
    /// `n_f`: samples a directional leaf needs before its own second moment weighs as much as
    /// the filtered one in the l2 masses (`none`: the filtered sums alone).
    #[arg(long, default_value_t = OrNone(GuidingConfig::default().filter_samples))]
    filter_samples: OrNone,
    /// `n0`: samples' worth of weight a directional cell's masses give its parent's.
    #[arg(long, default_value_t = GuidingConfig::default().prior_samples)]
    prior_samples: f32,
    /// `c`: spatial leaves split past `c·sqrt(2^k)` samples in iteration `k`.
    #[arg(long, default_value_t = GuidingConfig::default().spatial_threshold)]
    spatial_threshold: f32,
    /// How spatial leaves split: by their sample count, or where their halves see different
    /// light.
    #[arg(long, value_enum, default_value = "count")]
    spatial_split: SpatialSplitArg,
    /// `τ` of `--spatial-split gain`.
    #[arg(long, default_value_t = GuidingConfig::default().spatial_gain_threshold)]
    spatial_gain_threshold: f32,
    /// The Open PGL methods to run (default: `cos` with the `openpgl` feature, else none).
    #[arg(long, value_enum)]
    peer: Option<PeerArg>,
    /// Next-event estimation (light sampling at every vertex).
    #[arg(long, value_enum, default_value = "on")]
    nee: OnOff,
    /// Roulette and splitting variants, each run with every method (the peer: those without
    /// splitting; `grr`, Open PGL's guided roulette, the peer only).
    #[arg(long, value_enum, value_delimiter = ',')]
    rrs: Option<Vec<RrsArg>>,
    /// Render the scene's reference instead (with `--spp` and `--time 0`).
    #[arg(long)]
    reference: bool,
    /// A trained cache to probe instead of rendering.
    #[arg(long)]
    probe: Option<PathBuf>,
    /// A trained cache whose guided sample's cost to measure instead of rendering.
    #[arg(long)]
    cost: Option<PathBuf>,
    /// Rounds of the cost measurement.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    rounds: u32,
}

/// The parsed command line, in the demo's types.
pub struct Args {
    /// The scenes to render, in order.
    pub scenes: Vec<String>,
    /// Runs per scene, from seeds `seed, seed + 1, …`.
    pub seeds: u64,
    pub budget: Budget,
    pub rules: Vec<LeafRule>,
    pub out: PathBuf,
    pub threads: Option<usize>,
    pub seed: u64,
    pub cache: Option<PathBuf>,
    pub width: usize,
    pub height: usize,
    pub make_reference: bool,
    pub guide_probability: Option<f32>,
    /// The largest guide probability the field learns.
    pub max_guide_probability: f32,
    /// What a guided vertex costs, relative, for the field's cells to turn their guides off by
    /// (`None`: never).
    pub guide_cost: Option<f32>,
    pub refinement: Refinement,
    pub gain_threshold: f32,
    pub directional_filter: DirectionalFilter,
    pub filter_samples: Option<f32>,
    pub prior_samples: f32,
    pub spatial_threshold: f32,
    pub spatial_split: SpatialSplit,
    pub spatial_gain_threshold: f32,
    /// Next-event estimation (light sampling at every vertex).
    pub nee: bool,
    /// A trained cache to probe instead of rendering.
    pub probe: Option<PathBuf>,
    /// A trained cache whose guided sample's cost to measure instead of rendering.
    pub cost: Option<PathBuf>,
    /// Rounds of the cost measurement.
    pub rounds: u32,
    /// The Open PGL methods to run: with the cosine product or not.
    pub peers: Vec<bool>,
    /// Roulette and splitting variants, each run with every method (the peer: those without
    /// splitting).
    pub rrs: Vec<Rrs>,
    /// Neither `--rule` nor `--rrs` was given: render the recommended comparison (see
    /// [`Args::methods`]).
    pub recommended: bool,
}

impl Args {
    /// The methods to render, unguided with classic roulette first (the baseline of every
    /// ratio): the recommended comparison — unguided with classic roulette, unguided with
    /// efficiency-aware roulette and splitting, and [`RECOMMENDED`] (guided by the l2m rule
    /// with them) — or every rule with every roulette asked for, beside unguided with each;
    /// then the peer's methods, each with the roulettes asked for that do not split (classic if
    /// none such is; in the recommended comparison, classic and its own guided roulette).
    pub fn methods(&self) -> Vec<(Method, Rrs)> {
        let mut methods: Vec<(Method, Rrs)> = if self.recommended {
            vec![
                (Method::Unguided, Rrs::Classic),
                (Method::Unguided, Rrs::Ears),
                RECOMMENDED,
            ]
        } else {
            // Guided roulette is the peer's alone.
            let own: Vec<Rrs> = self
                .rrs
                .iter()
                .copied()
                .filter(|&r| r != Rrs::Guided)
                .collect();
            let unguided = own.iter().map(|&rrs| (Method::Unguided, rrs));
            let guided = self
                .rules
                .iter()
                .flat_map(|&rule| own.iter().map(move |&rrs| (Method::Guided(rule), rrs)));
            unguided.chain(guided).collect()
        };
        if !methods.contains(&(Method::Unguided, Rrs::Classic)) {
            methods.insert(0, (Method::Unguided, Rrs::Classic));
        }
        methods.sort_by_key(|&(m, r)| (m != Method::Unguided || r != Rrs::Classic) as u8);
        // The peer at its best beside its classic roulette in the recommended comparison.
        let mut roulettes: Vec<Rrs> = if self.recommended {
            vec![Rrs::Classic, Rrs::Guided]
        } else {
            self.rrs
                .iter()
                .copied()
                .filter(|r| r.mode().is_none())
                .collect()
        };
        if roulettes.is_empty() {
            roulettes.push(Rrs::Classic);
        }
        for &cosine_product in &self.peers {
            methods.extend(
                roulettes
                    .iter()
                    .map(|&rrs| (Method::OpenPgl { cosine_product }, rrs)),
            );
        }
        methods
    }

    /// The configuration of the fields the guided methods train (each with its rule).
    pub fn config(&self) -> GuidingConfig {
        GuidingConfig {
            refinement: self.refinement,
            gain_threshold: self.gain_threshold,
            directional_filter: self.directional_filter,
            filter_samples: self.filter_samples,
            prior_samples: self.prior_samples,
            spatial_threshold: self.spatial_threshold,
            spatial_split: self.spatial_split,
            spatial_gain_threshold: self.spatial_gain_threshold,
            max_guide_probability: self.max_guide_probability,
            guide_cost: self.guide_cost,
            ..GuidingConfig::default()
        }
    }
}

/// Parses the command line; `--help` and `--version` print and exit.
///
/// # Errors
///
/// What is wrong with the options, with the usage.
pub fn parse() -> Result<Args, String> {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(),
        Err(e) => return Err(e.to_string().trim_end().to_string()),
    };
    let peers = match cli.peer {
        None if cfg!(feature = "openpgl") => vec![true],
        None | Some(PeerArg::None) => Vec::new(),
        Some(PeerArg::Plain) => vec![false],
        Some(PeerArg::Cos) => vec![true],
        Some(PeerArg::Both) => vec![false, true],
    };
    if !peers.is_empty() && !cfg!(feature = "openpgl") {
        return Err("--peer needs the demo built with `--features openpgl`".into());
    }
    let budget = Budget {
        time: (cli.time > 0.0).then(|| Duration::from_secs_f32(cli.time)),
        spp: cli.spp,
        training_share: cli.training_share,
        ..Budget::default()
    };
    if budget.time.is_none() && budget.spp.is_none() {
        return Err("without a time budget (--time 0), --spp is needed".into());
    }
    Ok(Args {
        scenes: if cli.scene == "all" {
            scenes::compared().map(str::to_string).collect()
        } else {
            vec![cli.scene]
        },
        seeds: cli.seeds,
        budget,
        rules: cli
            .rule
            .as_deref()
            .unwrap_or(&[RuleArg::Both])
            .iter()
            .flat_map(|r| r.rules())
            .copied()
            .collect(),
        out: cli.out,
        threads: cli.threads,
        seed: cli.seed,
        cache: cli.cache,
        width: cli.width as usize,
        height: cli.height as usize,
        make_reference: cli.reference,
        guide_probability: cli.guide_probability,
        max_guide_probability: cli.max_guide_probability,
        guide_cost: cli.guide_cost.0,
        refinement: match cli.refinement {
            RefinementArg::Gain => Refinement::VarianceGain,
            RefinementArg::Flux => Refinement::FluxShare,
        },
        gain_threshold: cli.gain_threshold,
        directional_filter: match cli.filter {
            FilterArg::Box => DirectionalFilter::Box,
            FilterArg::Deferred => DirectionalFilter::DeferredBox,
            FilterArg::Nearest => DirectionalFilter::Nearest,
        },
        filter_samples: cli.filter_samples.0,
        prior_samples: cli.prior_samples,
        spatial_threshold: cli.spatial_threshold,
        spatial_split: match cli.spatial_split {
            SpatialSplitArg::Count => SpatialSplit::Count,
            SpatialSplitArg::Gain => SpatialSplit::Gain,
        },
        spatial_gain_threshold: cli.spatial_gain_threshold,
        nee: cli.nee == OnOff::On,
        probe: cli.probe,
        cost: cli.cost,
        rounds: cli.rounds,
        peers,
        recommended: cli.rule.is_none() && cli.rrs.is_none(),
        rrs: match &cli.rrs {
            Some(rrs) => rrs.as_slice(),
            None if cli.rule.is_none() => &[RrsArg::Classic, RrsArg::Ears],
            None => &[RrsArg::Classic],
        }
        .iter()
        .map(|r| match r {
            RrsArg::Classic => Rrs::Classic,
            RrsArg::Ear => Rrs::Ear,
            RrsArg::Ears => Rrs::Ears,
            RrsArg::None => Rrs::None,
            RrsArg::Grr => Rrs::Guided,
        })
        .collect(),
    })
}

/// The built-in scenes' names and `all`.
fn scene_names() -> clap::builder::PossibleValuesParser {
    let names: Vec<&'static str> = scenes::BUILT_IN.iter().map(|s| s.name).collect();
    clap::builder::PossibleValuesParser::new(names.into_iter().chain(["all"]))
}

fn number(value: &str) -> Result<f32, String> {
    value.parse().map_err(|_| format!("not a number: {value}"))
}

fn seconds(value: &str) -> Result<f32, String> {
    let s = number(value)?;
    if s.is_finite() && (0.0..=1e6).contains(&s) {
        Ok(s)
    } else {
        Err("seconds in [0, 1e6]".into())
    }
}

fn share(value: &str) -> Result<f32, String> {
    let s = number(value)?;
    if (0.0..1.0).contains(&s) {
        Ok(s)
    } else {
        Err("a share in [0, 1)".into())
    }
}

fn probability(value: &str) -> Result<f32, String> {
    let p = number(value)?;
    if (0.0..=1.0).contains(&p) {
        Ok(p)
    } else {
        Err("a probability in [0, 1]".into())
    }
}

/// `--guide-cost`, `--filter-samples`: a number, or `none`.
#[derive(Clone, Copy, Debug)]
struct OrNone(Option<f32>);

impl std::str::FromStr for OrNone {
    type Err = String;
    fn from_str(value: &str) -> Result<Self, String> {
        match value {
            "none" => Ok(OrNone(None)),
            _ => number(value).map(|c| OrNone(Some(c))),
        }
    }
}

impl std::fmt::Display for OrNone {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(c) => write!(f, "{c}"),
            None => write!(f, "none"),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum RuleArg {
    L1,
    L2,
    L2m,
    Both,
    All,
}

impl RuleArg {
    fn rules(self) -> &'static [LeafRule] {
        match self {
            RuleArg::L1 => &[LeafRule::L1],
            RuleArg::L2 => &[LeafRule::L2],
            RuleArg::L2m => &[LeafRule::L2Mixture],
            RuleArg::Both => &[LeafRule::L1, LeafRule::L2],
            RuleArg::All => &[LeafRule::L1, LeafRule::L2, LeafRule::L2Mixture],
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum RefinementArg {
    Gain,
    Flux,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum SpatialSplitArg {
    Count,
    Gain,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum FilterArg {
    Box,
    Deferred,
    Nearest,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum PeerArg {
    None,
    Plain,
    Cos,
    Both,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum OnOff {
    On,
    Off,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum RrsArg {
    Classic,
    Ear,
    Ears,
    None,
    Grr,
}
