//! Intel Open PGL, the production guiding library of Blender Cycles, as a second guiding backend
//! of the demo: a small safe wrapper over its C API, so that every figure the demo reports for
//! sdguide has the peer's beside it, measured in the same renderer and the same run.
//!
//! Built only with the `openpgl` feature; `build.rs` builds the vendored source and links it.
//! What is wired and what is not matched is in `docs/render.md`.
//!
//! The wrapper owns four kinds of Open PGL objects: the device (its thread pool), the field (a
//! kd-tree of parallax-aware von Mises–Fisher mixtures), the sample storage the render threads
//! record into, and the per-vertex sampling distributions. A distribution is a heap object that
//! Open PGL re-initialises at every vertex; one per render thread is kept in a thread-local pool,
//! so a vertex costs an `Init`, not an allocation.
#![allow(unsafe_code)]

use crate::backend::{Backend, Segment, VertexGuide};
use glam::{Vec2, Vec3};
use sdguide::Aabb;
use std::cell::RefCell;
use std::ffi::c_void;
use std::sync::atomic::{AtomicU64, Ordering};

/// The version of the Open PGL this demo was built against.
pub const VERSION: &str = env!("OPENPGL_VERSION");

/// The raw C API (`openpgl/openpgl.h`). Its "C" functions take C++ references in a few places;
/// those are pointers at the ABI level.
mod ffi;

fn vec3f(v: Vec3) -> ffi::Vec3f {
    ffi::Vec3f {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// One recorded vertex: the radiance that arrived along `direction` at `position`, drawn with
/// pdf `pdf`, from a source `distance` away (Open PGL's parallax compensation uses it), and what
/// the vertex reflected toward `outgoing` (its radiance cache learns it).
#[derive(Clone, Copy, Debug, Default)]
pub struct Record {
    /// Where the path scattered.
    pub position: Vec3,
    /// The unit direction it scattered into.
    pub direction: Vec3,
    /// The luminance of the radiance that arrived along `direction`.
    pub radiance: f32,
    /// The pdf `direction` was drawn with (the mixture's).
    pub pdf: f32,
    /// Distance to the next vertex along `direction`.
    pub distance: f32,
    /// The unit direction back along the path, toward the camera.
    pub outgoing: Vec3,
    /// The luminance of what the vertex reflected toward `outgoing` through this sample: the
    /// arrived radiance times `f·cos`, over `pdf`.
    pub reflected: f32,
    /// Whether the vertex lies inside a medium (it trains Open PGL's volume field).
    pub volume: bool,
}

/// Which directional distribution an Open PGL field fits in each spatial region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Directional {
    /// Its default and Cycles': a mixture of von Mises–Fisher lobes whose means move with the
    /// query point by the distances recorded (parallax).
    ParallaxAwareVmm,
    /// The same mixture without parallax compensation.
    Vmm,
    /// Its directional quadtree (Open PGL's `DQT`).
    QuadTree,
}

/// What a [`Guide`] is built with, beyond Open PGL's defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Arguments {
    /// The distribution fitted in every region (default [`Directional::ParallaxAwareVmm`]).
    pub directional: Directional,
    /// A kd-tree leaf splits once it holds more samples than this (default 32000, Open PGL's).
    pub max_samples_per_leaf: usize,
}

impl Default for Arguments {
    fn default() -> Self {
        Self {
            directional: Directional::ParallaxAwareVmm,
            max_samples_per_leaf: ffi::TREE_MAX_SAMPLE_PER_LEAF,
        }
    }
}

/// Distinguishes fields in the thread-local pool of distributions.
static NEXT_FIELD_ID: AtomicU64 = AtomicU64::new(1);

/// An Open PGL field with its device and sample storage: what the demo trains and renders with.
pub struct Guide {
    device: *mut c_void,
    field: *mut c_void,
    storage: *mut c_void,
    id: u64,
    cosine_product: bool,
}

// SAFETY: Open PGL's field and sample storage are made for render threads: initialising a
// sampling distribution from the field and adding samples to the storage (a TBB concurrent
// vector) are safe from any number of threads at once; the only mutation of the field,
// `update`, takes `&mut self`, so no thread can read it then. The pointers are owned by `Guide`
// and released once, in `Drop`.
unsafe impl Send for Guide {}
// SAFETY: as above; every `&self` method calls only the thread-safe part of the C API.
unsafe impl Sync for Guide {}

impl Guide {
    /// A new field over `bounds`, with Open PGL's default arguments (a kd-tree of
    /// parallax-aware VMMs, at most 32000 samples per leaf), deterministic so that a seed
    /// reproduces a render; `threads` is the size of the thread pool its update may use.
    /// With `cosine_product`, every vertex's distribution is multiplied by the clamped cosine
    /// around the shading normal (Open PGL's `ApplyCosineProduct`).
    ///
    /// # Errors
    ///
    /// A message when Open PGL cannot create its device, field or sample storage.
    pub fn new(bounds: Aabb, cosine_product: bool, threads: usize) -> Result<Guide, String> {
        Self::with_arguments(bounds, Arguments::default(), cosine_product, threads)
    }

    /// [`new`](Self::new) with another directional distribution or leaf size.
    ///
    /// # Errors
    ///
    /// As [`new`](Self::new).
    pub fn with_arguments(
        bounds: Aabb,
        chosen: Arguments,
        cosine_product: bool,
        threads: usize,
    ) -> Result<Guide, String> {
        let device_type = if cfg!(target_arch = "x86_64") && avx2() {
            ffi::DEVICE_TYPE_CPU_8
        } else {
            ffi::DEVICE_TYPE_CPU_4
        };
        let directional = match chosen.directional {
            Directional::ParallaxAwareVmm => ffi::DIRECTIONAL_DISTRIBUTION_PARALLAX_AWARE_VMM,
            Directional::Vmm => ffi::DIRECTIONAL_DISTRIBUTION_VMM,
            Directional::QuadTree => ffi::DIRECTIONAL_DISTRIBUTION_QUADTREE,
        };
        // SAFETY: plain constructor calls; every returned pointer is checked before use, and
        // what `pglFieldArgumentsSetDefaults` fills in is handed to the field it configures.
        // Its spatial arguments are the kd-tree's, as the spatial type asked for says.
        unsafe {
            let device = ffi::pglNewDevice(device_type, threads);
            if device.is_null() {
                return Err("Open PGL could not create its device".into());
            }
            let mut arguments = ffi::FieldArguments {
                spatial_structure_type: ffi::SPATIAL_STRUCTURE_KDTREE,
                spatial_structure_arguments: std::ptr::null_mut(),
                directional_distribution_type: directional,
                directional_distribution_arguments: std::ptr::null_mut(),
                deterministic: true,
                fit_regions: true,
            };
            // The directional defaults stay those of a 32000-sample leaf (the VMM's split and
            // merge counts derive from it); only the kd-tree's leaf size is set apart.
            ffi::pglFieldArgumentsSetDefaults(
                &mut arguments,
                ffi::SPATIAL_STRUCTURE_KDTREE,
                directional,
                true,
                ffi::TREE_MAX_SAMPLE_PER_LEAF,
            );
            let kd_tree = arguments
                .spatial_structure_arguments
                .cast::<ffi::KdTreeArguments>();
            if kd_tree.is_null() {
                ffi::pglReleaseDevice(device);
                return Err("Open PGL set no kd-tree arguments".into());
            }
            (*kd_tree).max_samples = chosen.max_samples_per_leaf.max(1);
            let field = ffi::pglDeviceNewField(device, arguments);
            if field.is_null() {
                ffi::pglReleaseDevice(device);
                return Err("Open PGL could not create its field".into());
            }
            ffi::pglFieldSetSceneBounds(
                field,
                ffi::Box3f {
                    lower: vec3f(bounds.min),
                    upper: vec3f(bounds.max),
                },
            );
            let storage = ffi::pglNewSampleStorage();
            if storage.is_null() {
                ffi::pglReleaseField(field);
                ffi::pglReleaseDevice(device);
                return Err("Open PGL could not create its sample storage".into());
            }
            Ok(Guide {
                device,
                field,
                storage,
                id: NEXT_FIELD_ID.fetch_add(1, Ordering::Relaxed),
                cosine_product,
            })
        }
    }

    /// Training updates so far.
    pub fn iteration(&self) -> usize {
        // SAFETY: a read of the field, which `&self` keeps alive and unchanged.
        unsafe { ffi::pglFieldGetIteration(self.field) }
    }

    /// Samples waiting for the next update.
    pub fn pending_samples(&self) -> usize {
        // SAFETY: a read of the storage, which `&self` keeps alive.
        unsafe { ffi::pglSampleStorageGetSizeSurface(self.storage) }
    }

    /// Records the vertices of one finished path (or any batch of samples); callable from
    /// every render thread at once. Vertices with zero radiance go in as Open PGL's zero-value
    /// samples, non-finite or negative values and non-positive pdfs are dropped (Open PGL
    /// asserts on them).
    pub fn record(&self, vertices: &[Record]) {
        for path in vertices.chunks(crate::integrator::MAX_DEPTH) {
            self.record_path(path);
        }
    }

    /// [`record`](Self::record) of at most `MAX_DEPTH` vertices, staged on the stack.
    fn record_path(&self, vertices: &[Record]) {
        const MAX: usize = crate::integrator::MAX_DEPTH;
        let mut samples = [ffi::SampleData::default(); MAX];
        let mut zeros = [ffi::ZeroValueSampleData::default(); MAX];
        let (mut n, mut z) = (0, 0);
        for v in vertices.iter().take(MAX) {
            let valid = v.pdf.is_finite() && v.pdf > 0.0 && v.radiance.is_finite();
            let finite = [v.position, v.direction, v.outgoing]
                .iter()
                .all(|x| x.is_finite());
            let reflected = v.reflected.is_finite() && v.reflected >= 0.0;
            if !valid || v.radiance < 0.0 || !finite || !reflected {
                continue;
            }
            if v.radiance > 0.0 && v.distance.is_finite() && v.distance > 0.0 {
                let grey = |l: f32| vec3f(Vec3::splat(l));
                samples[n] = ffi::SampleData {
                    position: vec3f(v.position),
                    direction: vec3f(v.direction),
                    weight: v.radiance / v.pdf,
                    // The recorded radiance carries its MIS weights already.
                    radiance_in: grey(v.radiance),
                    radiance_in_mis_weight: 1.0,
                    pdf: v.pdf,
                    distance: v.distance,
                    flags: if v.volume {
                        ffi::SAMPLE_INSIDE_VOLUME
                    } else {
                        0
                    },
                    direction_out: vec3f(v.outgoing),
                    radiance_out: grey(v.reflected),
                };
                n += 1;
            } else if v.radiance == 0.0 {
                zeros[z] = ffi::ZeroValueSampleData {
                    position: vec3f(v.position),
                    direction: vec3f(v.direction),
                    direction_out: vec3f(v.outgoing),
                    volume: v.volume,
                };
                z += 1;
            }
        }
        // SAFETY: the arrays hold `n` and `z` initialised samples of the C layout; the storage
        // is a concurrent vector that copies them.
        unsafe {
            if n > 0 {
                ffi::pglSampleStorageAddSamples(self.storage, samples.as_ptr(), n);
            }
            if z > 0 {
                ffi::pglSampleStorageAddZeroValueSamples(self.storage, zeros.as_ptr(), z);
            }
        }
    }

    /// Fits the field to the samples recorded since the last update, then clears them (what
    /// Cycles does between its training passes).
    pub fn update(&mut self) {
        // SAFETY: `&mut self`: no thread holds a distribution or records meanwhile.
        unsafe {
            ffi::pglFieldUpdate(self.field, self.storage);
            ffi::pglSampleStorageClear(self.storage);
        }
    }

    /// The field's distribution at `position`, for a surface with shading normal `normal`
    /// (used by the cosine product). `lookup` is the uniform random number Open PGL's
    /// stochastic spatial lookup draws with. `None` where the field has no distribution yet
    /// (before the first update): the vertex then samples its BSDF alone.
    pub fn distribution(&self, position: Vec3, normal: Vec3, lookup: f32) -> Option<Distribution> {
        let distribution = self.initialised(Kind::Surface, position, lookup)?;
        if self.cosine_product && normal.is_finite() && normal != Vec3::ZERO {
            let ptr = distribution.ptr();
            // SAFETY: an initialised surface distribution of this thread.
            unsafe {
                if ffi::pglSurfaceSamplingDistributionSupportsApplyCosineProduct(ptr) {
                    ffi::pglSurfaceSamplingDistributionApplyCosineProduct(
                        ptr,
                        vec3f(normal.normalize()),
                    );
                }
            }
        }
        Some(distribution)
    }

    /// The volume field's distribution at `position` inside a medium, as its product with the
    /// Henyey–Greenstein phase function of mean cosine `g` about `travel`, the direction the
    /// path arrived along (Open PGL's `ApplySingleLobeHenyeyGreensteinProduct`, as Cycles
    /// calls it with the ray's direction). `None` where the field has no distribution yet.
    pub fn volume_distribution(
        &self,
        position: Vec3,
        travel: Vec3,
        g: f32,
        lookup: f32,
    ) -> Option<Distribution> {
        let distribution = self.initialised(Kind::Volume, position, lookup)?;
        if travel.is_finite() && travel != Vec3::ZERO && g.is_finite() {
            let ptr = distribution.ptr();
            // SAFETY: an initialised volume distribution of this thread.
            unsafe {
                if ffi::pglVolumeSamplingDistributionSupportsApplySingleLobeHenyeyGreensteinProduct(
                    ptr,
                ) {
                    ffi::pglVolumeSamplingDistributionApplySingleLobeHenyeyGreensteinProduct(
                        ptr,
                        vec3f(travel.normalize()),
                        g,
                    );
                }
            }
        }
        Some(distribution)
    }

    /// A distribution object of `kind` from the thread's pool (or a new one), initialised at
    /// `position`.
    fn initialised(&self, kind: Kind, position: Vec3, lookup: f32) -> Option<Distribution> {
        let raw = POOL.with(|pool| {
            let mut pool = pool.borrow_mut();
            // Distributions of a field that is gone are released when the next one is asked.
            pool.retain(|d| d.field_id == self.id);
            let i = pool.iter().rposition(|d| d.kind == kind)?;
            Some(pool.swap_remove(i))
        });
        let raw = match raw {
            Some(raw) => raw,
            None => {
                // SAFETY: `&self` keeps the field alive; the result is checked.
                let ptr = unsafe {
                    match kind {
                        Kind::Surface => ffi::pglFieldNewSurfaceSamplingDistribution(self.field),
                        Kind::Volume => ffi::pglFieldNewVolumeSamplingDistribution(self.field),
                    }
                };
                if ptr.is_null() {
                    return None;
                }
                RawDistribution {
                    ptr,
                    field_id: self.id,
                    kind,
                }
            }
        };
        let mut sample1d = lookup.clamp(0.0, 1.0 - f32::EPSILON);
        // SAFETY: the distribution was made by this field (the pool is keyed by field) for
        // this kind, and `&self` keeps the field unchanged while it is initialised and used.
        let ok = unsafe {
            let at = vec3f(position);
            match kind {
                Kind::Surface => ffi::pglFieldInitSurfaceSamplingDistribution(
                    self.field,
                    raw.ptr,
                    at,
                    &mut sample1d,
                ),
                Kind::Volume => ffi::pglFieldInitVolumeSamplingDistribution(
                    self.field,
                    raw.ptr,
                    at,
                    &mut sample1d,
                ),
            }
        };
        let distribution = Distribution { raw: Some(raw) };
        ok.then_some(distribution)
    }
}

impl Drop for Guide {
    fn drop(&mut self) {
        // SAFETY: the pointers were created in `new` and are released once, field before the
        // device it belongs to.
        unsafe {
            ffi::pglReleaseSampleStorage(self.storage);
            ffi::pglReleaseField(self.field);
            ffi::pglReleaseDevice(self.device);
        }
    }
}

fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Which of Open PGL's distribution objects: a surface's or a volume's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Surface,
    Volume,
}

/// A sampling distribution object, owned by one thread.
struct RawDistribution {
    ptr: *mut c_void,
    field_id: u64,
    kind: Kind,
}

impl Drop for RawDistribution {
    fn drop(&mut self) {
        // SAFETY: created by `pglFieldNew{Surface,Volume}SamplingDistribution` as `kind` says,
        // released once here; it owns its data and does not reach back into the field.
        unsafe {
            match self.kind {
                Kind::Surface => ffi::pglReleaseSurfaceSamplingDistribution(self.ptr),
                Kind::Volume => ffi::pglReleaseVolumeSamplingDistribution(self.ptr),
            }
        }
    }
}

thread_local! {
    /// The render thread's distribution objects, reused from vertex to vertex.
    static POOL: RefCell<Vec<RawDistribution>> = const { RefCell::new(Vec::new()) };
}

/// Open PGL's directional distribution at one vertex: what the guide samples there. Returned to
/// its thread's pool when dropped.
pub struct Distribution {
    raw: Option<RawDistribution>,
}

impl Distribution {
    fn ptr(&self) -> *mut c_void {
        self.raw.as_ref().map_or(std::ptr::null_mut(), |r| r.ptr)
    }

    fn kind(&self) -> Kind {
        self.raw.as_ref().map_or(Kind::Surface, |r| r.kind)
    }

    /// Draws a world-space unit direction from two uniform numbers.
    pub fn sample(&self, u: Vec2) -> Vec3 {
        let u = ffi::Vec2f { x: u.x, y: u.y };
        // SAFETY: an initialised distribution of its kind, used by the thread that initialised
        // it (the type is neither `Send` nor `Sync`).
        let d = unsafe {
            match self.kind() {
                Kind::Surface => ffi::pglSurfaceSamplingDistributionSample(self.ptr(), u),
                Kind::Volume => ffi::pglVolumeSamplingDistributionSample(self.ptr(), u),
            }
        };
        Vec3::new(d.x, d.y, d.z)
    }

    /// The density of `direction` (solid angle), as `sample` draws it.
    pub fn pdf(&self, direction: Vec3) -> f32 {
        let d = vec3f(direction);
        // SAFETY: as in `sample`.
        unsafe {
            match self.kind() {
                Kind::Surface => ffi::pglSurfaceSamplingDistributionPDF(self.ptr(), d),
                Kind::Volume => ffi::pglVolumeSamplingDistributionPDF(self.ptr(), d),
            }
        }
    }

    /// The luminance of the radiance the region's cache estimates leaves it toward `direction`
    /// (Open PGL's `OutgoingRadiance`: a histogram over outgoing directions of what its samples
    /// reflected).
    pub fn outgoing_radiance(&self, direction: Vec3) -> f32 {
        let d = vec3f(direction);
        // SAFETY: as in `sample`.
        let l = unsafe {
            match self.kind() {
                Kind::Surface => ffi::pglSurfaceSamplingDistributionOutgoingRadiance(self.ptr(), d),
                Kind::Volume => ffi::pglVolumeSamplingDistributionOutgoingRadiance(self.ptr(), d),
            }
        };
        crate::material::luminance(Vec3::new(l.x, l.y, l.z))
    }
}

impl Drop for Distribution {
    fn drop(&mut self) {
        if let Some(raw) = self.raw.take() {
            // A thread being torn down has no pool left; the object is then released.
            let _ = POOL.try_with(|pool| pool.borrow_mut().push(raw));
        }
    }
}

/// The probability of sampling Open PGL's guide instead of the BSDF (or the phase function): ½,
/// Cycles' default surface and volume guiding probabilities (the peer learns none).
pub const PEER_GUIDE_PROBABILITY: f32 = 0.5;

impl Backend for Guide {
    type Vertex<'a> = Distribution;

    fn at(&self, position: Vec3, normal: Vec3, lookup: f32) -> Option<Distribution> {
        self.distribution(position, normal, lookup)
    }

    fn in_medium(&self, position: Vec3, travel: Vec3, g: f32, lookup: f32) -> Option<Distribution> {
        self.volume_distribution(position, travel, g, lookup)
    }

    fn draws_lookup(&self) -> bool {
        true
    }

    fn record(&self, sample: &sdguide::Sample, segment: Segment) {
        let reflected = sample.mixture.map_or(0.0, |m| m.integrand / sample.pdf);
        Guide::record(
            self,
            &[Record {
                position: sample.position,
                direction: sample.direction,
                radiance: sample.value,
                pdf: sample.pdf,
                distance: segment.distance,
                outgoing: segment.outgoing,
                reflected,
                volume: sample.volume,
            }],
        );
    }

    fn refine(&mut self) {
        self.update();
    }
}

impl VertexGuide for Distribution {
    fn sample(&self, u: Vec2) -> (Vec3, Option<f32>) {
        (Distribution::sample(self, u), None)
    }

    fn pdf(&self, direction: Vec3) -> f32 {
        Distribution::pdf(self, direction)
    }

    fn guide_probability(&self) -> f32 {
        PEER_GUIDE_PROBABILITY
    }

    fn outgoing_radiance(&self, direction: Vec3) -> Option<f32> {
        Some(Distribution::outgoing_radiance(self, direction))
    }
}

#[cfg(test)]
mod tests;
