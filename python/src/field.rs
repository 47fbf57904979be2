//! `sdguide.GuidingField`: the library's field, with its queries and `record` over numpy
//! arrays (one lane per path vertex), and its cache and merge.
//!
//! Every batch call checks its arrays, then releases the GIL while the library's batch calls
//! run the lanes in parallel on rayon's pool; each lane is the one-vertex call, to the bit.

use crate::arrays::{Input, all_or_none, input, optional, vec3_output};
use crate::errors::{cache_error, config_error, merge_error};
use crate::image::{PyImageStatistics, parse_mode};
use glam::Vec3;
use numpy::{PyArray1, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use rayon::prelude::*;
use sdguide::{Aabb, GuidingConfig, Sample};

/// The spellings serde gives the config's enums; a keyword argument may use any case and
/// `-`/`_` (`"l2-mixture"`, `"deferred_box"`).
const VARIANTS: [&str; 11] = [
    "L1",
    "L2",
    "L2Mixture",
    "FluxShare",
    "VarianceGain",
    "Nearest",
    "Stochastic",
    "Box",
    "DeferredBox",
    "Count",
    "Gain",
];

fn variant(text: &str) -> String {
    let squash = |s: &str| s.replace(['-', '_'], "").to_ascii_lowercase();
    let key = squash(text);
    VARIANTS
        .iter()
        .find(|v| squash(v) == key)
        .map_or_else(|| text.to_string(), |v| v.to_string())
}

/// The keyword arguments as a `GuidingConfig`: unknown keys, wrong types and values out of
/// range are `ConfigError`s.
fn config_from(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<GuidingConfig> {
    let mut map = serde_json::Map::new();
    for (key, value) in kwargs.into_iter().flatten() {
        let key: String = key.extract()?;
        let json = if value.is_none() {
            serde_json::Value::Null
        } else if let Ok(b) = value.cast::<pyo3::types::PyBool>() {
            serde_json::Value::Bool(b.is_true())
        } else if let Ok(i) = value.extract::<u64>() {
            serde_json::Value::from(i)
        } else if let Ok(x) = value.extract::<f64>() {
            serde_json::Number::from_f64(x)
                .map(serde_json::Value::Number)
                .ok_or_else(|| config_error(format!("`{key}` is {x}, not a finite number")))?
        } else if let Ok(s) = value.extract::<String>() {
            serde_json::Value::String(variant(&s))
        } else {
            return Err(config_error(format!(
                "`{key}` has type {}: a number, a bool, a string or None is expected",
                value.get_type().name()?
            )));
        };
        map.insert(key, json);
    }
    let config: GuidingConfig = serde_json::from_value(serde_json::Value::Object(map))
        .map_err(|e| config_error(e.to_string()))?;
    Ok(config)
}

/// Something serde can write, as the Python object `json.loads` makes of it.
fn to_python<'py>(py: Python<'py>, value: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| PyValueError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// What `sample` returns: the directions `(N, 3)` and their pdfs `(N,)`.
type Drawn<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<f32>>);

/// A guiding field over an axis-aligned box of the scene: record samples, refine between
/// passes, query `sample`/`pdf`/`guide_probability` — each over arrays of lanes.
#[pyclass(name = "GuidingField", module = "sdguide")]
pub struct PyGuidingField {
    pub(crate) inner: sdguide::GuidingField,
}

fn vec3(v: [f32; 3]) -> Vec3 {
    Vec3::from_array(v)
}

/// `N` zeroed vectors, as the `3·N` numbers of an `(N, 3)` array.
fn zeros3(n: usize) -> Vec<f32> {
    vec![0.0; 3 * n]
}

#[pymethods]
impl PyGuidingField {
    #[new]
    #[pyo3(signature = (lower, upper, **config))]
    fn new(lower: [f32; 3], upper: [f32; 3], config: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let config = config_from(config)?;
        let inner = sdguide::GuidingField::new(Aabb::new(vec3(lower), vec3(upper)), config)
            .map_err(|e| config_error(e.to_string()))?;
        Ok(Self { inner })
    }

    /// Draws one direction per lane from the guide at `positions[i]` (with `normals`, its
    /// product with the clamped cosine about `normals[i]`) with the numbers `u[i]` in [0, 1)²:
    /// returns `(directions (N, 3), pdfs (N,))`, unit directions and their solid-angle pdfs.
    #[pyo3(signature = (positions, u, normals = None))]
    fn sample<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        u: &Bound<'py, PyAny>,
        normals: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Drawn<'py>> {
        let positions: Input<f32> = input(positions, "positions", None, Some(3))?;
        let n = positions.vec3s().len();
        let u: Input<f32> = input(u, "u", Some(n), Some(2))?;
        let normals: Option<Input<f32>> = optional(normals, "normals", n, Some(3))?;
        let (p, uv, nv) = (
            positions.vec3s(),
            u.vec2s(),
            normals.as_ref().map(|a| a.vec3s()),
        );
        let field = &self.inner;
        let (directions, pdfs) = py
            .detach(|| {
                let mut directions = zeros3(n);
                let mut pdfs = vec![0.0f32; n];
                field
                    .sample_batch(
                        p,
                        nv,
                        uv,
                        bytemuck::cast_slice_mut(&mut directions),
                        &mut pdfs,
                    )
                    .map(|()| (directions, pdfs))
            })
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok((vec3_output(py, directions)?, PyArray1::from_vec(py, pdfs)))
    }

    /// The solid-angle pdf with which `sample` draws `directions[i]` at `positions[i]` (with
    /// `normals`, the product's pdf): `(N,)`.
    #[pyo3(signature = (positions, directions, normals = None))]
    fn pdf<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        normals: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let positions: Input<f32> = input(positions, "positions", None, Some(3))?;
        let n = positions.vec3s().len();
        let directions: Input<f32> = input(directions, "directions", Some(n), Some(3))?;
        let normals: Option<Input<f32>> = optional(normals, "normals", n, Some(3))?;
        let (p, d, nv) = (
            positions.vec3s(),
            directions.vec3s(),
            normals.as_ref().map(|a| a.vec3s()),
        );
        let field = &self.inner;
        let pdfs = py
            .detach(|| {
                let mut pdfs = vec![0.0f32; n];
                field.pdf_batch(p, nv, d, &mut pdfs).map(|()| pdfs)
            })
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(PyArray1::from_vec(py, pdfs))
    }

    /// The learned probability of sampling the guide rather than the BSDF at each position
    /// (0 where the guide does not pay for its cost): `(N,)`.
    fn guide_probability<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let positions: Input<f32> = input(positions, "positions", None, Some(3))?;
        let p = positions.vec3s();
        let field = &self.inner;
        let a = py
            .detach(|| {
                let mut a = vec![0.0f32; p.len()];
                field.guide_probability_batch(p, &mut a).map(|()| a)
            })
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(PyArray1::from_vec(py, a))
    }

    /// Records one training sample per lane: the radiance `values[i]` (a luminance) that
    /// arrived at `positions[i]` from `directions[i]`, drawn with the solid-angle density
    /// `pdfs[i]`. Optional: `normals` (the shading normal passed to the surface product),
    /// and the one-sample mixture's terms `integrands`, `bsdf_pdfs`, `guide_pdfs` (all three
    /// or none), `volume` (bool, medium vertices). Returns how many samples were rejected
    /// (non-finite, out of the bounds, zero pdf: counted in `stats()`, never raised).
    #[pyo3(signature = (positions, directions, values, pdfs, *, normals = None,
        integrands = None, bsdf_pdfs = None, guide_pdfs = None, volume = None))]
    #[allow(clippy::too_many_arguments)]
    fn record<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        values: &Bound<'py, PyAny>,
        pdfs: &Bound<'py, PyAny>,
        normals: Option<&Bound<'py, PyAny>>,
        integrands: Option<&Bound<'py, PyAny>>,
        bsdf_pdfs: Option<&Bound<'py, PyAny>>,
        guide_pdfs: Option<&Bound<'py, PyAny>>,
        volume: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<u64> {
        let positions: Input<f32> = input(positions, "positions", None, Some(3))?;
        let n = positions.vec3s().len();
        let directions: Input<f32> = input(directions, "directions", Some(n), Some(3))?;
        let values: Input<f32> = input(values, "values", Some(n), None)?;
        let pdfs: Input<f32> = input(pdfs, "pdfs", Some(n), None)?;
        let normals: Option<Input<f32>> = optional(normals, "normals", n, Some(3))?;
        let integrands: Option<Input<f32>> = optional(integrands, "integrands", n, None)?;
        let bsdf_pdfs: Option<Input<f32>> = optional(bsdf_pdfs, "bsdf_pdfs", n, None)?;
        let guide_pdfs: Option<Input<f32>> = optional(guide_pdfs, "guide_pdfs", n, None)?;
        let volume: Option<Input<bool>> = optional(volume, "volume", n, None)?;
        let mixture = all_or_none(
            "`integrands`, `bsdf_pdfs` and `guide_pdfs`",
            [&integrands, &bsdf_pdfs, &guide_pdfs],
        )?;
        let (p, d, v, q) = (
            positions.vec3s(),
            directions.vec3s(),
            values.slice(),
            pdfs.slice(),
        );
        let normals = normals.as_ref().map(|a| a.vec3s());
        let volume = volume.as_ref().map(|a| a.slice());
        let field = &self.inner;
        Ok(py.detach(|| {
            let samples: Vec<Sample> = (0..n)
                .into_par_iter()
                .map(|i| {
                    let mut s = Sample {
                        position: p[i],
                        direction: d[i],
                        value: v[i],
                        pdf: q[i],
                        normal: normals.map(|n| n[i]),
                        volume: volume.is_some_and(|m| m[i]),
                        ..Sample::default()
                    };
                    if let Some([f, b, g]) = mixture {
                        s = s.with_mixture(f[i], b[i], g[i]);
                    }
                    s
                })
                .collect();
            field.record_batch(&samples)
        }))
    }

    /// The efficiency-aware factor `q` at each vertex: from the continuation estimate of the
    /// cell at `positions[i]`, the throughput weight `throughputs[i]` (a luminance, every
    /// earlier `1/q` included) and the pixel `pixels[i]` (`uint32`) of `image`; in
    /// `[min_survival, 1]` under `mode="roulette"`, up to `max_splits` under `"splitting"`.
    /// NaN where there is no factor (the cell has too few continuations, the image no pass
    /// with enough samples yet, a bad throughput): play your own roulette there.
    #[pyo3(signature = (positions, throughputs, pixels, image, *, mode = "splitting",
        min_survival = 0.05, max_splits = 8.0))]
    #[allow(clippy::too_many_arguments)]
    fn splitting_factor<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        throughputs: &Bound<'py, PyAny>,
        pixels: &Bound<'py, PyAny>,
        image: &PyImageStatistics,
        mode: &str,
        min_survival: f32,
        max_splits: f32,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let positions: Input<f32> = input(positions, "positions", None, Some(3))?;
        let n = positions.vec3s().len();
        let throughputs: Input<f32> = input(throughputs, "throughputs", Some(n), None)?;
        let pixels: Input<u32> = input(pixels, "pixels", Some(n), None)?;
        let policy = image
            .inner
            .splitting(parse_mode(mode)?)
            .map(|p| p.with_bounds(min_survival, max_splits))
            .transpose()
            .map_err(|e| config_error(e.to_string()))?;
        let (x, t, p) = (positions.vec3s(), throughputs.slice(), pixels.slice());
        let (field, image) = (&self.inner, &image.inner);
        let factors = py.detach(|| {
            (0..n)
                .into_par_iter()
                .with_min_len(sdguide::BATCH_CHUNK)
                .map(|i| {
                    let pixel = image.pixel(p[i] as usize);
                    policy
                        .and_then(|policy| policy.factor(&field.continuation(x[i]), t[i], pixel))
                        .unwrap_or(f32::NAN)
                })
                .collect()
        });
        Ok(PyArray1::from_vec(py, factors))
    }

    /// Learns from what was recorded since the last `refine`: new spatial and directional
    /// splits, masses, guide probabilities. Call it between passes, not during one.
    fn refine(&mut self, py: Python<'_>) {
        let field = &mut self.inner;
        py.detach(|| field.refine());
    }

    /// Adds the statistics `other` recorded in the current iteration to this field's (both
    /// must have started the iteration from the same state, e.g. the same cache). Exact:
    /// workers merged in any order give the bytes one field recording every sample gives.
    fn merge(&mut self, other: &PyGuidingField) -> PyResult<()> {
        self.inner.merge(&other.inner).map_err(merge_error)
    }

    /// The field's cache: versioned, checksummed bytes that `from_bytes` reads back.
    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        let bytes = py.detach(|| self.inner.to_bytes());
        PyBytes::new(py, &bytes)
    }

    /// The field a cache holds; `CacheError` if the bytes are not a valid cache.
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: &[u8]) -> PyResult<Self> {
        py.detach(|| sdguide::GuidingField::from_bytes(data))
            .map(|inner| Self { inner })
            .map_err(cache_error)
    }

    /// Writes the cache to `path` (atomically: a temporary file, then a rename).
    fn save(&self, py: Python<'_>, path: std::path::PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.save_to_path(&path))
            .map_err(cache_error)
    }

    /// The field the cache at `path` holds.
    #[staticmethod]
    fn load(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Self> {
        py.detach(|| sdguide::GuidingField::load_from_path(&path))
            .map(|inner| Self { inner })
            .map_err(cache_error)
    }

    /// Counts: iteration, tree sizes, samples recorded and rejected (by reason), memory.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_python(py, &self.inner.stats())
    }

    /// The configuration the field was made with, as a dict of the constructor's keywords.
    #[getter]
    fn config<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_python(py, self.inner.config())
    }

    /// `(lower, upper)`: the corners of the box the field covers.
    #[getter]
    fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let b = self.inner.bounds();
        (b.min.to_array(), b.max.to_array())
    }

    /// Refinements so far.
    #[getter]
    fn iteration(&self) -> u32 {
        self.inner.iteration()
    }

    fn __repr__(&self) -> String {
        let s = self.inner.stats();
        format!(
            "GuidingField(iteration={}, spatial_leaves={}, directional_nodes={})",
            s.iteration, s.spatial_leaves, s.directional_nodes
        )
    }
}
