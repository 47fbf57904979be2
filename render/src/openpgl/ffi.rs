//! The part of Open PGL 0.7.1's C API the wrapper calls: its data layouts and functions.
use std::ffi::c_void;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct Vec3f {
    pub x: f32,
    pub y: f32,
    pub z: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct Vec2f {
    pub x: f32,
    pub y: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct Box3f {
    pub lower: Vec3f,
    pub upper: Vec3f,
}

/// `PGLSampleData` with the radiance-cache fields (the build turns them on; no compression).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct SampleData {
    pub position: Vec3f,
    pub direction: Vec3f,
    pub weight: f32,
    pub radiance_in: Vec3f,
    pub radiance_in_mis_weight: f32,
    pub pdf: f32,
    pub distance: f32,
    pub flags: u32,
    pub direction_out: Vec3f,
    pub radiance_out: Vec3f,
}

/// `PGLZeroValueSampleData` with the radiance-cache field.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct ZeroValueSampleData {
    pub position: Vec3f,
    pub direction: Vec3f,
    pub direction_out: Vec3f,
    pub volume: bool,
}

/// `PGLFieldArguments`.
#[repr(C)]
pub struct FieldArguments {
    pub spatial_structure_type: i32,
    pub spatial_structure_arguments: *mut c_void,
    pub directional_distribution_type: i32,
    pub directional_distribution_arguments: *mut c_void,
    pub deterministic: bool,
    pub fit_regions: bool,
}

pub const SPATIAL_STRUCTURE_KDTREE: i32 = 0;

/// `PGLKDTreeArguments`, what `spatial_structure_arguments` points to for the kd-tree.
#[repr(C)]
pub struct KdTreeArguments {
    pub knn_lookup: bool,
    pub is_knn_lookup: bool,
    pub min_samples: usize,
    pub max_samples: usize,
    pub max_depth: usize,
}
pub const DIRECTIONAL_DISTRIBUTION_PARALLAX_AWARE_VMM: i32 = 0;
pub const DIRECTIONAL_DISTRIBUTION_QUADTREE: i32 = 1;
pub const DIRECTIONAL_DISTRIBUTION_VMM: i32 = 2;
pub const DEVICE_TYPE_CPU_4: i32 = 0;
pub const DEVICE_TYPE_CPU_8: i32 = 1;
/// `PGL_TREE_MAX_SAMPLE_PER_LEAF`, the library's default.
pub const TREE_MAX_SAMPLE_PER_LEAF: usize = 32000;
/// `PGLSampleData::flags`: the sample lies inside a participating medium.
pub const SAMPLE_INSIDE_VOLUME: u32 = 1;

unsafe extern "C" {
    pub fn pglNewDevice(device_type: i32, num_threads: usize) -> *mut c_void;
    pub fn pglReleaseDevice(device: *mut c_void);
    pub fn pglFieldArgumentsSetDefaults(
        arguments: *mut FieldArguments,
        spatial_type: i32,
        directional_type: i32,
        deterministic: bool,
        max_samples_per_leaf: usize,
    );
    pub fn pglDeviceNewField(device: *mut c_void, arguments: FieldArguments) -> *mut c_void;
    pub fn pglReleaseField(field: *mut c_void);
    pub fn pglFieldSetSceneBounds(field: *mut c_void, bounds: Box3f);
    pub fn pglFieldUpdate(field: *mut c_void, storage: *mut c_void);
    pub fn pglFieldGetIteration(field: *mut c_void) -> usize;
    pub fn pglFieldNewSurfaceSamplingDistribution(field: *mut c_void) -> *mut c_void;
    pub fn pglFieldInitSurfaceSamplingDistribution(
        field: *mut c_void,
        distribution: *mut c_void,
        position: Vec3f,
        sample1d: *mut f32,
    ) -> bool;
    pub fn pglReleaseSurfaceSamplingDistribution(distribution: *mut c_void);
    pub fn pglSurfaceSamplingDistributionApplyCosineProduct(
        distribution: *mut c_void,
        normal: Vec3f,
    );
    pub fn pglSurfaceSamplingDistributionSupportsApplyCosineProduct(
        distribution: *mut c_void,
    ) -> bool;
    pub fn pglSurfaceSamplingDistributionSample(distribution: *mut c_void, sample: Vec2f) -> Vec3f;
    pub fn pglFieldNewVolumeSamplingDistribution(field: *mut c_void) -> *mut c_void;
    pub fn pglFieldInitVolumeSamplingDistribution(
        field: *mut c_void,
        distribution: *mut c_void,
        position: Vec3f,
        sample1d: *mut f32,
    ) -> bool;
    pub fn pglReleaseVolumeSamplingDistribution(distribution: *mut c_void);
    pub fn pglVolumeSamplingDistributionApplySingleLobeHenyeyGreensteinProduct(
        distribution: *mut c_void,
        direction: Vec3f,
        mean_cosine: f32,
    );
    pub fn pglVolumeSamplingDistributionSupportsApplySingleLobeHenyeyGreensteinProduct(
        distribution: *mut c_void,
    ) -> bool;
    pub fn pglVolumeSamplingDistributionSample(distribution: *mut c_void, sample: Vec2f) -> Vec3f;
    pub fn pglVolumeSamplingDistributionPDF(distribution: *mut c_void, direction: Vec3f) -> f32;
    pub fn pglSurfaceSamplingDistributionPDF(distribution: *mut c_void, direction: Vec3f) -> f32;
    pub fn pglSurfaceSamplingDistributionOutgoingRadiance(
        distribution: *mut c_void,
        direction: Vec3f,
    ) -> Vec3f;
    pub fn pglVolumeSamplingDistributionOutgoingRadiance(
        distribution: *mut c_void,
        direction: Vec3f,
    ) -> Vec3f;
    pub fn pglNewSampleStorage() -> *mut c_void;
    pub fn pglReleaseSampleStorage(storage: *mut c_void);
    pub fn pglSampleStorageAddSamples(
        storage: *mut c_void,
        samples: *const SampleData,
        count: usize,
    );
    pub fn pglSampleStorageAddZeroValueSamples(
        storage: *mut c_void,
        samples: *const ZeroValueSampleData,
        count: usize,
    );
    pub fn pglSampleStorageClear(storage: *mut c_void);
    pub fn pglSampleStorageGetSizeSurface(storage: *mut c_void) -> usize;
}
