//! The path recorder handle: a render thread's camera sample, vertex by vertex, and the
//! training samples and continuations it yields (see the Rust `PathRecorder`).

use crate::error::{Failure, fail, guard, put, sdg_status};
use crate::field::{destroy, sdg_field};
use crate::lock::shared;
use crate::types::{SDG_SAMPLE_MIXTURE, SDG_SAMPLE_NORMAL, SDG_SAMPLE_VOLUME, sdg_vec3};
use sdguide::{PathRecorder, PathVertex, VertexId};

/// A path recorder (opaque): one per render thread, reused for every camera sample. Create
/// with `sdg_path_create`; destroy with `sdg_path_destroy`. Not for two threads at once.
pub struct sdg_path {
    inner: PathRecorder,
}

/// A scattering vertex as the renderer pushes it (see `sdg_path_push`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct sdg_path_vertex {
    /// The vertex.
    pub position: sdg_vec3,
    /// Its shading normal, facing the side the path arrived from; read with
    /// `SDG_SAMPLE_NORMAL` in `flags`.
    pub normal: sdg_vec3,
    /// The direction drawn (any length).
    pub direction: sdg_vec3,
    /// `f·|cos θ|` toward `direction`, per channel (0 below the surface).
    pub bsdf: sdg_vec3,
    /// The density `direction` was drawn with: the mixture's `q`.
    pub pdf: f32,
    /// The BSDF sampling pdf of `direction`; with `guide_pdf`, read with `SDG_SAMPLE_MIXTURE`
    /// in `flags`.
    pub bsdf_pdf: f32,
    /// The guide's pdf of `direction` (the product's where the renderer samples it).
    pub guide_pdf: f32,
    /// `SDG_SAMPLE_NORMAL`, `SDG_SAMPLE_MIXTURE`, `SDG_SAMPLE_VOLUME` (a medium vertex:
    /// `bsdf` is the phase function's value, `bsdf_pdf` its pdf), or'ed; 0 for none.
    pub flags: u32,
}

/// The recorder's counts of bad input (see the Rust `PathRecorderStats`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct sdg_path_recorder_stats {
    /// Paths finished.
    pub paths: u64,
    /// Vertices pushed with bad input: kept, recording and passing on nothing.
    pub bad_vertices: u64,
    /// Radiance, costs, probabilities, factors or handles that were ignored.
    pub bad_values: u64,
    /// Vertices refused past the recorder's capacity.
    pub dropped_vertices: u64,
    /// Paths that overflowed: they record nothing.
    pub truncated_paths: u64,
}

impl sdg_path_vertex {
    fn to_rust(self) -> PathVertex {
        let mut v = PathVertex::new(
            self.position.into(),
            self.direction.into(),
            self.bsdf.into(),
            self.pdf,
        );
        if self.flags & SDG_SAMPLE_NORMAL != 0 {
            v = v.with_normal(self.normal.into());
        }
        if self.flags & SDG_SAMPLE_MIXTURE != 0 {
            v = v.with_mixture(self.bsdf_pdf, self.guide_pdf);
        }
        if self.flags & SDG_SAMPLE_VOLUME != 0 {
            v = v.in_volume();
        }
        v
    }
}

/// The recorder behind a handle, or a `NullPointer` failure.
///
/// # Safety
/// `path` must be null or a live handle that no other thread is using.
unsafe fn recorder<'a>(path: *mut sdg_path) -> Result<&'a mut PathRecorder, Failure> {
    // SAFETY: the caller's contract; null is checked here.
    match unsafe { path.as_mut() } {
        Some(p) => Ok(&mut p.inner),
        None => fail(sdg_status::NullPointer, "`path` is null"),
    }
}

/// Runs `f` on the recorder behind `path`.
///
/// # Safety
/// As [`recorder`].
unsafe fn with(path: *mut sdg_path, f: impl FnOnce(&mut PathRecorder)) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        f(unsafe { recorder(path) }?);
        Ok(sdg_status::Ok)
    })
}

/// Creates a recorder holding up to `max_vertices` vertices per camera sample (0: the
/// library's default, 4096), and stores its handle in `*out`.
///
/// # Safety
/// `out` must be null or valid for writing a pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_create(max_vertices: u32, out: *mut *mut sdg_path) -> sdg_status {
    guard(|| {
        let inner = match max_vertices {
            0 => PathRecorder::new(),
            n => PathRecorder::with_max_vertices(n as usize),
        };
        let handle = Box::into_raw(Box::new(sdg_path { inner }));
        // SAFETY: the caller's contract.
        if let Err(e) = unsafe { put(out, "out", handle) } {
            // SAFETY: made just above, never shared.
            unsafe { destroy(handle) };
            return Err(e);
        }
        Ok(sdg_status::Ok)
    })
}

/// Destroys a recorder. Null is ignored.
///
/// # Safety
/// `path` must be null or a handle from `sdg_path_create`, not yet destroyed, that no other
/// thread is using.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_destroy(path: *mut sdg_path) {
    // SAFETY: created by `Box::into_raw` in `sdg_path_create`, destroyed once.
    unsafe { destroy(path) }
}

/// Starts a new camera sample and stores the handle of its camera ray in `*camera`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses; `camera` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_start(path: *mut sdg_path, camera: *mut u32) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let id = unsafe { recorder(path) }?.start();
        // SAFETY: the caller's contract.
        unsafe { put(camera, "camera", id.index() as u32) }?;
        Ok(sdg_status::Ok)
    })
}

/// Radiance `radiance` arriving at vertex `at` along its direction: emission its ray hit (with
/// its MIS weight), or a next-event contribution at the vertex its ray reached. Negative or
/// non-finite values are ignored and counted.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_add_radiance(
    path: *mut sdg_path,
    at: u32,
    radiance: sdg_vec3,
) -> sdg_status {
    // SAFETY: the caller's contract.
    unsafe {
        with(path, |p| {
            p.add_radiance(VertexId::from_index(at), radiance.into())
        })
    }
}

/// A cost (rays, say) spent tracing for vertex `at`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_add_cost(path: *mut sdg_path, at: u32, cost: f32) -> sdg_status {
    // SAFETY: the caller's contract.
    unsafe { with(path, |p| p.add_cost(VertexId::from_index(at), cost)) }
}

/// A direction drawn at the vertex the ray of `from` reached; stores its handle in `*out`. A
/// vertex with bad input is kept but records nothing; past the capacity the handle is a sink.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses; `vertex` null or valid; `out`
/// null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_push(
    path: *mut sdg_path,
    from: u32,
    vertex: *const sdg_path_vertex,
    out: *mut u32,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let v = unsafe { crate::error::arg(vertex, "vertex") }?.to_rust();
        // SAFETY: the caller's contract.
        let id = unsafe { recorder(path) }?.push(VertexId::from_index(from), v);
        // SAFETY: the caller's contract.
        unsafe { put(out, "out", id.index() as u32) }?;
        Ok(sdg_status::Ok)
    })
}

/// Russian roulette on the path along `at`: it went on with `probability` if `survived`
/// (non-zero), else it ended; what arrives at `at` afterwards weighs `1/probability`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_roulette(
    path: *mut sdg_path,
    at: u32,
    probability: f32,
    survived: u32,
) -> sdg_status {
    // SAFETY: the caller's contract.
    unsafe {
        with(path, |p| {
            p.roulette(VertexId::from_index(at), probability, survived != 0)
        })
    }
}

/// Roulette or splitting at the vertex the ray of `at` reached: `traced` continuations for
/// `factor`, each pushed afterwards weighing `1/factor`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_split(
    path: *mut sdg_path,
    at: u32,
    factor: f32,
    traced: u32,
) -> sdg_status {
    // SAFETY: the caller's contract.
    unsafe { with(path, |p| p.split(VertexId::from_index(at), factor, traced)) }
}

/// Ends the camera sample and stores its estimate (the radiance along the camera ray) in
/// `*estimate`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses; `estimate` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_finish(
    path: *mut sdg_path,
    estimate: *mut sdg_vec3,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let l = unsafe { recorder(path) }?.finish();
        // SAFETY: the caller's contract.
        unsafe { put(estimate, "estimate", l.into()) }?;
        Ok(sdg_status::Ok)
    })
}

/// Records the finished camera sample into `field` (every vertex's sample and continuation)
/// and stores how many vertices it recorded in `*recorded` (which may be null). Takes the
/// field's lock shared, like `sdg_field_record`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses; `field` null or valid;
/// `recorded` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_record(
    path: *mut sdg_path,
    field: *const sdg_field,
    recorded: *mut usize,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let (p, f) = unsafe { (recorder(path)?, crate::error::arg(field, "field")?) };
        let n = p.record(&shared(&f.inner));
        if !recorded.is_null() {
            // SAFETY: non-null and writable by the caller's contract.
            unsafe { recorded.write(n) };
        }
        Ok(sdg_status::Ok)
    })
}

/// Stores the recorder's counts of bad input in `*out`.
///
/// # Safety
/// `path` must be null or a live handle no other thread uses; `out` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn sdg_path_stats(
    path: *mut sdg_path,
    out: *mut sdg_path_recorder_stats,
) -> sdg_status {
    guard(|| {
        // SAFETY: the caller's contract.
        let s = unsafe { recorder(path) }?.stats();
        let stats = sdg_path_recorder_stats {
            paths: s.paths,
            bad_vertices: s.bad_vertices,
            bad_values: s.bad_values,
            dropped_vertices: s.dropped_vertices,
            truncated_paths: s.truncated_paths,
        };
        // SAFETY: the caller's contract.
        unsafe { put(out, "out", stats) }?;
        Ok(sdg_status::Ok)
    })
}
