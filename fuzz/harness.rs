//! What the fuzz targets do with their input. Shared by the cargo-fuzz targets (nightly) and by
//! `tests/fuzz_corpus.rs`, which replays the checked-in corpus on stable.
//!
//! Both functions must never panic on any input; the assertions inside are the library's
//! guarantees (a loaded cache saves back identically, `sample` returns the pdf `pdf` gives, ...)
//! and a failing one is a bug the fuzzer found.

use glam::{Vec2, Vec3};
use sdguide::{
    Aabb, Continuation, DirectionalFilter, GuidingConfig, GuidingField, LeafRule, PathRecorder,
    PathVertex, Refinement, Sample, SpatialFilter, SpatialSplit, VertexId,
};

/// At most this many operations, refines and save–load round trips per input, and a memory
/// budget of at most 1 MiB (`field_from`), so that an input runs in about a millisecond and the
/// fuzzer explores thousands of them a second. The budget binds often, which fuzzes the growth
/// limits too; larger fields take the same code paths, only longer.
const MAX_OPS: usize = 256;
const MAX_REFINES: usize = 8;
const MAX_ROUND_TRIPS: usize = 4;

/// Arbitrary bytes as a cache: as given, and with the length field and checksum repaired so
/// that mutations reach the structural validation behind the checksum.
pub fn cache_load(data: &[u8]) {
    load_and_check(data);
    if data.len() >= 36 {
        let mut fixed = data.to_vec();
        let len = fixed.len();
        fixed[24..32].copy_from_slice(&(len as u64).to_le_bytes());
        let crc = crc32fast::hash(&fixed[..len - 4]);
        fixed[len - 4..].copy_from_slice(&crc.to_le_bytes());
        load_and_check(&fixed);
    }
}

fn load_and_check(data: &[u8]) {
    if let Ok(field) = GuidingField::from_bytes(data) {
        let bytes = field.to_bytes();
        let again = GuidingField::from_bytes(&bytes).expect("a saved field loads");
        assert_eq!(again.to_bytes(), bytes, "load ∘ save is the identity");
        let _ = field.stats();
        check_query(&field, Vec3::splat(0.5), Vec2::new(0.3, 0.6));
    }
}

/// Arbitrary bytes as a configuration, bounds, and a sequence of operations on a field.
pub fn field_ops(data: &[u8]) {
    let mut b = Bytes(data);
    let Some(mut field) = field_from(&mut b) else {
        return;
    };
    let (mut refines, mut round_trips) = (0, 0);
    for _ in 0..MAX_OPS {
        let Some(op) = b.u8() else { break };
        match op % 8 {
            // Record a sample, possibly many times.
            0 | 1 => {
                let (Some(p), Some(d), Some(v), Some(pdf), Some(n)) =
                    (b.vec3(), b.vec3(), b.f32(), b.f32(), b.u8())
                else {
                    break;
                };
                // The high bit of `n` adds mixture terms (integrand v, BSDF pdf `pdf`, guide pdf
                // `v`): arbitrary values for the guide-selection sums. The next bit adds a second
                // moment (`pdf`, any value, to the second-moment sums), the next one a normal
                // (the direction, any vector: the tally of normals), the next one makes it a
                // medium sample (the volume guides, or a rejection without them).
                let mut sample = Sample {
                    position: p,
                    direction: d,
                    value: v,
                    pdf,
                    second_moment: (n & 0x40 != 0).then_some(pdf),
                    normal: (n & 0x20 != 0).then_some(d),
                    volume: n & 0x10 != 0,
                    ..Sample::default()
                };
                if n & 0x80 != 0 {
                    sample = sample.with_mixture(v, pdf, v.abs());
                }
                for _ in 0..=(n % 16) {
                    field.record(&sample);
                }
            }
            2 if refines < MAX_REFINES => {
                field.refine();
                refines += 1;
            }
            // Query, and record what the query drew, as a renderer would; then the volume
            // guide's product with a phase function of arbitrary asymmetry `v` about the drawn
            // direction, recorded as a medium sample.
            3 => {
                let (Some(x), Some(u), Some(v)) = (b.vec3(), b.vec2(), b.f32()) else {
                    break;
                };
                let (d, pdf) = check_query(&field, x, u);
                field.record(&Sample {
                    position: x,
                    direction: d,
                    value: v,
                    pdf,
                    ..Sample::default()
                });
                let phase = field.volume_distribution(x).with_phase(d, v);
                let (w, p) = phase.sample(u);
                assert!(
                    w.is_finite() && (w.length() - 1.0).abs() < 1e-4,
                    "direction {w}"
                );
                assert!(p > 0.0 && p.is_finite(), "phase pdf {p}");
                assert_eq!(p.to_bits(), phase.pdf(w).to_bits(), "phase sample and pdf");
                field.record(&Sample {
                    position: x,
                    direction: w,
                    value: v,
                    pdf: p,
                    volume: true,
                    ..Sample::default()
                });
            }
            4 if round_trips < MAX_ROUND_TRIPS => {
                round_trips += 1;
                let bytes = field.to_bytes();
                let loaded = GuidingField::from_bytes(&bytes).expect("a saved field loads");
                assert_eq!(loaded.to_bytes(), bytes, "load ∘ save is the identity");
                // A render farm's merge: a copy merges exactly, its counts added.
                let mut twin = GuidingField::from_bytes(&bytes).expect("a saved field loads");
                twin.merge(&loaded)
                    .expect("a field merges with its own copy");
                assert_eq!(
                    twin.stats().samples_recorded,
                    2 * loaded.stats().samples_recorded,
                    "merge adds the counts"
                );
                field = loaded;
            }
            // A continuation, with arbitrary value and cost (the continuation sums).
            5 => {
                let (Some(position), Some(value), Some(cost)) = (b.vec3(), b.f32(), b.f32()) else {
                    break;
                };
                field.record_continuation(&Continuation {
                    position,
                    value,
                    cost,
                });
            }
            // A path through the recorder: arbitrary events on arbitrary handles, then recorded.
            6 => {
                let Some(events) = b.u8() else { break };
                path_ops(&mut b, &field, events % 32);
            }
            _ => {
                let s = field.stats();
                assert!(s.spatial_nodes <= u64::from(field.config().max_spatial_nodes));
            }
        }
    }
}

/// `events` path-recorder calls from fuzz bytes on a small recorder (8 vertices, so that
/// overflow is reached), each on a handle the bytes pick (valid or not); then the path is
/// finished and recorded into `field`.
fn path_ops(b: &mut Bytes<'_>, field: &GuidingField, events: u8) {
    let mut path = PathRecorder::with_max_vertices(8);
    let mut ids = vec![path.start()];
    for _ in 0..events {
        let (Some(kind), Some(pick), Some(x), Some(w), Some(f)) =
            (b.u8(), b.u8(), b.vec3(), b.vec3(), b.f32())
        else {
            break;
        };
        let at = match pick {
            255 => VertexId::from_index(u32::from(pick)),
            _ => ids[usize::from(pick) % ids.len()],
        };
        match kind % 6 {
            0 => {
                let v = PathVertex::new(x, w, w.abs(), f).with_normal(x);
                let v = if kind & 0x40 != 0 { v.in_volume() } else { v };
                ids.push(path.push(
                    at,
                    if kind & 0x80 != 0 {
                        v.with_mixture(f, f)
                    } else {
                        v
                    },
                ));
            }
            1 => ids.push(path.push_delta(at, x, w)),
            2 => path.add_radiance(at, w),
            3 => path.roulette(at, f, kind & 0x80 != 0),
            4 => path.split(at, f, u32::from(kind >> 4)),
            _ => path.add_cost(at, f),
        }
    }
    let estimate = path.finish();
    let bits = |v: Vec3| v.to_array().map(f32::to_bits);
    assert_eq!(
        bits(path.finish()),
        bits(estimate),
        "finish twice: the same estimate"
    );
    let records = path.records().count();
    assert!(records < 8, "at most the vertices a path holds");
    assert_eq!(path.record(field), records);
}

/// A field from fuzz bytes: every configuration field and the bounds are arbitrary (the memory
/// budget is at most 1 MiB so that inputs stay cheap); invalid ones are refused by `new`.
fn field_from(b: &mut Bytes<'_>) -> Option<GuidingField> {
    let mut config = GuidingConfig {
        rule: [LeafRule::L1, LeafRule::L2, LeafRule::L2Mixture][usize::from(b.u8()? % 3)],
        spatial_threshold: b.f32()?,
        subdivision_threshold: b.f32()?,
        max_directional_depth: u32::from(b.u8()?),
        uniform_fraction: b.f32()?,
        max_directional_nodes: u32::from(b.u16()?),
        max_spatial_nodes: u32::from(b.u16()?),
        max_memory_bytes: u64::from(b.u8()?) << 12,
        ..GuidingConfig::default()
    };
    let bounds = Aabb::new(b.vec3()?, b.vec3()?);
    config.prior_samples = b.f32()?;
    let filters = b.u8()?;
    config.spatial_filter = [
        SpatialFilter::Nearest,
        SpatialFilter::Stochastic,
        SpatialFilter::Box,
    ][usize::from(filters % 3)];
    // Bit 2 picks a box filter, bit 4 defers it to refine.
    config.directional_filter = match (filters & 4 != 0, filters & 16 != 0) {
        (false, _) => DirectionalFilter::Nearest,
        (true, false) => DirectionalFilter::Box,
        (true, true) => DirectionalFilter::DeferredBox,
    };
    // Bit 5 gives every spatial leaf a volume guide.
    config.volumes = filters & 32 != 0;
    // Bit 3 picks the refinement; the arbitrary ρ doubles as τ (both must be in (0, 1)).
    if filters & 8 == 0 {
        config.refinement = Refinement::FluxShare;
    } else {
        config.refinement = Refinement::VarianceGain;
        config.gain_threshold = config.subdivision_threshold;
    }
    // Bit 6 splits spatial leaves by gain; the arbitrary ρ doubles as its τ too.
    if filters & 64 != 0 {
        config.spatial_split = SpatialSplit::Gain;
        config.spatial_gain_threshold = config.subdivision_threshold;
    }
    GuidingField::new(bounds, config).ok()
}

/// Samples the distribution at `x` and checks what the library promises about the result.
fn check_query(field: &GuidingField, x: Vec3, u: Vec2) -> (Vec3, f32) {
    let dist = field.distribution(x);
    let (d, pdf) = dist.sample(u);
    assert!(
        d.is_finite() && (d.length() - 1.0).abs() < 1e-4,
        "direction {d}"
    );
    assert!(pdf > 0.0 && pdf.is_finite(), "pdf {pdf}");
    assert_eq!(
        pdf.to_bits(),
        dist.pdf(d).to_bits(),
        "sample and pdf disagree"
    );
    (d, pdf)
}

/// A cursor over fuzz bytes.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let (head, tail) = self.0.split_first_chunk::<N>()?;
        self.0 = tail;
        Some(*head)
    }
    fn u8(&mut self) -> Option<u8> {
        Some(self.take::<1>()?[0])
    }
    fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes(self.take()?))
    }
    fn f32(&mut self) -> Option<f32> {
        Some(f32::from_le_bytes(self.take()?))
    }
    fn vec2(&mut self) -> Option<Vec2> {
        Some(Vec2::new(self.f32()?, self.f32()?))
    }
    fn vec3(&mut self) -> Option<Vec3> {
        Some(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }
}
