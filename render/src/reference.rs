//! Stored reference images: a linear EXR per scene under `render/reference/`, with a small text
//! file saying what it shows (scene fingerprint, resolution, samples, seed, the command that made
//! it). A reference is refused if it does not match the scene it is compared with, or if it was
//! drawn from the same random streams as the run compared with it.
//!
//! A reference renders from a seed of its own, [`seed`], derived from the seed it was asked
//! for. A run's random streams are a function of its seed (one per pixel and pass), so a
//! reference rendered with seed 1 would otherwise share every stream of a seed-1 run: a guided
//! run whose field came out as the reference's would draw the very samples the reference
//! averaged, and its error against it would come out far too small.

use crate::image::{Image, ImageError};
use crate::rng::Rng;
use crate::scene::Scene;
use std::fmt;
use std::path::{Path, PathBuf};

/// Why a reference cannot be used.
#[derive(Debug)]
pub enum ReferenceError {
    /// No reference is stored for the scene.
    Missing(PathBuf),
    /// The image or its description could not be read.
    Unreadable(PathBuf, String),
    /// It was rendered from another scene description or at another resolution.
    Mismatch(String),
}

impl fmt::Display for ReferenceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReferenceError::Missing(p) => write!(f, "no reference at {}", p.display()),
            ReferenceError::Unreadable(p, e) => write!(f, "cannot read {}: {e}", p.display()),
            ReferenceError::Mismatch(e) => write!(f, "the stored reference {e}"),
        }
    }
}

impl std::error::Error for ReferenceError {}

/// The seed a reference asked for with `seed` renders from: a pseudo-random function of it,
/// so that the reference's random streams are independent of those of the runs compared with
/// it (see the module's documentation).
///
/// ```
/// use sdguide_render::reference;
/// assert_ne!(reference::seed(1), 1);
/// ```
pub fn seed(seed: u64) -> u64 {
    // The bytes of "referenc", to separate these seeds from the runs' own.
    Rng::new(seed ^ 0x7265_6665_7265_6e63).next_u64()
}

/// The directory references are stored in.
pub fn directory() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("reference")
}

fn paths(dir: &Path, scene: &Scene) -> (PathBuf, PathBuf) {
    (
        dir.join(format!("{}.exr", scene.name)),
        dir.join(format!("{}.txt", scene.name)),
    )
}

/// The description stored next to a reference image.
#[derive(Clone, Debug, PartialEq)]
pub struct Description {
    /// Scene name.
    pub scene: String,
    /// [`Scene::fingerprint`] of the scene rendered.
    pub fingerprint: u64,
    /// Resolution.
    pub width: usize,
    /// Resolution.
    pub height: usize,
    /// Samples per pixel.
    pub spp: u32,
    /// The seed it was rendered from ([`seed`] of the one asked for); `None` in a description
    /// written before references had seeds of their own, which is refused.
    pub seed: Option<u64>,
    /// The command that rendered it.
    pub command: String,
}

impl Description {
    fn to_text(&self) -> String {
        let seed = self.seed.map_or(String::new(), |s| format!("seed {s}\n"));
        format!(
            "scene {}\nfingerprint {:016x}\nwidth {}\nheight {}\nspp {}\n{seed}command {}\n",
            self.scene, self.fingerprint, self.width, self.height, self.spp, self.command
        )
    }

    fn parse(text: &str) -> Option<Description> {
        let field = |key: &str| {
            text.lines()
                .find_map(|l| l.strip_prefix(key)?.strip_prefix(' '))
                .map(str::to_string)
        };
        Some(Description {
            scene: field("scene")?,
            fingerprint: u64::from_str_radix(&field("fingerprint")?, 16).ok()?,
            width: field("width")?.parse().ok()?,
            height: field("height")?.parse().ok()?,
            spp: field("spp")?.parse().ok()?,
            seed: match field("seed") {
                Some(s) => Some(s.parse().ok()?),
                None => None,
            },
            command: field("command").unwrap_or_default(),
        })
    }
}

/// Stores `image`, rendered from `seed` (see [`seed`]), as the reference of `scene` in `dir`.
///
/// # Errors
///
/// An [`ImageError`] when the image or its description cannot be written.
pub fn store(
    dir: &Path,
    scene: &Scene,
    image: &Image,
    spp: u32,
    seed: u64,
    command: &str,
) -> Result<PathBuf, ImageError> {
    std::fs::create_dir_all(dir)?;
    let (exr, txt) = paths(dir, scene);
    image.write_exr(&exr)?;
    let description = Description {
        scene: scene.name.clone(),
        fingerprint: scene.fingerprint(),
        width: image.width,
        height: image.height,
        spp,
        seed: Some(seed),
        command: command.to_string(),
    };
    std::fs::write(&txt, description.to_text())?;
    Ok(exr)
}

/// Loads the reference of `scene` from `dir` and checks it shows this scene at this resolution,
/// from other random streams than those of a run seeded with `run_seed`.
///
/// # Errors
///
/// What is missing or does not match, with the command that renders a new reference.
pub fn load(
    dir: &Path,
    scene: &Scene,
    width: usize,
    height: usize,
    run_seed: u64,
) -> Result<(Image, Description), ReferenceError> {
    let (exr, txt) = paths(dir, scene);
    if !exr.exists() {
        return Err(ReferenceError::Missing(exr));
    }
    let text = std::fs::read_to_string(&txt)
        .map_err(|e| ReferenceError::Unreadable(txt.clone(), e.to_string()))?;
    let description = Description::parse(&text)
        .ok_or_else(|| ReferenceError::Unreadable(txt.clone(), "malformed description".into()))?;
    if description.scene != scene.name || description.fingerprint != scene.fingerprint() {
        return Err(ReferenceError::Mismatch(format!(
            "was rendered from another description of `{}` (fingerprint {:016x}, the scene's is \
             {:016x}); render it again with: {}",
            scene.name,
            description.fingerprint,
            scene.fingerprint(),
            description.command
        )));
    }
    if (description.width, description.height) != (width, height) {
        return Err(ReferenceError::Mismatch(format!(
            "is {}×{}, the render {width}×{height}",
            description.width, description.height
        )));
    }
    match description.seed {
        None => {
            return Err(ReferenceError::Mismatch(format!(
                "of `{}` was rendered before references had seeds of their own, and shares the \
                 random streams of the runs with its seed; render it again with: {}",
                scene.name, description.command
            )));
        }
        Some(s) if s == run_seed => {
            return Err(ReferenceError::Mismatch(format!(
                "was rendered from seed {s}, the run's: its samples are the run's own, so the \
                 run's error against it means nothing; run with another --seed"
            )));
        }
        Some(_) => {}
    }
    let image = Image::read_exr(&exr)
        .map_err(|e| ReferenceError::Unreadable(exr.clone(), e.to_string()))?;
    if (image.width, image.height) != (width, height) {
        return Err(ReferenceError::Mismatch(format!(
            "image is {}×{}, its description says {width}×{height}",
            image.width, image.height
        )));
    }
    Ok((image, description))
}
