//! What crosses the binding: the exception classes and the one table from an API error's kind to its class
//! ([`to_py`]), and Python's values into the API's (integers through [`unsigned`], arrays as little-endian
//! bytes, regions, output names, images).

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use raypatch::raypatch_model::error::{one_line, Quoted};
use raypatch::{ErrorKind, Image, Output, Outputs, Region};

create_exception!(raypatch, Error, PyException, "Everything raypatch refuses or fails at: a one-line message.");
create_exception!(
    raypatch,
    InputError,
    Error,
    "An input the engine cannot take: arrays, cameras, poses, sizes, views, requests, values that overflow float32."
);
create_exception!(raypatch, FileError, Error, "A model, scene or image file that is missing or malformed.");
create_exception!(raypatch, GpuError, Error, "No adapter, a device lost or failing, out of memory.");
create_exception!(raypatch, EngineClosed, Error, "Work asked of an engine after `Engine.close()`.");

/// The Python exception for an API error, by whose fault it is (`raypatch::Error::kind`), with the message on
/// one bounded line (`one_line`); a bug of raypatch's own is the base class `raypatch.Error`.
pub fn to_py(e: raypatch::Error) -> PyErr {
    let message = one_line(&e.to_string());
    match e.kind() {
        ErrorKind::Input => InputError::new_err(message),
        ErrorKind::File => FileError::new_err(message),
        ErrorKind::Device => GpuError::new_err(message),
        ErrorKind::Internal => Error::new_err(message),
    }
}

pub fn input_error(message: String) -> PyErr {
    InputError::new_err(message)
}

/// A size, count or index from Python. The binding takes signed integers so that a negative one is an
/// InputError naming the argument (an unsigned parameter would raise OverflowError).
pub fn unsigned(name: &str, value: i64) -> PyResult<usize> {
    usize::try_from(value).map_err(|_| input_error(format!("{name} {value}: expected 0 or more")))
}

/// `count` little-endian values of `N` bytes from `bytes`, or an InputError naming `what` and `kind`.
fn values<const N: usize>(what: &str, kind: &str, bytes: &[u8], count: usize) -> PyResult<Vec<[u8; N]>> {
    let length = count
        .checked_mul(N)
        .ok_or_else(|| input_error(format!("{what}: {count} values are more than memory holds")))?;
    if bytes.len() != length {
        return Err(input_error(format!("{what}: {} bytes, expected {count} {kind} values", bytes.len())));
    }
    Ok(bytes.chunks_exact(N).map(|b| b.try_into().expect("N bytes")).collect())
}

/// Little-endian f32s from bytes, `count` of them.
pub fn f32s(what: &str, bytes: &[u8], count: usize) -> PyResult<Vec<f32>> {
    Ok(values(what, "float32", bytes, count)?.into_iter().map(f32::from_le_bytes).collect())
}

pub fn u32s(what: &str, bytes: &[u8], count: usize) -> PyResult<Vec<u32>> {
    Ok(values(what, "uint32", bytes, count)?.into_iter().map(u32::from_le_bytes).collect())
}

pub fn f64s(what: &str, bytes: &[u8], count: usize) -> PyResult<Vec<f64>> {
    Ok(values(what, "float64", bytes, count)?.into_iter().map(f64::from_le_bytes).collect())
}

pub fn f32_bytes<'py>(py: Python<'py>, values: &[f32]) -> Bound<'py, PyBytes> {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    PyBytes::new(py, &bytes)
}

/// A region `(x, y, width, height)` from Python.
pub fn region_of(region: Option<(i64, i64, i64, i64)>) -> PyResult<Option<Region>> {
    let Some((x, y, width, height)) = region else { return Ok(None) };
    let (x, y) = (unsigned("region x", x)?, unsigned("region y", y)?);
    Ok(Some(Region { x, y, width: unsigned("region width", width)?, height: unsigned("region height", height)? }))
}

pub fn outputs_of(names: Vec<String>) -> PyResult<Outputs> {
    let mut outputs = Outputs::default();
    for (i, name) in names.iter().enumerate() {
        let output = Output::from_name(name).ok_or_else(|| {
            let name = Quoted(name);
            input_error(format!("outputs: {name:?} is not one of \"rgb\", \"logdepth\", \"depth\", \"segmentation\""))
        })?;
        outputs = if i == 0 { Outputs::of(&[output]) } else { outputs.with(output) };
    }
    Ok(outputs)
}

/// Reads an image of `[height, width, 3]` f32 values in [0, 1].
pub fn image_of(what: &str, bytes: &[u8], width: i64, height: i64) -> PyResult<Image> {
    let (_, width, height) = image_sizes(what, 1, width, height)?;
    Image::new(width, height, f32s(what, bytes, width * height * 3)?).map_err(to_py)
}

/// `count` images of `width` x `height` pixels checked against the engine's limits (each image's size, the
/// views of a scene and their pixels) before anything is converted or allocated for them: (count, width,
/// height), whose products cannot overflow.
pub fn image_sizes(what: &str, count: i64, width: i64, height: i64) -> PyResult<(usize, usize, usize)> {
    use raypatch::raypatch_model::views::MAX_VIEWS;
    let (count, width, height) = (unsigned("images", count)?, unsigned("width", width)?, unsigned("height", height)?);
    if count > MAX_VIEWS {
        return Err(input_error(format!("{what}: {count} views; a scene may have at most {MAX_VIEWS}")));
    }
    raypatch::check_image_size(width, height).map_err(|reason| input_error(format!("{what}: {reason}")))?;
    let most = raypatch::MAX_SCENE_PIXELS;
    if count * width * height > most {
        return Err(input_error(format!(
            "{what}: {count} images of {width}x{height}; a scene holds at most {most} pixels"
        )));
    }
    Ok((count, width, height))
}
