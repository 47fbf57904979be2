//! Stored reference images: a linear EXR per scene under `render/reference/`, with a small text
//! file saying what it shows (scene fingerprint, resolution, samples, the command that made it).
//! A reference is refused if it does not match the scene it is compared with.

use crate::image::{Image, ImageError};
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
    /// The command that rendered it.
    pub command: String,
}

impl Description {
    fn to_text(&self) -> String {
        format!(
            "scene {}\nfingerprint {:016x}\nwidth {}\nheight {}\nspp {}\ncommand {}\n",
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
            command: field("command").unwrap_or_default(),
        })
    }
}

/// Stores `image` as the reference of `scene` in `dir`.
pub fn store(
    dir: &Path,
    scene: &Scene,
    image: &Image,
    spp: u32,
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
        command: command.to_string(),
    };
    std::fs::write(&txt, description.to_text())?;
    Ok(exr)
}

/// Loads the reference of `scene` from `dir` and checks it shows this scene at this resolution.
pub fn load(
    dir: &Path,
    scene: &Scene,
    width: usize,
    height: usize,
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
