//! `sdguide.PathRecorderBatch`: the library's path recorder, one per lane, driven a bounce at
//! a time by a wavefront renderer.
//!
//! Lane `i` is one camera sample; each call reports the same event for every active lane
//! (`active[i]`, default all) with that lane's arguments, and a vertex is named by the handle
//! `push` returned for it (`uint32`; the camera ray's comes from `start`). An inactive lane
//! gets the handle `NO_VERTEX` back and is left alone. The recorders run in parallel with the
//! GIL released, and each does exactly what the one-path recorder does.

use crate::arrays::{Input, input, optional, vec3_output};
use crate::field::PyGuidingField;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use sdguide::{PathRecorder, PathVertex, VertexId};

/// The handle returned for an inactive lane.
const NO_VERTEX: u32 = u32::MAX;

/// One path recorder per lane (a camera sample each), reused from pass to pass.
#[pyclass(name = "PathRecorderBatch", module = "sdguide")]
pub struct PyPathRecorderBatch {
    lanes: Vec<PathRecorder>,
}

/// The per-call inputs every event takes: the handles and the mask.
struct Lanes<'py> {
    at: Input<'py, u32>,
    active: Option<Input<'py, bool>>,
}

impl<'py> Lanes<'py> {
    fn new(n: usize, at: &Bound<'py, PyAny>, active: Option<&Bound<'py, PyAny>>) -> PyResult<Self> {
        Ok(Self {
            at: input(at, "at", Some(n), None)?,
            active: optional(active, "active", n, None)?,
        })
    }

    /// `(handle, active)` of every lane.
    fn views(&self) -> (&[u32], Option<&[bool]>) {
        (self.at.slice(), self.active.as_ref().map(|a| a.slice()))
    }
}

impl PyPathRecorderBatch {
    /// Runs `f(lane, recorder, handle)` on every active lane in parallel, with the GIL
    /// released; returns what each lane gave (`NO_VERTEX` for inactive ones).
    fn each<F>(&mut self, py: Python<'_>, lanes: &Lanes<'_>, f: F) -> Vec<u32>
    where
        F: Fn(usize, &mut PathRecorder, VertexId) -> u32 + Sync + Send,
    {
        let (at, active) = lanes.views();
        let recorders = &mut self.lanes;
        py.detach(|| {
            recorders
                .par_iter_mut()
                .enumerate()
                .map(|(i, r)| {
                    if active.is_none_or(|a| a[i]) {
                        f(i, r, VertexId::from_index(at[i]))
                    } else {
                        NO_VERTEX
                    }
                })
                .collect()
        })
    }
}

fn handles(id: VertexId) -> u32 {
    u32::try_from(id.index()).unwrap_or(NO_VERTEX)
}

#[pymethods]
impl PyPathRecorderBatch {
    /// `lanes` recorders, each holding up to `max_vertices` vertices per path.
    #[new]
    #[pyo3(signature = (lanes, max_vertices = PathRecorder::DEFAULT_MAX_VERTICES))]
    fn new(lanes: usize, max_vertices: usize) -> Self {
        Self {
            lanes: vec![PathRecorder::with_max_vertices(max_vertices); lanes],
        }
    }

    /// The number of lanes.
    fn __len__(&self) -> usize {
        self.lanes.len()
    }

    /// Starts a camera sample on every lane: returns the camera rays' handles, `(N,)` `uint32`.
    fn start<'py>(&mut self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        let recorders = &mut self.lanes;
        let ids: Vec<u32> = py.detach(|| {
            recorders
                .par_iter_mut()
                .map(|r| handles(r.start()))
                .collect()
        });
        PyArray1::from_vec(py, ids)
    }

    /// Radiance `radiance[i]` (RGB, `(N, 3)`) arriving at `at[i]` along its direction:
    /// emission the ray of `at[i]` hit (with its MIS weight) and next-event contributions at
    /// the vertex it reached, not multiplied by anything before them.
    #[pyo3(signature = (at, radiance, active = None))]
    fn add_radiance(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        radiance: &Bound<'_, PyAny>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let lanes = Lanes::new(self.lanes.len(), at, active)?;
        let radiance: Input<f32> = input(radiance, "radiance", Some(self.lanes.len()), Some(3))?;
        let l = radiance.vec3s();
        self.each(py, &lanes, |i, r, v| {
            r.add_radiance(v, l[i]);
            0
        });
        Ok(())
    }

    /// A cost (rays, say) spent tracing for `at[i]`.
    #[pyo3(signature = (at, costs, active = None))]
    fn add_cost(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        costs: &Bound<'_, PyAny>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let lanes = Lanes::new(self.lanes.len(), at, active)?;
        let costs: Input<f32> = input(costs, "costs", Some(self.lanes.len()), None)?;
        let c = costs.slice();
        self.each(py, &lanes, |i, r, v| {
            r.add_cost(v, c[i]);
            0
        });
        Ok(())
    }

    /// At the vertex the ray of `at[i]` reached (`positions[i]`), the direction
    /// `directions[i]` was drawn with the density `pdfs[i]` (the mixture's), where the BSDF
    /// times the cosine is `bsdf[i]` (RGB). Optional: `normals`, the BSDF's and the guide's
    /// pdfs of the direction (`bsdf_pdfs`, `guide_pdfs`, both or neither), `volume` (bool).
    /// Returns the new vertices' handles.
    #[pyo3(signature = (at, positions, directions, bsdf, pdfs, *, normals = None,
        bsdf_pdfs = None, guide_pdfs = None, volume = None, active = None))]
    #[allow(clippy::too_many_arguments)]
    fn push<'py>(
        &mut self,
        py: Python<'py>,
        at: &Bound<'py, PyAny>,
        positions: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        bsdf: &Bound<'py, PyAny>,
        pdfs: &Bound<'py, PyAny>,
        normals: Option<&Bound<'py, PyAny>>,
        bsdf_pdfs: Option<&Bound<'py, PyAny>>,
        guide_pdfs: Option<&Bound<'py, PyAny>>,
        volume: Option<&Bound<'py, PyAny>>,
        active: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let n = self.lanes.len();
        let lanes = Lanes::new(n, at, active)?;
        let positions: Input<f32> = input(positions, "positions", Some(n), Some(3))?;
        let directions: Input<f32> = input(directions, "directions", Some(n), Some(3))?;
        let bsdf: Input<f32> = input(bsdf, "bsdf", Some(n), Some(3))?;
        let pdfs: Input<f32> = input(pdfs, "pdfs", Some(n), None)?;
        let normals: Option<Input<f32>> = optional(normals, "normals", n, Some(3))?;
        let bsdf_pdfs: Option<Input<f32>> = optional(bsdf_pdfs, "bsdf_pdfs", n, None)?;
        let guide_pdfs: Option<Input<f32>> = optional(guide_pdfs, "guide_pdfs", n, None)?;
        let volume: Option<Input<bool>> = optional(volume, "volume", n, None)?;
        let mixture = match (&bsdf_pdfs, &guide_pdfs) {
            (Some(b), Some(g)) => Some((b.slice(), g.slice())),
            (None, None) => None,
            _ => {
                return Err(pyo3::exceptions::PyValueError::new_err(
                    "`bsdf_pdfs` and `guide_pdfs` come together: both or neither",
                ));
            }
        };
        let (x, d, f, q) = (
            positions.vec3s(),
            directions.vec3s(),
            bsdf.vec3s(),
            pdfs.slice(),
        );
        let normals = normals.as_ref().map(|a| a.vec3s());
        let volume = volume.as_ref().map(|a| a.slice());
        let ids = self.each(py, &lanes, |i, r, from| {
            let mut vertex = PathVertex::new(x[i], d[i], f[i], q[i]);
            if let Some(n) = normals {
                vertex = vertex.with_normal(n[i]);
            }
            if let Some((b, g)) = mixture {
                vertex = vertex.with_mixture(b[i], g[i]);
            }
            if volume.is_some_and(|m| m[i]) {
                vertex = vertex.in_volume();
            }
            handles(r.push(from, vertex))
        });
        Ok(PyArray1::from_vec(py, ids))
    }

    /// A delta vertex (a specular bounce) at `positions[i]` with weight `weights[i]` (`f/p`,
    /// RGB): passes its weight on, records nothing. Returns the new handles.
    #[pyo3(signature = (at, positions, weights, active = None))]
    fn push_delta<'py>(
        &mut self,
        py: Python<'py>,
        at: &Bound<'py, PyAny>,
        positions: &Bound<'py, PyAny>,
        weights: &Bound<'py, PyAny>,
        active: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let n = self.lanes.len();
        let lanes = Lanes::new(n, at, active)?;
        let positions: Input<f32> = input(positions, "positions", Some(n), Some(3))?;
        let weights: Input<f32> = input(weights, "weights", Some(n), Some(3))?;
        let (x, w) = (positions.vec3s(), weights.vec3s());
        let ids = self.each(py, &lanes, |i, r, from| {
            handles(r.push_delta(from, x[i], w[i]))
        });
        Ok(PyArray1::from_vec(py, ids))
    }

    /// Russian roulette on the path along `at[i]`: it went on with probability
    /// `probabilities[i]` if `survived[i]`, else it ended there.
    #[pyo3(signature = (at, probabilities, survived, active = None))]
    fn roulette(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        probabilities: &Bound<'_, PyAny>,
        survived: &Bound<'_, PyAny>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let n = self.lanes.len();
        let lanes = Lanes::new(n, at, active)?;
        let probabilities: Input<f32> = input(probabilities, "probabilities", Some(n), None)?;
        let survived: Input<bool> = input(survived, "survived", Some(n), None)?;
        let (p, s) = (probabilities.slice(), survived.slice());
        self.each(py, &lanes, |i, r, v| {
            r.roulette(v, p[i], s[i]);
            0
        });
        Ok(())
    }

    /// Ends every lane's camera sample: returns their estimates, `(N, 3)` (RGB, every
    /// weight applied).
    fn finish<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let recorders = &mut self.lanes;
        let estimates: Vec<f32> = py.detach(|| {
            recorders
                .par_iter_mut()
                .flat_map_iter(|r| r.finish().to_array())
                .collect()
        });
        vec3_output(py, estimates)
    }

    /// Records every finished path into `field` (samples and continuations); returns how
    /// many vertices recorded.
    fn record(&self, py: Python<'_>, field: &PyGuidingField) -> usize {
        let (recorders, field) = (&self.lanes, &field.inner);
        py.detach(|| recorders.par_iter().map(|r| r.record(field)).sum())
    }

    /// The recorders' counts, summed over the lanes: `paths`, `bad_vertices`, `bad_values`,
    /// `dropped_vertices`, `truncated_paths`, `factors`, `no_factor` (see the Rust
    /// `PathRecorderStats`).
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut sum = [0u64; 7];
        for r in &self.lanes {
            let s = r.stats();
            let counts = [
                s.paths,
                s.bad_vertices,
                s.bad_values,
                s.dropped_vertices,
                s.truncated_paths,
                s.factors,
                s.no_factor,
            ];
            for (total, c) in sum.iter_mut().zip(counts) {
                *total += c;
            }
        }
        let names = [
            "paths",
            "bad_vertices",
            "bad_values",
            "dropped_vertices",
            "truncated_paths",
            "factors",
            "no_factor",
        ];
        let dict = PyDict::new(py);
        for (k, v) in names.into_iter().zip(sum) {
            dict.set_item(k, v)?;
        }
        Ok(dict)
    }
}
