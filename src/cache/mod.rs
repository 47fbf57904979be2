//! The guiding cache: a whole field as a versioned, checksummed, validated binary file.
//!
//! The format is specified byte by byte in `docs/cache-format.md`, so that a tool in another
//! language can read it. In short: a 32-byte header (magic, major/minor version, file length), a
//! table of sections (kind, flags, offset, length), the sections — `META` (configuration, bounds,
//! counters), `SPATIAL` (the binary tree), `DIRECTIONAL` (every quadtree: sampling nodes,
//! recording topology, moments) — and a CRC-32 of everything before it. All numbers are
//! little-endian.
//!
//! Reading trusts nothing: every size is checked against the bytes that are there before
//! anything is allocated, every child index must point forward and inside its tree, every node
//! must have exactly one parent, depths and node counts stay within the configuration, and every
//! number must be finite and in range. A malformed file is a [`CacheError`], never a panic.

use crate::bounds::Aabb;
use crate::config::GuidingConfig;
use crate::exact::{Signed, Sum};
use crate::field::GuidingField;
use crate::filter::{DirectionalFilter, SpatialFilter};
use crate::guide_probability::{
    GuideSelection, MAX_GUIDE_PROBABILITY, MIN_GUIDE_PROBABILITY, SelectionSums,
};
use crate::moments::{AtomicPending, AtomicQuadrants, AtomicSums};
use crate::quadtree::{self, RecordingTree, SLOTS, SamplingNode, SamplingTree, Tallied, WORDS};
use crate::refinement::Refinement;
use crate::region::{Guide, GuideView, GuideViewMut, Region};
use crate::rule::LeafRule;
use crate::spatial::{self, MAX_SPATIAL_DEPTH, SpatialTree};
use crate::spatial_split::{self, SignatureSums, SpatialSplit};
use crate::splitting::{ContinuationEstimate, ContinuationStats, ContinuationSums};
use crate::stats::{EventCount, REASONS, RejectCounters, Rejections};
use glam::Vec3;
use std::fmt;
use std::io::{self, Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

mod bytes;
mod envelope;
mod leaf_sums;
mod meta;
mod trees;
mod validate;

use bytes::{In, Out};
use envelope::{read_envelope, write_envelope};
use leaf_sums::{
    decode_continuations, decode_guide_cost, decode_pending, decode_quadrants, decode_selection,
    decode_signatures, decode_surfaces, encode_continuations, encode_guide_cost, encode_pending,
    encode_quadrants, encode_selection, encode_signatures, encode_surfaces,
};
use meta::{decode_meta, encode_meta};
use trees::{decode_directional, decode_spatial, encode_directional, encode_spatial};
use validate::{check_permutation, check_tree, node_count};

/// The first eight bytes of every cache file.
pub const MAGIC: [u8; 8] = *b"SDGUIDE\0";
/// The format's major version. Major 3 stores every sum a field learns from as an exact
/// fixed-point integer (see the crate docs on determinism), where major 2 stored `f64`: a
/// reader loads majors 2 and 3 and refuses others. A 2.x file loads when each of its sums is
/// one exactly — always true of a file saved at an iteration's start, whose sums are zero — and
/// is refused with [`CacheError::Inexact`] otherwise. Major 2 had the byte layout of 1.2 with the
/// directional trees on the octahedral map; 1.x files are refused.
pub const FORMAT_MAJOR: u16 = 3;
/// The format's minor version: a reader loads any minor of its major, skipping what it does
/// not know (optional sections, trailing bytes of a section). 3.0 is 2.6 with exact sums, the
/// normal tally's buckets, the clamped-sample counters at the end of `META`, and the optional
/// `PENDING` section (the deferred box filter's sums not yet spread). 3.1 adds volume guides:
/// the `volumes` flag and the medium samples' rejection counters at the end of `META`, and the
/// `VOLUME_*` sections (required where the field has volumes; a 3.0 file has none). 3.2 adds
/// `filter_samples` to `META`; 3.3 the spatial split rule to `META` and the optional
/// `SIGNATURES` section.
pub const FORMAT_MINOR: u16 = 3;
/// The oldest major a reader loads (converting its sums).
const LEGACY_MAJOR: u16 = 2;

const HEADER_LEN: usize = 32;
const ENTRY_LEN: usize = 24;
const CHECKSUM_LEN: usize = 4;
const SECTION_META: u32 = 1;
const SECTION_SPATIAL: u32 = 2;
const SECTION_DIRECTIONAL: u32 = 3;
/// 1.1: each spatial leaf's guide-vs-BSDF selection (optional: a reader without it starts at ½).
const SECTION_SELECTION: u32 = 4;
const SELECTION_LEN: usize = 32;
/// 1.2: each directional leaf's quadrant sums, for refinement by variance gain (optional: a
/// reader without it starts the iteration's quadrant sums at zero).
const SECTION_QUADRANTS: u32 = 5;
const QUADRANTS_LEN: usize = 64;
/// 2.3: each spatial leaf's continuation estimate and recorded sums, for roulette and splitting
/// (optional: a reader without it starts with no estimate).
const SECTION_CONTINUATIONS: u32 = 6;
const CONTINUATIONS_LEN: usize = 64;
/// 2.5: each spatial leaf's tally of recorded normals, and which have stored products
/// (optional: a reader without it starts with no tally, and queries take the per-query product).
const SECTION_SURFACES: u32 = 7;
const SURFACES_LEN: usize = 8 + 20 * SLOTS;
/// 2.6: whether each spatial leaf's guide is off, and the variance sums that decide it
/// (optional: a reader without it starts every guide on, with no sums).
const SECTION_GUIDE_COST: u32 = 8;
const GUIDE_COST_LEN: usize = 40;
/// 3.0: each directional leaf's sums the deferred box filter has yet to spread (optional: a
/// reader without it spreads nothing it did not see).
const SECTION_PENDING: u32 = 9;
/// 3.1: the guides of medium vertices, one per spatial leaf, laid out as `DIRECTIONAL` (a
/// required section where the field has volumes: a reader that skipped it would answer medium
/// queries with a uniform guide).
const SECTION_VOLUME_DIRECTIONAL: u32 = 10;
/// 3.1: the volume guides' sections laid out as `SELECTION`, `QUADRANTS`, `GUIDE_COST` and
/// `PENDING` (optional, as those are).
const SECTION_VOLUME_SELECTION: u32 = 11;
const SECTION_VOLUME_QUADRANTS: u32 = 12;
const SECTION_VOLUME_GUIDE_COST: u32 = 13;
const SECTION_VOLUME_PENDING: u32 = 14;
/// 3.3: each spatial leaf's split signature, in a field that splits spatial leaves by gain
/// (optional: a reader without it starts the iteration's signatures at zero).
const SECTION_SIGNATURES: u32 = 15;
const SIGNATURE_LEN: usize =
    8 * spatial_split::SIGNATURE_COUNTS + 16 * spatial_split::SIGNATURE_SUMS;
/// Section flag: a reader that does not know the section's kind must refuse the file.
const FLAG_REQUIRED: u32 = 1;
/// Length of the `META` section in format 1.0 (readers need at least this much).
const META_LEN_1_0: usize = 176;
/// Length of the `META` section in format 1.1.
const META_LEN_1_1: usize = 184;
/// Length of the `META` section in formats 1.2 to 2.3.
const META_LEN_2_3: usize = 192;
/// Length of the `META` section in formats 2.4 and 2.5.
const META_LEN_2_5: usize = 196;
/// Length of the `META` section in format 2.6.
const META_LEN_2_6: usize = 200;
/// Rejection reasons whose counters `META` holds at offsets 96 and 136 (those of 1.0–3.0); the
/// ones added since are appended at its end.
const REASONS_3_0: usize = 5;
/// Length of the `META` section in format 3.0.
const META_LEN_3_0: usize = 216;
/// Length of the `META` section in format 3.1.
const META_LEN_3_1: usize = 240;
/// Length of the `META` section in format 3.2.
const META_LEN_3_2: usize = 248;
/// Length of the `META` section this library writes (1.1 appends `prior_samples` and the
/// filters, 1.2 the refinement criterion and its threshold, 2.4 the guide probability's bound,
/// 2.6 the guide's cost, 3.0 the clamped-sample counters, 3.1 the flags (bit 0: volumes) and
/// the counters of medium samples rejected for want of a volume guide, 3.2 `filter_samples`,
/// 3.3 the spatial split rule and its threshold).
const META_LEN: usize = 256;
const SAMPLING_NODE_LEN: usize = 32;
const RECORDING_NODE_LEN: usize = 16;
const MOMENTS_LEN: usize = 24;
/// Tolerance on probabilities that should sum to 1 (they are `f32` roundings of `f64` ratios).
const SUM_TOLERANCE: f32 = 1e-4;

/// Why a cache could not be read or written.
#[derive(Debug)]
#[non_exhaustive]
pub enum CacheError {
    /// Reading or writing failed.
    Io(io::Error),
    /// The input does not start with [`MAGIC`]: not a cache file.
    BadMagic,
    /// The file's major version is not one this library reads.
    UnsupportedVersion {
        /// `(major, minor)` of the file.
        found: (u16, u16),
        /// `(major, minor)` this library writes; it reads every minor of that major.
        supported: (u16, u16),
    },
    /// The input ends before the length its header declares.
    Truncated {
        /// Bytes the file should have.
        expected: u64,
        /// Bytes there are.
        found: u64,
    },
    /// The CRC-32 stored at the end does not match the contents.
    ChecksumMismatch {
        /// The checksum in the file.
        stored: u32,
        /// The checksum of what was read.
        computed: u32,
    },
    /// A 2.x file holds a floating-point sum that no exact sum of this format equals: it was
    /// saved in the middle of an iteration by a library whose sums depended on the order of
    /// the samples. Refine it with that library first (a file saved at an iteration's start
    /// converts), or record the iteration again.
    Inexact {
        /// The section that holds it.
        section: &'static str,
        /// The sum.
        value: f64,
    },
    /// A part of the file is malformed (only possible when the checksum was forged or the
    /// writer was faulty).
    Corrupt {
        /// The part: `"header"`, `"sections"`, `"meta"`, `"spatial"` or `"directional"`.
        section: &'static str,
        /// What is wrong with it.
        detail: String,
    },
}

impl fmt::Display for CacheError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CacheError::Io(e) => write!(f, "cache i/o failed: {e}"),
            CacheError::BadMagic => write!(f, "not a sdguide cache (bad magic)"),
            CacheError::UnsupportedVersion { found, supported } => write!(
                f,
                "unsupported cache version {}.{} (this library reads {}.x, writes {}.{})",
                found.0, found.1, supported.0, supported.0, supported.1
            ),
            CacheError::Truncated { expected, found } => {
                write!(f, "cache truncated: {found} bytes of {expected}")
            }
            CacheError::ChecksumMismatch { stored, computed } => write!(
                f,
                "cache checksum mismatch: stored {stored:08x}, computed {computed:08x}"
            ),
            CacheError::Inexact { section, value } => write!(
                f,
                "cache of format 2.x holds the floating-point sum {value} ({section}), which no \
                 exact sum equals: it was saved mid-iteration; refine it with the library that \
                 wrote it first"
            ),
            CacheError::Corrupt { section, detail } => {
                write!(f, "corrupt cache ({section}): {detail}")
            }
        }
    }
}

impl std::error::Error for CacheError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            CacheError::Io(e) => Some(e),
            _ => None,
        }
    }
}

impl From<io::Error> for CacheError {
    fn from(e: io::Error) -> Self {
        CacheError::Io(e)
    }
}

fn corrupt(section: &'static str, detail: impl Into<String>) -> CacheError {
    CacheError::Corrupt {
        section,
        detail: detail.into(),
    }
}

impl GuidingField {
    /// Writes the whole field — configuration, trees, the current iteration's statistics and
    /// the counters — as a cache (see the module docs of `cache` and `docs/cache-format.md`).
    ///
    /// ```
    /// use sdguide::{Aabb, GuidingConfig, GuidingField};
    /// use glam::Vec3;
    /// let field = GuidingField::new(Aabb::new(Vec3::ZERO, Vec3::ONE), GuidingConfig::default())?;
    /// let mut bytes = Vec::new();
    /// field.save(&mut bytes)?;
    /// let loaded = GuidingField::load(bytes.as_slice())?;
    /// assert_eq!(loaded.stats(), field.stats());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    ///
    /// [`CacheError::Io`] when the writer fails.
    pub fn save(&self, mut writer: impl Write) -> Result<(), CacheError> {
        writer.write_all(&self.to_bytes())?;
        writer.flush()?;
        Ok(())
    }

    /// The cache as bytes (what [`save`](Self::save) writes).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut sections = vec![
            (SECTION_META, FLAG_REQUIRED, encode_meta(self)),
            (
                SECTION_SPATIAL,
                FLAG_REQUIRED,
                encode_spatial(&self.spatial),
            ),
            (
                SECTION_DIRECTIONAL,
                FLAG_REQUIRED,
                encode_directional(&self.regions),
            ),
            (SECTION_SELECTION, 0, encode_selection(&self.regions)),
            (SECTION_QUADRANTS, 0, encode_quadrants(&self.regions)),
            (
                SECTION_CONTINUATIONS,
                0,
                encode_continuations(&self.regions),
            ),
            (SECTION_SURFACES, 0, encode_surfaces(&self.regions)),
            (SECTION_GUIDE_COST, 0, encode_guide_cost(&self.regions)),
            (SECTION_PENDING, 0, encode_pending(&self.regions)),
        ];
        if self.config.spatial_split == SpatialSplit::Gain {
            sections.push((SECTION_SIGNATURES, 0, encode_signatures(&self.regions)));
        }
        if self.config.volumes {
            let volumes: Vec<&Guide> = self.regions.iter().filter_map(Region::volume).collect();
            sections.extend([
                (
                    SECTION_VOLUME_DIRECTIONAL,
                    FLAG_REQUIRED,
                    encode_directional(&volumes),
                ),
                (SECTION_VOLUME_SELECTION, 0, encode_selection(&volumes)),
                (SECTION_VOLUME_QUADRANTS, 0, encode_quadrants(&volumes)),
                (SECTION_VOLUME_GUIDE_COST, 0, encode_guide_cost(&volumes)),
                (SECTION_VOLUME_PENDING, 0, encode_pending(&volumes)),
            ]);
        }
        write_envelope(&sections)
    }

    /// Reads a cache written by [`save`](Self::save). The loaded field answers `sample` and
    /// `pdf` exactly as the saved one did, and training can continue from it.
    ///
    /// # Errors
    ///
    /// [`CacheError::Io`] when the reader fails, and every error of
    /// [`from_bytes`](Self::from_bytes).
    pub fn load(mut reader: impl Read) -> Result<GuidingField, CacheError> {
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes)?;
        Self::from_bytes(&bytes)
    }

    /// Reads a cache from bytes (see [`load`](Self::load)).
    ///
    /// # Errors
    ///
    /// A [`CacheError`] saying what is wrong when the bytes are not a valid cache of a
    /// supported version: bad magic, unsupported version, truncated, checksum mismatch, or a
    /// corrupt section (with detail).
    pub fn from_bytes(bytes: &[u8]) -> Result<GuidingField, CacheError> {
        let sections = read_envelope(bytes)?;
        let major = sections.major;
        let mut field = decode_meta(sections.meta)?;
        field.spatial = decode_spatial(sections.spatial, &field)?;
        let guides = decode_directional(sections.directional, "directional", &field, major)?;
        field.regions = guides
            .into_iter()
            .map(|g| Region::new(g.sampling, g.recording))
            .collect();
        let volumes = match (field.config.volumes, sections.volume_directional) {
            (true, Some(bytes)) => Some(decode_directional(
                bytes,
                "volume directional",
                &field,
                major,
            )?),
            (false, None) => None,
            (volumes, _) => {
                return Err(corrupt(
                    "sections",
                    format!("volumes {volumes} in meta, and a volume section that says otherwise"),
                ));
            }
        };
        if let Some(bytes) = sections.continuations {
            decode_continuations(bytes, &mut field.regions, major)?;
        }
        if let Some(bytes) = sections.surfaces {
            decode_surfaces(bytes, &mut field.regions, major)?;
        }
        let gain = field.config.spatial_split == SpatialSplit::Gain;
        for region in &mut field.regions {
            region.set_signature(gain);
        }
        if let (true, Some(bytes)) = (gain, sections.signatures) {
            decode_signatures(bytes, &mut field.regions)?;
        }
        let deferred = field.config.directional_filter.defers();
        decode_guide_sums(&sections.surface, &mut field.regions, major, deferred)?;
        if let Some(mut volumes) = volumes {
            decode_guide_sums(&sections.volume, &mut volumes, major, deferred)?;
            for (region, guide) in field.regions.iter_mut().zip(volumes) {
                region.set_volume(Some(guide));
            }
        }
        Ok(field)
    }

    /// Saves to `path` atomically: the cache is written to a temporary file in the same
    /// directory, flushed to disk, and renamed over `path`. An interrupted save leaves the old
    /// file (or none) in place, never a partial one.
    ///
    /// # Errors
    ///
    /// [`CacheError::Io`] when the path names no file or the temporary file cannot be
    /// created, written, synced or renamed; the file at `path` is then left as it was.
    pub fn save_to_path(&self, path: impl AsRef<Path>) -> Result<(), CacheError> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let path = path.as_ref();
        let name = path
            .file_name()
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "the path names no file"))?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let tmp = dir.join(format!(
            ".{}.{}-{}.tmp",
            name.to_string_lossy(),
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let bytes = self.to_bytes();
        let written = (|| {
            let mut file = std::fs::File::create_new(&tmp)?;
            file.write_all(&bytes)?;
            file.sync_all()?;
            drop(file);
            std::fs::rename(&tmp, path)?;
            sync_dir(dir)
        })();
        if written.is_err() {
            // Best effort: the temporary file is ours and useless now.
            let _ = std::fs::remove_file(&tmp);
        }
        Ok(written?)
    }

    /// Loads a cache file (see [`load`](Self::load)).
    ///
    /// # Errors
    ///
    /// [`CacheError::Io`] when the file cannot be read, and every error of
    /// [`from_bytes`](Self::from_bytes).
    pub fn load_from_path(path: impl AsRef<Path>) -> Result<GuidingField, CacheError> {
        Self::from_bytes(&std::fs::read(path)?)
    }
}

/// Makes a rename in `dir` durable (on Unix, by syncing the directory).
fn sync_dir(dir: &Path) -> io::Result<()> {
    #[cfg(unix)]
    std::fs::File::open(dir)?.sync_all()?;
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Reads a guide's optional sections — selection, quadrant sums, guide cost, pending sums — into
/// `guides` (decoded from the matching directional section), giving their recording trees
/// pending sums first where the filter defers (`deferred`).
fn decode_guide_sums(
    sections: &envelope::GuideSections<'_>,
    guides: &mut [impl GuideViewMut],
    major: u16,
    deferred: bool,
) -> Result<(), CacheError> {
    if let Some(bytes) = sections.selection {
        decode_selection(bytes, guides, major)?;
    }
    if let Some(bytes) = sections.quadrants {
        decode_quadrants(bytes, guides, major)?;
    }
    if let Some(bytes) = sections.guide_cost {
        decode_guide_cost(bytes, guides, major)?;
    }
    if deferred {
        for g in guides.iter_mut() {
            g.recording_mut().defer();
        }
    }
    if let Some(bytes) = sections.pending {
        decode_pending(bytes, guides)?;
    }
    Ok(())
}
