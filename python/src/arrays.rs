//! numpy arrays in and out: the checks every batch call makes on what Python hands it, and
//! the outputs it hands back.
//!
//! Inputs are C-contiguous `float32` arrays of shape `(N, 3)` (vectors), `(N, 2)` (pairs of
//! uniform numbers) or `(N,)` (scalars); anything else — another dtype, another shape, a
//! strided view, a list — is a `ValueError` that names the argument, before any work. No
//! silent conversion: a copy in a wavefront renderer's inner loop should be the renderer's
//! choice, made once.

use glam::{Vec2, Vec3};
use numpy::{
    Element, PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// A checked, read-only view of an input array, kept borrowed while its slice is used.
pub struct Input<'py, T: Element> {
    array: PyReadonlyArrayDyn<'py, T>,
}

impl<'py, T: Element> Input<'py, T> {
    /// The array's elements, in memory order (C-contiguous: checked on extraction).
    pub fn slice(&self) -> &[T] {
        self.array
            .as_slice()
            .expect("contiguity was checked when the input was taken")
    }
}

impl Input<'_, f32> {
    /// The `(N, 3)` array as `N` vectors.
    pub fn vec3s(&self) -> &[Vec3] {
        bytemuck::cast_slice(self.slice())
    }

    /// The `(N, 2)` array as `N` pairs.
    pub fn vec2s(&self) -> &[Vec2] {
        bytemuck::cast_slice(self.slice())
    }
}

/// A dtype as numpy prints it (`float32`).
fn dtype_name(dtype: &Bound<'_, numpy::PyArrayDescr>) -> String {
    dtype.str().map_or_else(|_| "?".into(), |s| s.to_string())
}

/// `object` as a C-contiguous array of `T` with shape `(lanes, width)` (`width` `None`: shape
/// `(lanes,)`); `lanes` `None` takes the first axis's length as the lane count.
pub fn input<'py, T: Element>(
    object: &Bound<'py, PyAny>,
    name: &str,
    lanes: Option<usize>,
    width: Option<usize>,
) -> PyResult<Input<'py, T>> {
    let py = object.py();
    let shape_text = match width {
        Some(w) => format!("(N, {w})"),
        None => "(N,)".into(),
    };
    let Ok(array) = object.cast::<PyArrayDyn<T>>() else {
        let found = match object.cast::<numpy::PyUntypedArray>() {
            Ok(a) => format!(
                "an array of dtype {} and shape {:?}",
                dtype_name(&a.dtype()),
                a.shape()
            ),
            Err(_) => format!("a {}", object.get_type().name()?),
        };
        return Err(PyValueError::new_err(format!(
            "`{name}` must be a numpy array of dtype {} and shape {shape_text}; got {found}",
            dtype_name(&T::get_dtype(py))
        )));
    };
    let shape = array.shape();
    let expected_dims = if width.is_some() { 2 } else { 1 };
    let lanes_ok = lanes.is_none_or(|n| shape.first() == Some(&n));
    let width_ok = width.is_none_or(|w| shape.get(1) == Some(&w));
    if shape.len() != expected_dims || !lanes_ok || !width_ok {
        let lanes_text = lanes.map_or("N".to_string(), |n| n.to_string());
        let want = match width {
            Some(w) => format!("({lanes_text}, {w})"),
            None => format!("({lanes_text},)"),
        };
        return Err(PyValueError::new_err(format!(
            "`{name}` must have shape {want}; got {shape:?}"
        )));
    }
    if !array.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "`{name}` must be C-contiguous (numpy.ascontiguousarray makes a copy that is)"
        )));
    }
    Ok(Input {
        array: array.readonly(),
    })
}

/// An optional input: `None` stays `None`.
pub fn optional<'py, T: Element>(
    object: Option<&Bound<'py, PyAny>>,
    name: &str,
    lanes: usize,
    width: Option<usize>,
) -> PyResult<Option<Input<'py, T>>> {
    object
        .filter(|o| !o.is_none())
        .map(|o| input(o, name, Some(lanes), width))
        .transpose()
}

/// A new `float32` array of shape `(lanes, 3)` holding `data` (`3·lanes` numbers).
pub fn vec3_output(py: Python<'_>, data: Vec<f32>) -> PyResult<Bound<'_, PyArray2<f32>>> {
    let lanes = data.len() / 3;
    PyArray1::from_vec(py, data).reshape([lanes, 3])
}

/// Optional inputs that come together (the mixture's terms): their slices if all are given,
/// `None` if none is, a `ValueError` naming them (`names`) otherwise.
pub fn all_or_none<'a, const N: usize>(
    names: &str,
    inputs: [&'a Option<Input<'_, f32>>; N],
) -> PyResult<Option<[&'a [f32]; N]>> {
    let given = inputs.iter().filter(|i| i.is_some()).count();
    if given == 0 {
        return Ok(None);
    }
    if given < N {
        return Err(PyValueError::new_err(format!(
            "{names} come together: all or none"
        )));
    }
    Ok(Some(
        inputs.map(|i| i.as_ref().map_or(&[][..], |a| a.slice())),
    ))
}
