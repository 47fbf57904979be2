//! The file's envelope: header (magic, version, length), table of sections, checksum. Writing
//! lays the sections out; reading checks all of it before any section is decoded.

use super::*;

/// The header, the table of sections, the sections and the checksum: a whole cache file from
/// its sections `(kind, flags, bytes)`.
pub(super) fn write_envelope(sections: &[(u32, u32, Vec<u8>)]) -> Vec<u8> {
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
    for (kind, flags, s) in sections {
        out.u32(*kind);
        out.u32(*flags);
        out.u64(offset as u64);
        out.u64(s.len() as u64);
        offset += s.len();
    }
    for (_, _, s) in sections {
        out.0.extend_from_slice(s);
    }
    let crc = crc32fast::hash(&out.0);
    out.u32(crc);
    out.0
}

/// The optional sections of one kind of guide (surface or volume): the sums beside its trees.
#[derive(Default)]
pub(super) struct GuideSections<'a> {
    pub(super) selection: Option<&'a [u8]>,
    pub(super) quadrants: Option<&'a [u8]>,
    pub(super) guide_cost: Option<&'a [u8]>,
    pub(super) pending: Option<&'a [u8]>,
}

/// The sections of a file (`META`, `SPATIAL` and `DIRECTIONAL` required), and its major
/// version.
pub(super) struct Sections<'a> {
    pub(super) meta: &'a [u8],
    pub(super) spatial: &'a [u8],
    pub(super) directional: &'a [u8],
    pub(super) surface: GuideSections<'a>,
    /// `VOLUME_DIRECTIONAL`, required where `META` says the field has volumes.
    pub(super) volume_directional: Option<&'a [u8]>,
    pub(super) volume: GuideSections<'a>,
    pub(super) continuations: Option<&'a [u8]>,
    pub(super) surfaces: Option<&'a [u8]>,
    pub(super) signatures: Option<&'a [u8]>,
    /// The file's major version: 2.x files hold their sums as `f64`.
    pub(super) major: u16,
}

/// Checks magic, version, length and checksum, and finds the sections.
pub(super) fn read_envelope(bytes: &[u8]) -> Result<Sections<'_>, CacheError> {
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
    let mut header = In::new(&bytes[MAGIC.len()..HEADER_LEN], "header");
    let version = (header.u16()?, header.u16()?);
    if !(LEGACY_MAJOR..=FORMAT_MAJOR).contains(&version.0) {
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
    let mut table = In::new(&bytes[HEADER_LEN..table_end], "sections");
    let (mut meta, mut spatial, mut directional) = (None, None, None);
    let (mut volume_directional, mut continuations, mut surfaces) = (None, None, None);
    let mut signatures = None;
    let (mut surface, mut volume) = (GuideSections::default(), GuideSections::default());
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
            SECTION_SELECTION => &mut surface.selection,
            SECTION_QUADRANTS => &mut surface.quadrants,
            SECTION_CONTINUATIONS => &mut continuations,
            SECTION_SURFACES => &mut surfaces,
            SECTION_GUIDE_COST => &mut surface.guide_cost,
            SECTION_PENDING => &mut surface.pending,
            SECTION_VOLUME_DIRECTIONAL => &mut volume_directional,
            SECTION_VOLUME_SELECTION => &mut volume.selection,
            SECTION_VOLUME_QUADRANTS => &mut volume.quadrants,
            SECTION_VOLUME_GUIDE_COST => &mut volume.guide_cost,
            SECTION_VOLUME_PENDING => &mut volume.pending,
            SECTION_SIGNATURES => &mut signatures,
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
        surface,
        volume_directional,
        volume,
        continuations,
        surfaces,
        signatures,
        major: version.0,
    })
}
