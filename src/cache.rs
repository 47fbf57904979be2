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

use crate::moments::{AtomicMoments, AtomicQuadrants};
use crate::quadtree::{self, DirectionalTree, RecordingTree, SamplingNode, SamplingTree};
use crate::selection::{
    GuideSelection, MAX_GUIDE_PROBABILITY, MIN_GUIDE_PROBABILITY, SelectionSums,
};
use crate::spatial::{self, MAX_SPATIAL_DEPTH, SpatialTree};
use crate::stats::RejectCounters;
use crate::{
    Aabb, DirectionalFilter, GuidingConfig, GuidingField, LeafRule, Moments, Refinement,
    Rejections, SpatialFilter,
};
use glam::Vec3;
use std::fmt;
use std::io::{self, Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// The first eight bytes of every cache file.
pub const MAGIC: [u8; 8] = *b"SDGUIDE\0";
/// The format's major version: a reader refuses other majors. Major 2 has the byte layout of
/// 1.2, with the directional trees on the octahedral map (see [`sphere`](crate::sphere)); in a
/// 1.x file they are on the cylindrical map, so the same bytes mean other directions.
pub const FORMAT_MAJOR: u16 = 2;
/// The format's minor version: a reader loads any minor of its major, skipping what it does
/// not know (optional sections, trailing bytes of a section). 2.1 added directional filter 2
/// (the deferred box filter) to `META`; a 2.0 reader refuses files that use it.
pub const FORMAT_MINOR: u16 = 1;

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
/// Section flag: a reader that does not know the section's kind must refuse the file.
const FLAG_REQUIRED: u32 = 1;
/// Length of the `META` section in format 1.0 (readers need at least this much).
const META_LEN_1_0: usize = 176;
/// Length of the `META` section in format 1.1.
const META_LEN_1_1: usize = 184;
/// Length of the `META` section this library writes (1.1 appends `prior_samples` and the
/// filters, 1.2 the refinement criterion and its threshold).
const META_LEN: usize = 192;
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
    pub fn save(&self, mut writer: impl Write) -> Result<(), CacheError> {
        writer.write_all(&self.to_bytes())?;
        writer.flush()?;
        Ok(())
    }

    /// The cache as bytes (what [`save`](Self::save) writes).
    pub fn to_bytes(&self) -> Vec<u8> {
        let sections = [
            (SECTION_META, FLAG_REQUIRED, encode_meta(self)),
            (
                SECTION_SPATIAL,
                FLAG_REQUIRED,
                encode_spatial(&self.spatial),
            ),
            (
                SECTION_DIRECTIONAL,
                FLAG_REQUIRED,
                encode_directional(&self.trees),
            ),
            (SECTION_SELECTION, 0, encode_selection(&self.trees)),
            (SECTION_QUADRANTS, 0, encode_quadrants(&self.trees)),
        ];
        let table_end = HEADER_LEN + ENTRY_LEN * sections.len();
        let body: usize = sections.iter().map(|(_, _, s)| s.len()).sum();
        let total = table_end + body + CHECKSUM_LEN;
        let mut out = Out(Vec::with_capacity(total));
        out.0.extend_from_slice(&MAGIC);
        out.u16(FORMAT_MAJOR);
        out.u16(FORMAT_MINOR);
        out.u32(0); // flags: none defined in 1.0
        out.u32(sections.len() as u32);
        out.u32(0); // reserved
        out.u64(total as u64);
        let mut offset = table_end;
        for (kind, flags, s) in &sections {
            out.u32(*kind);
            out.u32(*flags);
            out.u64(offset as u64);
            out.u64(s.len() as u64);
            offset += s.len();
        }
        for (_, _, s) in &sections {
            out.0.extend_from_slice(s);
        }
        let crc = crc32fast::hash(&out.0);
        out.u32(crc);
        out.0
    }

    /// Reads a cache written by [`save`](Self::save). The loaded field answers `sample` and
    /// `pdf` exactly as the saved one did, and training can continue from it.
    pub fn load(mut reader: impl Read) -> Result<GuidingField, CacheError> {
        let mut bytes = Vec::new();
        reader.read_to_end(&mut bytes)?;
        Self::from_bytes(&bytes)
    }

    /// Reads a cache from bytes (see [`load`](Self::load)).
    pub fn from_bytes(bytes: &[u8]) -> Result<GuidingField, CacheError> {
        let sections = read_envelope(bytes)?;
        let mut field = decode_meta(sections.meta)?;
        field.spatial = decode_spatial(sections.spatial, &field)?;
        field.trees = decode_directional(sections.directional, &field)?;
        if let Some(bytes) = sections.selection {
            decode_selection(bytes, &mut field.trees)?;
        }
        if let Some(bytes) = sections.quadrants {
            decode_quadrants(bytes, &mut field.trees)?;
        }
        field.prepare_recording();
        Ok(field)
    }

    /// Saves to `path` atomically: the cache is written to a temporary file in the same
    /// directory, flushed to disk, and renamed over `path`. An interrupted save leaves the old
    /// file (or none) in place, never a partial one.
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

/// A little-endian byte writer.
struct Out(Vec<u8>);

impl Out {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn vec3(&mut self, v: Vec3) {
        for c in v.to_array() {
            self.f32(c);
        }
    }
}

/// A little-endian reader over one section; reading past its end is corruption (the file's
/// length was already checked, so a short section means a wrong length in its table entry).
struct In<'a> {
    bytes: &'a [u8],
    section: &'static str,
}

impl<'a> In<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], CacheError> {
        if n > self.bytes.len() {
            return Err(corrupt(
                self.section,
                format!(
                    "ends early: {n} more bytes needed, {} left",
                    self.bytes.len()
                ),
            ));
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Ok(head)
    }
    fn array<const N: usize>(&mut self) -> Result<[u8; N], CacheError> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    fn u8(&mut self) -> Result<u8, CacheError> {
        Ok(self.array::<1>()?[0])
    }
    fn u16(&mut self) -> Result<u16, CacheError> {
        Ok(u16::from_le_bytes(self.array()?))
    }
    fn u32(&mut self) -> Result<u32, CacheError> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    fn u64(&mut self) -> Result<u64, CacheError> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    fn f32(&mut self) -> Result<f32, CacheError> {
        Ok(f32::from_bits(self.u32()?))
    }
    fn f64(&mut self) -> Result<f64, CacheError> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn vec3(&mut self) -> Result<Vec3, CacheError> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }
    /// A `u32` element count, checked against the bytes left before anyone allocates for it.
    fn count(&mut self, element_len: usize, what: &str) -> Result<usize, CacheError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(element_len) > self.bytes.len() {
            return Err(corrupt(
                self.section,
                format!("{n} {what} declared, only {} bytes left", self.bytes.len()),
            ));
        }
        Ok(n)
    }
}

/// The three sections every 1.x file has.
struct Sections<'a> {
    meta: &'a [u8],
    spatial: &'a [u8],
    directional: &'a [u8],
    selection: Option<&'a [u8]>,
    quadrants: Option<&'a [u8]>,
}

/// Checks magic, version, length and checksum, and finds the sections.
fn read_envelope(bytes: &[u8]) -> Result<Sections<'_>, CacheError> {
    let found = bytes.len() as u64;
    let prefix = bytes.len().min(MAGIC.len());
    if bytes[..prefix] != MAGIC[..prefix] {
        return Err(CacheError::BadMagic);
    }
    let minimum = (HEADER_LEN + CHECKSUM_LEN) as u64;
    if found < minimum {
        return Err(CacheError::Truncated {
            expected: minimum,
            found,
        });
    }
    let mut header = In {
        bytes: &bytes[MAGIC.len()..HEADER_LEN],
        section: "header",
    };
    let version = (header.u16()?, header.u16()?);
    if version.0 != FORMAT_MAJOR {
        return Err(CacheError::UnsupportedVersion {
            found: version,
            supported: (FORMAT_MAJOR, FORMAT_MINOR),
        });
    }
    let _flags = header.u32()?;
    let section_count = header.u32()? as usize;
    let _reserved = header.u32()?;
    let declared = header.u64()?;
    if found < declared {
        return Err(CacheError::Truncated {
            expected: declared,
            found,
        });
    }
    if found > declared || declared < minimum {
        return Err(corrupt(
            "header",
            format!("declared length {declared}, found {found} bytes"),
        ));
    }
    let body_end = bytes.len() - CHECKSUM_LEN;
    let stored = u32::from_le_bytes([
        bytes[body_end],
        bytes[body_end + 1],
        bytes[body_end + 2],
        bytes[body_end + 3],
    ]);
    let computed = crc32fast::hash(&bytes[..body_end]);
    if stored != computed {
        return Err(CacheError::ChecksumMismatch { stored, computed });
    }

    let table_end = section_count
        .checked_mul(ENTRY_LEN)
        .and_then(|t| t.checked_add(HEADER_LEN))
        .filter(|&t| t <= body_end)
        .ok_or_else(|| corrupt("sections", format!("{section_count} entries do not fit")))?;
    let mut table = In {
        bytes: &bytes[HEADER_LEN..table_end],
        section: "sections",
    };
    let (mut meta, mut spatial, mut directional) = (None, None, None);
    let (mut selection, mut quadrants) = (None, None);
    for _ in 0..section_count {
        let (kind, flags, offset, length) =
            (table.u32()?, table.u32()?, table.u64()?, table.u64()?);
        let range = usize::try_from(offset)
            .ok()
            .zip(usize::try_from(length).ok())
            .and_then(|(o, l)| Some(o..o.checked_add(l)?))
            .filter(|r| r.start >= table_end && r.end <= body_end)
            .ok_or_else(|| {
                corrupt(
                    "sections",
                    format!("section {kind} at {offset}+{length} lies outside the body"),
                )
            })?;
        let slot = match kind {
            SECTION_META => &mut meta,
            SECTION_SPATIAL => &mut spatial,
            SECTION_DIRECTIONAL => &mut directional,
            SECTION_SELECTION => &mut selection,
            SECTION_QUADRANTS => &mut quadrants,
            _ if flags & FLAG_REQUIRED != 0 => {
                return Err(corrupt(
                    "sections",
                    format!("unknown required section kind {kind}"),
                ));
            }
            _ => continue, // an optional section from a newer minor version
        };
        if slot.replace(&bytes[range]).is_some() {
            return Err(corrupt(
                "sections",
                format!("section kind {kind} appears twice"),
            ));
        }
    }
    let missing = |name: &str| corrupt("sections", format!("no {name} section"));
    Ok(Sections {
        meta: meta.ok_or_else(|| missing("meta"))?,
        spatial: spatial.ok_or_else(|| missing("spatial"))?,
        directional: directional.ok_or_else(|| missing("directional"))?,
        selection,
        quadrants,
    })
}

fn encode_meta(field: &GuidingField) -> Vec<u8> {
    let c = &field.config;
    let mut out = Out(Vec::with_capacity(META_LEN));
    out.u8(match c.rule {
        LeafRule::L1 => 0,
        LeafRule::L2 => 1,
    });
    out.0.extend_from_slice(&[0; 3]);
    out.f32(c.spatial_threshold);
    out.f32(c.subdivision_threshold);
    out.u32(c.max_directional_depth);
    out.f32(c.uniform_fraction);
    out.u32(c.max_directional_nodes);
    out.u32(c.max_spatial_nodes);
    out.u32(0);
    out.u64(c.max_memory_bytes);
    out.vec3(field.bounds.min);
    out.vec3(field.bounds.max);
    out.u32(field.iteration);
    out.u32(0);
    out.u64(field.recorded_before);
    out.u64(field.spatial_refused);
    out.u64(field.directional_refused);
    for counts in [field.rejected_before, field.rejected.get()] {
        for c in counts.to_array() {
            out.u64(c);
        }
    }
    debug_assert_eq!(out.0.len(), META_LEN_1_0);
    out.f32(c.prior_samples);
    out.u8(match c.spatial_filter {
        SpatialFilter::Nearest => 0,
        SpatialFilter::Stochastic => 1,
        SpatialFilter::Box => 2,
    });
    out.u8(match c.directional_filter {
        DirectionalFilter::Nearest => 0,
        DirectionalFilter::Box => 1,
        DirectionalFilter::DeferredBox => 2,
    });
    out.0.extend_from_slice(&[0; 2]);
    debug_assert_eq!(out.0.len(), META_LEN_1_1);
    out.u8(match c.refinement {
        Refinement::FluxShare => 0,
        Refinement::VarianceGain => 1,
    });
    out.0.extend_from_slice(&[0; 3]);
    out.f32(c.gain_threshold);
    debug_assert_eq!(out.0.len(), META_LEN);
    out.0
}

/// Reads `META` into a field with its configuration, bounds and counters (and no trees yet).
fn decode_meta(bytes: &[u8]) -> Result<GuidingField, CacheError> {
    let mut r = In {
        bytes,
        section: "meta",
    };
    let rule = match r.u8()? {
        0 => LeafRule::L1,
        1 => LeafRule::L2,
        other => return Err(corrupt("meta", format!("unknown leaf rule {other}"))),
    };
    r.take(3)?;
    let mut config = GuidingConfig {
        rule,
        spatial_threshold: r.f32()?,
        subdivision_threshold: r.f32()?,
        max_directional_depth: r.u32()?,
        uniform_fraction: r.f32()?,
        max_directional_nodes: r.u32()?,
        max_spatial_nodes: r.u32()?,
        ..GuidingConfig::default()
    };
    r.u32()?;
    config.max_memory_bytes = r.u64()?;
    let bounds = Aabb::new(r.vec3()?, r.vec3()?);
    // `new` validates the configuration and the bounds exactly as for a field built in code.
    let mut field =
        GuidingField::new(bounds, config).map_err(|e| corrupt("meta", e.to_string()))?;
    field.iteration = r.u32()?;
    r.u32()?;
    field.recorded_before = r.u64()?;
    field.spatial_refused = r.u64()?;
    field.directional_refused = r.u64()?;
    let mut counts = [Rejections::default(); 2];
    for c in &mut counts {
        let mut a = [0u64; 5];
        for x in &mut a {
            *x = r.u64()?;
        }
        *c = Rejections::from_array(a);
    }
    field.rejected_before = counts[0];
    field.rejected = RejectCounters::from_rejections(counts[1]);
    // 1.1: shrinkage and filters. A 1.0 file trained without shrinkage (and unfiltered), and
    // keeps training so.
    if r.bytes.is_empty() {
        field.config.prior_samples = 0.0;
    } else {
        field.config.prior_samples = r.f32()?;
        field.config.spatial_filter = match r.u8()? {
            0 => SpatialFilter::Nearest,
            1 => SpatialFilter::Stochastic,
            2 => SpatialFilter::Box,
            other => return Err(corrupt("meta", format!("unknown spatial filter {other}"))),
        };
        field.config.directional_filter = match r.u8()? {
            0 => DirectionalFilter::Nearest,
            1 => DirectionalFilter::Box,
            2 => DirectionalFilter::DeferredBox,
            other => {
                return Err(corrupt(
                    "meta",
                    format!("unknown directional filter {other}"),
                ));
            }
        };
        r.take(2)?;
    }
    // 1.2: the refinement criterion. A 1.1 (or 1.0) file was refined by flux share, and keeps
    // being so.
    if r.bytes.is_empty() {
        field.config.refinement = Refinement::FluxShare;
    } else {
        field.config.refinement = match r.u8()? {
            0 => Refinement::FluxShare,
            1 => Refinement::VarianceGain,
            other => return Err(corrupt("meta", format!("unknown refinement {other}"))),
        };
        r.take(3)?;
        field.config.gain_threshold = r.f32()?;
    }
    field
        .config
        .validate()
        .map_err(|e| corrupt("meta", e.to_string()))?;
    Ok(field)
}

fn encode_spatial(tree: &SpatialTree) -> Vec<u8> {
    let nodes = tree.nodes();
    let mut out = Out(Vec::with_capacity(4 + 4 * nodes.len()));
    out.u32(nodes.len() as u32);
    for &n in nodes {
        out.u32(n);
    }
    out.0
}

fn decode_spatial(bytes: &[u8], field: &GuidingField) -> Result<SpatialTree, CacheError> {
    let mut r = In {
        bytes,
        section: "spatial",
    };
    let n = r.count(4, "nodes")?;
    if n == 0 || n > field.config.max_spatial_nodes as usize {
        return Err(corrupt(
            "spatial",
            format!("{n} nodes, expected 1..={}", field.config.max_spatial_nodes),
        ));
    }
    let nodes = (0..n).map(|_| r.u32()).collect::<Result<Vec<u32>, _>>()?;
    check_tree(n, MAX_SPATIAL_DEPTH, |i| {
        let e = nodes[i];
        if e & spatial::LEAF_BIT != 0 {
            [None, None]
        } else {
            [Some(e as usize), Some(e as usize + 1)]
        }
    })
    .map_err(|d| corrupt("spatial", d))?;
    // Leaves index directional trees 0..leaves, each exactly once.
    let leaves: Vec<usize> = nodes
        .iter()
        .filter(|&&e| e & spatial::LEAF_BIT != 0)
        .map(|&e| (e & !spatial::LEAF_BIT) as usize)
        .collect();
    check_permutation(&leaves).map_err(|d| corrupt("spatial", format!("leaf {d}")))?;
    Ok(SpatialTree::from_nodes(field.spatial.cube(), nodes))
}

fn encode_directional(trees: &[DirectionalTree]) -> Vec<u8> {
    let mut out = Out(Vec::new());
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.sampling.nodes();
        out.u32(s.len() as u32);
        for n in s.iter() {
            for p in n.px.iter().chain(n.py.iter().flatten()) {
                out.f32(*p);
            }
            for c in n.child {
                out.u16(c);
            }
        }
        let r = &t.recording;
        out.u32(r.nodes.len() as u32);
        for slots in r.nodes.iter() {
            for &s in slots {
                out.u32(s);
            }
        }
        // The moments as the format defines them: every sample's filtered share included.
        r.flush_pending();
        out.u32(r.moments.len() as u32);
        for m in r.moments.iter() {
            let m = m.get();
            out.f64(m.sum);
            out.f64(m.sum_sq);
            out.u64(m.count);
        }
    }
    out.0
}

fn encode_selection(trees: &[DirectionalTree]) -> Vec<u8> {
    let mut out = Out(Vec::with_capacity(4 + SELECTION_LEN * trees.len()));
    out.u32(trees.len() as u32);
    for t in trees {
        let s = t.selection.sums();
        out.f32(t.selection.probability);
        out.u32(0);
        out.f64(s.gradient);
        out.f64(s.curvature);
        out.u64(s.count);
    }
    out.0
}

fn encode_quadrants(trees: &[DirectionalTree]) -> Vec<u8> {
    let mut out = Out(Vec::new());
    out.u32(trees.len() as u32);
    for t in trees {
        let q = &t.recording.quadrants;
        out.u32(q.len() as u32);
        for (s2, n) in q.iter().flat_map(|q| q.get()) {
            out.f64(s2);
            out.u64(n);
        }
    }
    out.0
}

/// Reads the optional quadrants section into `trees` (already decoded).
fn decode_quadrants(bytes: &[u8], trees: &mut [DirectionalTree]) -> Result<(), CacheError> {
    let section = "quadrants";
    let mut r = In { bytes, section };
    let n = r.count(4, "trees")?;
    if n != trees.len() {
        return Err(corrupt(
            section,
            format!("{n} trees of quadrant sums for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let leaves = r.count(QUADRANTS_LEN, "leaves")?;
        if leaves != t.recording.moments.len() {
            return Err(corrupt(
                section,
                format!(
                    "tree {i}: {leaves} leaves of quadrant sums for {} leaves",
                    t.recording.moments.len()
                ),
            ));
        }
        for (k, slot) in t.recording.quadrants.iter_mut().enumerate() {
            let mut q = [(0.0, 0); 4];
            for x in &mut q {
                *x = (r.f64()?, r.u64()?);
            }
            if !q.iter().all(|(s2, _)| s2.is_finite() && *s2 >= 0.0) {
                return Err(corrupt(
                    section,
                    format!("tree {i}, leaf {k}: quadrant sums {q:?}"),
                ));
            }
            *slot = AtomicQuadrants::from_quadrants(q);
        }
    }
    Ok(())
}

/// Reads the optional selection section into `trees` (already decoded).
fn decode_selection(bytes: &[u8], trees: &mut [DirectionalTree]) -> Result<(), CacheError> {
    let mut r = In {
        bytes,
        section: "selection",
    };
    let n = r.count(SELECTION_LEN, "selections")?;
    if n != trees.len() {
        return Err(corrupt(
            "selection",
            format!("{n} selections for {} trees", trees.len()),
        ));
    }
    for (i, t) in trees.iter_mut().enumerate() {
        let probability = r.f32()?;
        r.u32()?;
        let sums = SelectionSums {
            gradient: r.f64()?,
            curvature: r.f64()?,
            count: r.u64()?,
        };
        let in_range = (MIN_GUIDE_PROBABILITY..=MAX_GUIDE_PROBABILITY).contains(&probability);
        let sums_ok = sums.gradient.is_finite()
            && sums.curvature.is_finite()
            && sums.curvature >= 0.0
            && (sums.count > 0 || (sums.gradient == 0.0 && sums.curvature == 0.0));
        if !(in_range && sums_ok) {
            return Err(corrupt(
                "selection",
                format!("tree {i}: probability {probability}, sums {sums:?}"),
            ));
        }
        t.selection = GuideSelection::from_parts(probability, sums);
    }
    Ok(())
}

fn decode_directional(
    bytes: &[u8],
    field: &GuidingField,
) -> Result<Vec<DirectionalTree>, CacheError> {
    let mut r = In {
        bytes,
        section: "directional",
    };
    let leaves = field.spatial.leaves().len();
    let n = r.count(12, "trees")?;
    if n != leaves {
        return Err(corrupt(
            "directional",
            format!("{n} trees for {leaves} spatial leaves"),
        ));
    }
    let c = &field.config;
    (0..n)
        .map(|i| {
            decode_tree(&mut r, c).map_err(|e| match e {
                CacheError::Corrupt { section, detail } => {
                    corrupt(section, format!("tree {i}: {detail}"))
                }
                other => other,
            })
        })
        .collect()
}

fn decode_tree(r: &mut In<'_>, c: &GuidingConfig) -> Result<DirectionalTree, CacheError> {
    let section = "directional";
    // Interior node depth is at most max_depth − 1: their children, the leaves, reach max_depth.
    let max_node_depth = c.max_directional_depth - 1;
    let max_nodes = c.max_directional_nodes as usize;

    let n = node_count(r, SAMPLING_NODE_LEN, "sampling nodes", max_nodes)?;
    let mut sampling = Vec::with_capacity(n);
    for i in 0..n {
        let mut p = [0f32; 6];
        for x in &mut p {
            *x = r.f32()?;
        }
        let node = SamplingNode {
            px: [p[0], p[1]],
            py: [[p[2], p[3]], [p[4], p[5]]],
            child: [r.u16()?, r.u16()?, r.u16()?, r.u16()?],
        };
        for pair in [node.px, node.py[0], node.py[1]] {
            let ok = pair.iter().all(|&x| x > 0.0 && x <= 1.0)
                && (pair[0] + pair[1] - 1.0).abs() <= SUM_TOLERANCE;
            if !ok {
                return Err(corrupt(
                    section,
                    format!("sampling node {i}: probabilities {pair:?}"),
                ));
            }
        }
        sampling.push(node);
    }
    check_tree(n, max_node_depth, |i| {
        sampling[i]
            .child
            .map(|ch| (ch != quadtree::NO_CHILD).then_some(usize::from(ch)))
    })
    .map_err(|d| corrupt(section, format!("sampling tree: {d}")))?;

    let n = node_count(r, RECORDING_NODE_LEN, "recording nodes", max_nodes)?;
    let mut nodes = Vec::with_capacity(n);
    for _ in 0..n {
        nodes.push([r.u32()?, r.u32()?, r.u32()?, r.u32()?]);
    }
    check_tree(n, max_node_depth, |i| {
        nodes[i].map(|s| (s & quadtree::LEAF_BIT == 0).then_some(s as usize))
    })
    .map_err(|d| corrupt(section, format!("recording tree: {d}")))?;
    let leaf_slots: Vec<usize> = nodes
        .iter()
        .flatten()
        .filter(|&&s| s & quadtree::LEAF_BIT != 0)
        .map(|&s| (s & !quadtree::LEAF_BIT) as usize)
        .collect();
    check_permutation(&leaf_slots).map_err(|d| corrupt(section, format!("recording leaf {d}")))?;

    let m = r.count(MOMENTS_LEN, "leaf moments")?;
    if m != leaf_slots.len() {
        return Err(corrupt(
            section,
            format!("{m} leaf moments for {} leaves", leaf_slots.len()),
        ));
    }
    let mut moments = Vec::with_capacity(m);
    for k in 0..m {
        let mm = Moments {
            sum: r.f64()?,
            sum_sq: r.f64()?,
            count: r.u64()?,
        };
        let sums_ok = [mm.sum, mm.sum_sq]
            .iter()
            .all(|s| s.is_finite() && *s >= 0.0);
        // A zero count may carry sums: a box filter spreads shares into leaves it does not count.
        if !sums_ok {
            return Err(corrupt(section, format!("leaf {k}: moments {mm:?}")));
        }
        moments.push(AtomicMoments::from_moments(mm));
    }
    Ok(DirectionalTree {
        sampling: SamplingTree::new(sampling.into_boxed_slice()),
        recording: RecordingTree {
            nodes: nodes.into_boxed_slice(),
            quadrants: (0..moments.len()).map(|_| Default::default()).collect(),
            moments: moments.into_boxed_slice(),
            pending: Box::default(),
        },
        selection: GuideSelection::default(),
    })
}

/// A tree's node count: present in the bytes, and between 1 and the configuration's cap.
fn node_count(r: &mut In<'_>, len: usize, what: &str, max: usize) -> Result<usize, CacheError> {
    let n = r.count(len, what)?;
    if n == 0 || n > max {
        return Err(corrupt(
            r.section,
            format!("{n} {what}, expected 1..={max}"),
        ));
    }
    Ok(n)
}

/// Checks that `children(i)` describes one tree over nodes `0..n` rooted at 0: every child
/// comes after its parent and inside the tree (so there are no cycles), every node but the root
/// has exactly one parent, and no node is deeper than `max_depth`.
fn check_tree<const K: usize>(
    n: usize,
    max_depth: u32,
    children: impl Fn(usize) -> [Option<usize>; K],
) -> Result<(), String> {
    const UNREACHED: u32 = u32::MAX;
    let mut depth = vec![UNREACHED; n];
    depth[0] = 0;
    for i in 0..n {
        if depth[i] == UNREACHED {
            return Err(format!("node {i} has no parent"));
        }
        for c in children(i).into_iter().flatten() {
            if c <= i || c >= n {
                return Err(format!("node {i} points to {c}, outside {}..{n}", i + 1));
            }
            if depth[c] != UNREACHED {
                return Err(format!("node {c} has two parents"));
            }
            if depth[i] + 1 > max_depth {
                return Err(format!("node {c} is deeper than {max_depth}"));
            }
            depth[c] = depth[i] + 1;
        }
    }
    Ok(())
}

/// Checks that `indices` is a permutation of `0..indices.len()`; the error names the culprit.
fn check_permutation(indices: &[usize]) -> Result<(), String> {
    let mut seen = vec![false; indices.len()];
    for &k in indices {
        match seen.get_mut(k) {
            Some(s) if !*s => *s = true,
            Some(_) => return Err(format!("{k} appears twice")),
            None => return Err(format!("{k} is out of range 0..{}", indices.len())),
        }
    }
    Ok(())
}
