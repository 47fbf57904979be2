//! `sdguide.PathRecorderBatch`: the library's path recorder, one per camera sample, driven a
//! bounce at a time by a wavefront renderer.
//!
//! Each call reports one event for every active lane (`active[i]`, default all) with that
//! lane's arguments; a vertex is named by the handle `push` returned for it (`uint32`; the
//! camera ray's comes from `start`). Lane `i` belongs to path `i`, or with `paths`, to path
//! `paths[i]`: a renderer that splits traces several lanes of one path (`paths` must then be
//! sorted, which keeping lanes in order after `np.repeat` and masks does). An inactive lane gets
//! the handle `NO_VERTEX` back and is left alone. The paths run in parallel with the GIL
//! released, each path's lanes in order, and each recorder does exactly what the one-path
//! recorder does.

use crate::arrays::{Input, all_or_none, input, optional, vec3_output};
use crate::field::PyGuidingField;
use numpy::{Element, PyArray1, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;
use sdguide::{PathRecorder, PathVertex, VertexId};

/// The handle returned for an inactive lane.
const NO_VERTEX: u32 = u32::MAX;

/// One path recorder per camera sample, reused from pass to pass.
#[pyclass(name = "PathRecorderBatch", module = "sdguide")]
pub struct PyPathRecorderBatch {
    paths: Vec<PathRecorder>,
}

/// The per-call inputs every event takes: the handles, the lanes' paths and the mask.
struct Lanes<'py> {
    at: Input<'py, u32>,
    /// Where each path's lanes start and end (`bounds[p]..bounds[p + 1]`), with `paths`.
    bounds: Option<Vec<usize>>,
    active: Option<Input<'py, bool>>,
}

impl<'py> Lanes<'py> {
    fn new(
        recorders: usize,
        at: &Bound<'py, PyAny>,
        paths: Option<&Bound<'py, PyAny>>,
        active: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Self> {
        let lanes = match paths {
            Some(p) if !p.is_none() => None,
            _ => Some(recorders),
        };
        let at: Input<u32> = input(at, "at", lanes, None)?;
        let n = at.slice().len();
        let paths: Option<Input<u32>> = optional(paths, "paths", n, None)?;
        let bounds = paths
            .map(|p| run_bounds(p.slice(), recorders))
            .transpose()?;
        Ok(Self {
            at,
            bounds,
            active: optional(active, "active", n, None)?,
        })
    }

    fn len(&self) -> usize {
        self.at.slice().len()
    }
}

/// The start of each path's run of lanes in `paths` (sorted, each below `recorders`), and the
/// end of the last: `recorders + 1` offsets.
fn run_bounds(paths: &[u32], recorders: usize) -> PyResult<Vec<usize>> {
    if paths.windows(2).any(|w| w[0] > w[1]) {
        return Err(PyValueError::new_err(
            "`paths` must be sorted (non-decreasing)",
        ));
    }
    if paths.last().is_some_and(|&p| p as usize >= recorders) {
        return Err(PyValueError::new_err(format!(
            "`paths` holds a path index beyond the {recorders} paths"
        )));
    }
    let mut bounds = vec![0usize; recorders + 1];
    for &p in paths {
        bounds[p as usize + 1] += 1;
    }
    for i in 1..bounds.len() {
        bounds[i] += bounds[i - 1];
    }
    Ok(bounds)
}

impl PyPathRecorderBatch {
    /// Runs `f(lane, recorder, handle)` on every active lane, the paths in parallel and each
    /// path's lanes in order, with the GIL released; returns what each lane gave (`NO_VERTEX`
    /// for inactive ones).
    fn each<F>(&mut self, py: Python<'_>, lanes: &Lanes<'_>, f: F) -> Vec<u32>
    where
        F: Fn(usize, &mut PathRecorder, VertexId) -> u32 + Sync + Send,
    {
        let at = lanes.at.slice();
        let active = lanes.active.as_ref().map(|a| a.slice());
        let bounds = lanes.bounds.as_deref();
        let recorders = &mut self.paths;
        let mut out = vec![NO_VERTEX; lanes.len()];
        py.detach(|| {
            let lane = |i: usize, r: &mut PathRecorder, o: &mut u32| {
                if active.is_none_or(|a| a[i]) {
                    *o = f(i, r, VertexId::from_index(at[i]));
                }
            };
            match bounds {
                None => recorders
                    .par_iter_mut()
                    .zip(out.par_iter_mut())
                    .enumerate()
                    .for_each(|(i, (r, o))| lane(i, r, o)),
                Some(bounds) => {
                    let mut runs = Vec::with_capacity(recorders.len());
                    let mut rest = out.as_mut_slice();
                    for w in bounds.windows(2) {
                        let (run, tail) = rest.split_at_mut(w[1] - w[0]);
                        runs.push(run);
                        rest = tail;
                    }
                    recorders
                        .par_iter_mut()
                        .zip(runs.into_par_iter())
                        .enumerate()
                        .for_each(|(p, (r, run))| {
                            for (k, o) in run.iter_mut().enumerate() {
                                lane(bounds[p] + k, r, o);
                            }
                        });
                }
            }
        });
        out
    }
}

impl PyPathRecorderBatch {
    /// [`each`](Self::each) for an event with two per-lane scalars, `(name, array)` each.
    fn each_with<A, B>(
        &mut self,
        py: Python<'_>,
        lanes: &Lanes<'_>,
        (a_name, a): (&str, &Bound<'_, PyAny>),
        (b_name, b): (&str, &Bound<'_, PyAny>),
        f: impl Fn(&mut PathRecorder, VertexId, A, B) + Sync + Send,
    ) -> PyResult<()>
    where
        A: Element + Copy + Sync,
        B: Element + Copy + Sync,
    {
        let a: Input<A> = input(a, a_name, Some(lanes.len()), None)?;
        let b: Input<B> = input(b, b_name, Some(lanes.len()), None)?;
        let (a, b) = (a.slice(), b.slice());
        self.each(py, lanes, |i, r, v| {
            f(r, v, a[i], b[i]);
            0
        });
        Ok(())
    }
}

fn handles(id: VertexId) -> u32 {
    u32::try_from(id.index()).unwrap_or(NO_VERTEX)
}

#[pymethods]
impl PyPathRecorderBatch {
    /// `paths` recorders (camera samples), each holding up to `max_vertices` vertices.
    #[new]
    #[pyo3(signature = (paths, max_vertices = PathRecorder::DEFAULT_MAX_VERTICES))]
    fn new(paths: usize, max_vertices: usize) -> Self {
        Self {
            paths: vec![PathRecorder::with_max_vertices(max_vertices); paths],
        }
    }

    /// The number of paths.
    fn __len__(&self) -> usize {
        self.paths.len()
    }

    /// Starts a camera sample on every path: returns the camera rays' handles, `(P,)`.
    fn start<'py>(&mut self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        let recorders = &mut self.paths;
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
    #[pyo3(signature = (at, radiance, *, paths = None, active = None))]
    fn add_radiance(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        radiance: &Bound<'_, PyAny>,
        paths: Option<&Bound<'_, PyAny>>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let lanes = Lanes::new(self.paths.len(), at, paths, active)?;
        let radiance: Input<f32> = input(radiance, "radiance", Some(lanes.len()), Some(3))?;
        let l = radiance.vec3s();
        self.each(py, &lanes, |i, r, v| {
            r.add_radiance(v, l[i]);
            0
        });
        Ok(())
    }

    /// A cost (rays, say) spent tracing for `at[i]`.
    #[pyo3(signature = (at, costs, *, paths = None, active = None))]
    fn add_cost(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        costs: &Bound<'_, PyAny>,
        paths: Option<&Bound<'_, PyAny>>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let lanes = Lanes::new(self.paths.len(), at, paths, active)?;
        let costs: Input<f32> = input(costs, "costs", Some(lanes.len()), None)?;
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
        bsdf_pdfs = None, guide_pdfs = None, volume = None, paths = None, active = None))]
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
        paths: Option<&Bound<'py, PyAny>>,
        active: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let lanes = Lanes::new(self.paths.len(), at, paths, active)?;
        let n = lanes.len();
        let positions: Input<f32> = input(positions, "positions", Some(n), Some(3))?;
        let directions: Input<f32> = input(directions, "directions", Some(n), Some(3))?;
        let bsdf: Input<f32> = input(bsdf, "bsdf", Some(n), Some(3))?;
        let pdfs: Input<f32> = input(pdfs, "pdfs", Some(n), None)?;
        let normals: Option<Input<f32>> = optional(normals, "normals", n, Some(3))?;
        let bsdf_pdfs: Option<Input<f32>> = optional(bsdf_pdfs, "bsdf_pdfs", n, None)?;
        let guide_pdfs: Option<Input<f32>> = optional(guide_pdfs, "guide_pdfs", n, None)?;
        let volume: Option<Input<bool>> = optional(volume, "volume", n, None)?;
        let mixture = all_or_none("`bsdf_pdfs` and `guide_pdfs`", [&bsdf_pdfs, &guide_pdfs])?;
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
            if let Some([b, g]) = mixture {
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
    #[pyo3(signature = (at, positions, weights, *, paths = None, active = None))]
    fn push_delta<'py>(
        &mut self,
        py: Python<'py>,
        at: &Bound<'py, PyAny>,
        positions: &Bound<'py, PyAny>,
        weights: &Bound<'py, PyAny>,
        paths: Option<&Bound<'py, PyAny>>,
        active: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let lanes = Lanes::new(self.paths.len(), at, paths, active)?;
        let n = lanes.len();
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
    #[pyo3(signature = (at, probabilities, survived, *, paths = None, active = None))]
    fn roulette(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        probabilities: &Bound<'_, PyAny>,
        survived: &Bound<'_, PyAny>,
        paths: Option<&Bound<'_, PyAny>>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let lanes = Lanes::new(self.paths.len(), at, paths, active)?;
        let (p, s) = (("probabilities", probabilities), ("survived", survived));
        self.each_with(py, &lanes, p, s, |r, v, p: f32, s: bool| {
            r.roulette(v, p, s)
        })
    }

    /// Roulette or splitting at the vertex the ray of `at[i]` reached: `traced[i]`
    /// continuations for the factor `factors[i]` (see `continuations`), each pushed after this
    /// weighing `1/factors[i]`. Push a split's continuations as lanes of the same path.
    #[pyo3(signature = (at, factors, traced, *, paths = None, active = None))]
    fn split(
        &mut self,
        py: Python<'_>,
        at: &Bound<'_, PyAny>,
        factors: &Bound<'_, PyAny>,
        traced: &Bound<'_, PyAny>,
        paths: Option<&Bound<'_, PyAny>>,
        active: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let lanes = Lanes::new(self.paths.len(), at, paths, active)?;
        let (k, t) = (("factors", factors), ("traced", traced));
        self.each_with(py, &lanes, k, t, |r, v, k: f32, t: u32| r.split(v, k, t))
    }

    /// Ends every path's camera sample: returns their estimates, `(P, 3)` (RGB, every
    /// weight applied).
    fn finish<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let recorders = &mut self.paths;
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
        let (recorders, field) = (&self.paths, &field.inner);
        py.detach(|| recorders.par_iter().map(|r| r.record(field)).sum())
    }

    /// The recorders' counts, summed over the lanes: `paths`, `bad_vertices`, `bad_values`,
    /// `dropped_vertices`, `truncated_paths`, `factors`, `no_factor` (see the Rust
    /// `PathRecorderStats`).
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut sum = [0u64; 7];
        for r in &self.paths {
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
