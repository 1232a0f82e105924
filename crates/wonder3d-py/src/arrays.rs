//! numpy arrays in and out. In: any array-like (a numpy array of another float or integer
//! width, a list) is checked for its shape and dtype *kind* and converted once; a wrong one
//! is an `InvalidInputError` naming the argument, the shape and dtype expected and those
//! found. Out: new arrays that own a copy (a `Mesh` stays immutable from Python).

use numpy::{Element, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use wonder3d::Image;

use crate::errors::invalid;

/// `numpy.ascontiguousarray(value)`: the array-like as an ndarray (no copy when it is one).
fn as_array<'py>(value: &Bound<'py, PyAny>, name: &str) -> PyResult<Bound<'py, PyUntypedArray>> {
    let py = value.py();
    let numpy = py.import("numpy")?;
    let array = numpy
        .call_method1("asarray", (value,))
        .map_err(|e| invalid(name, format!("an array (numpy.asarray failed: {e})")))?;
    Ok(array.cast_into::<PyUntypedArray>()?)
}

/// What an array is, for errors: `float64 array of shape (5, 2)`.
fn describe(array: &Bound<'_, PyUntypedArray>) -> String {
    let dtype = array.dtype().str().map(|s| s.to_string()).unwrap_or_else(|_| "?".into());
    format!("{dtype} array of shape {}", python_shape(array.shape()))
}

/// A shape as Python writes it: `(4, 2)`, `(4,)`, `()`.
fn python_shape(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!("({})", shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
    }
}

/// The array's elements as `T` (C order), after checking its dtype kind is one of `kinds`
/// (numpy's kind letters: `f` float, `i` signed, `u` unsigned, `b` bool) and its shape
/// with `check_shape`.
fn elements<T: Element + Copy>(
    value: &Bound<'_, PyAny>,
    name: &str,
    kinds: &[u8],
    expected: &str,
    check_shape: impl Fn(&[usize]) -> bool,
) -> PyResult<(Vec<usize>, Vec<T>)> {
    let array = as_array(value, name)?;
    let kind = array.dtype().kind();
    if !kinds.contains(&kind) || !check_shape(array.shape()) {
        return Err(invalid(name, format!("{expected}, got a {}", describe(&array))));
    }
    let shape = array.shape().to_vec();
    let py = value.py();
    let numpy = py.import("numpy")?;
    let converted = numpy.call_method1("ascontiguousarray", (array, numpy::dtype::<T>(py)))?;
    let typed = converted.cast_into::<PyArrayDyn<T>>()?;
    let readonly = typed.readonly();
    let data = readonly.as_slice().map_err(|e| invalid(name, format!("a contiguous array ({e})")))?.to_vec();
    Ok((shape, data))
}

/// Rows of `K` floats: an `(N, K)` float array (float64 is rounded to float32, the core's
/// precision).
pub fn float_rows<const K: usize>(value: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f32; K]>> {
    let expected = format!("a float array of shape (N, {K})");
    let (_, data) = elements::<f32>(value, name, b"f", &expected, |s| s.len() == 2 && s[1] == K)?;
    Ok(data.chunks_exact(K).map(|c| std::array::from_fn(|i| c[i])).collect())
}

/// Triangles: an `(M, 3)` integer array of vertex indices in `0..vertex_count` (trimesh's
/// int64 faces welcome); a negative or too large index names its row and column.
pub fn triangles(value: &Bound<'_, PyAny>, name: &str, vertex_count: usize) -> PyResult<Vec<[u32; 3]>> {
    let (_, data) =
        elements::<i64>(value, name, b"iu", "an integer array of shape (M, 3)", |s| s.len() == 2 && s[1] == 3)?;
    let mut out = Vec::with_capacity(data.len() / 3);
    for (row, corners) in data.chunks_exact(3).enumerate() {
        let mut triangle = [0u32; 3];
        for (column, &index) in corners.iter().enumerate() {
            if index < 0 || index as u64 >= vertex_count as u64 {
                return Err(invalid(
                    format!("{name}[{row}][{column}]"),
                    format!("a vertex index in 0..{vertex_count}, got {index}"),
                ));
            }
            triangle[column] = index as u32;
        }
        out.push(triangle);
    }
    Ok(out)
}

/// An image: an `(H, W, C)` float array with `channels` channels (an `(H, W)` array when
/// `channels` is 1), values as the core documents them (colours sRGB in [0, 1], unit
/// normals, masks in [0, 1]).
pub fn image(value: &Bound<'_, PyAny>, name: &str, channels: usize) -> PyResult<Image> {
    let expected = if channels == 1 {
        "a float array of shape (H, W) or (H, W, 1)".to_string()
    } else {
        format!("a float array of shape (H, W, {channels})")
    };
    let fits = |s: &[usize]| match s {
        [h, w] => channels == 1 && *h > 0 && *w > 0,
        [h, w, c] => *c == channels && *h > 0 && *w > 0,
        _ => false,
    };
    let (shape, data) = elements::<f32>(value, name, b"f", &expected, fits)?;
    let (height, width) = (shape[0], shape[1]);
    let too_large = |v: usize| u32::try_from(v).map_err(|_| invalid(name, format!("{expected}, got a side of {v}")));
    Image::new(too_large(width)?, too_large(height)?, channels as u32, data)
        .map_err(|e| invalid(name, format!("a valid image ({e})")))
}

/// An image as an `(H, W, C)` float32 array (`(H, W)` for one channel when `squeeze`).
pub fn image_to_array<'py>(py: Python<'py>, image: &Image, squeeze: bool) -> PyResult<Bound<'py, PyAny>> {
    let (h, w, c) = (image.height() as usize, image.width() as usize, image.channels() as usize);
    let flat = numpy::PyArray1::from_slice(py, image.data());
    let array = if squeeze && c == 1 { flat.reshape([h, w])?.into_any() } else { flat.reshape([h, w, c])?.into_any() };
    Ok(array)
}

/// Rows of `K` values as an `(N, K)` array.
pub fn rows_to_array<'py, T: Element + Copy, const K: usize>(
    py: Python<'py>,
    rows: &[[T; K]],
) -> PyResult<Bound<'py, PyAny>> {
    let flat: Vec<T> = rows.iter().flatten().copied().collect();
    Ok(numpy::PyArray1::from_vec(py, flat).reshape([rows.len(), K])?.into_any())
}

/// A serialisable value as Python objects (through JSON and `json.loads`): reports and
/// metrics keep the keys of the CLI's JSON. `what` names it in the (unexpected) error.
pub fn to_py_objects<'py, T: serde::Serialize>(py: Python<'py>, value: &T, what: &str) -> PyResult<Bound<'py, PyAny>> {
    let json = serde_json::to_string(value).map_err(|e| crate::errors::invalid(what, e.to_string()))?;
    py.import("json")?.call_method1("loads", (json,))
}
