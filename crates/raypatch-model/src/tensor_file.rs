//! Reading safetensors files into f32 host tensors, with errors that name the file and the tensor.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use safetensors::{Dtype, SafeTensors};

use crate::error::ModelError;

/// The largest safetensors file read (16 GiB): far above any model this engine can hold on one GPU, and a
/// bound on what a bad path can make it allocate.
pub const MAX_TENSOR_FILE_BYTES: u64 = 16 << 30;

/// What a file that is not safetensors looks like, from its first bytes.
fn sniff(bytes: &[u8]) -> Option<&'static str> {
    let kinds: [(&[u8], &str); 5] = [
        (b"\x89PNG", "a PNG image"),
        (b"\xff\xd8\xff", "a JPEG image"),
        (b"PK\x03\x04", "a zip archive (a PyTorch checkpoint? convert it with tools/convert_checkpoint.py)"),
        (b"\x80", "a pickle (a PyTorch checkpoint? convert it with tools/convert_checkpoint.py)"),
        (b"{", "a JSON file"),
    ];
    kinds.iter().find(|(magic, _)| bytes.starts_with(magic)).map(|(_, kind)| *kind)
}

/// A row-major f32 tensor on the host.
#[derive(Clone, Debug, PartialEq)]
pub struct HostTensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// One tensor as found in the file; `data` is decoded only for F32, `integers` only for integer dtypes.
#[derive(Clone, Debug)]
struct FileTensor {
    shape: Vec<usize>,
    dtype: Dtype,
    data: Option<Vec<f32>>,
    integers: Option<Vec<i64>>,
    wide: Option<Vec<f64>>,
}

/// The values of an integer tensor, widened to i64 (None for other dtypes).
fn integers(dtype: Dtype, bytes: &[u8]) -> Option<Vec<i64>> {
    fn le<const N: usize>(bytes: &[u8], f: impl Fn([u8; N]) -> i64) -> Vec<i64> {
        bytes.chunks_exact(N).map(|b| f(b.try_into().expect("chunk of N bytes"))).collect()
    }
    Some(match dtype {
        Dtype::U8 => bytes.iter().map(|&b| i64::from(b)).collect(),
        Dtype::I8 => bytes.iter().map(|&b| i64::from(b as i8)).collect(),
        Dtype::U16 => le(bytes, |b| i64::from(u16::from_le_bytes(b))),
        Dtype::I16 => le(bytes, |b| i64::from(i16::from_le_bytes(b))),
        Dtype::U32 => le(bytes, |b| i64::from(u32::from_le_bytes(b))),
        Dtype::I32 => le(bytes, |b| i64::from(i32::from_le_bytes(b))),
        Dtype::I64 => le(bytes, i64::from_le_bytes),
        _ => return None,
    })
}

/// A parsed safetensors file.
#[derive(Debug)]
pub struct TensorFile {
    pub path: String,
    pub metadata: HashMap<String, String>,
    tensors: BTreeMap<String, FileTensor>,
}

impl TensorFile {
    /// Reads and parses a safetensors file (a regular file, see [`crate::files`]).
    pub fn open(path: &Path) -> Result<TensorFile, ModelError> {
        let shown = path.display().to_string();
        Self::parse(&shown, &Self::read(path)?)
    }

    /// Like [`open`](Self::open), for a file that should be `expected` (e.g. "a model .safetensors file"):
    /// a file that is not safetensors at all is reported as what it looks like, and what was expected.
    pub fn open_as(path: &Path, expected: &str) -> Result<TensorFile, ModelError> {
        let bytes = Self::read(path)?;
        Self::parse(&path.display().to_string(), &bytes).map_err(|e| match e {
            ModelError::Format { path, reason } => {
                let looks_like = sniff(&bytes).map_or(String::new(), |kind| format!("it looks like {kind}; "));
                ModelError::Format { path, reason: format!("{reason} ({looks_like}expected {expected})") }
            }
            other => other,
        })
    }

    fn read(path: &Path) -> Result<Vec<u8>, ModelError> {
        crate::files::read_regular(path, MAX_TENSOR_FILE_BYTES)
            .map_err(|e| ModelError::Io { path: path.display().to_string(), source: e.into() })
    }

    /// Parses file contents; `path` names the file in errors. [`check_layout`](crate::layout::check_layout)
    /// and the safetensors crate check the header length, the JSON, the dtypes, and that the tensors' byte
    /// ranges tile the data section exactly.
    pub fn parse(path: &str, bytes: &[u8]) -> Result<TensorFile, ModelError> {
        let format_err = |reason: String| ModelError::Format { path: path.to_string(), reason };
        crate::layout::check_layout(bytes).map_err(format_err)?;
        let (_, header) = SafeTensors::read_metadata(bytes).map_err(|e| format_err(e.to_string()))?;
        let st = SafeTensors::deserialize(bytes).map_err(|e| format_err(e.to_string()))?;
        let metadata = header.metadata().clone().unwrap_or_default();
        let mut tensors = BTreeMap::new();
        for (name, view) in st.tensors() {
            let data = (view.dtype() == Dtype::F32)
                .then(|| view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect());
            let integers = integers(view.dtype(), view.data());
            let wide = (view.dtype() == Dtype::F64).then(|| {
                view.data().chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))).collect()
            });
            let shape = view.shape().to_vec();
            tensors.insert(name, FileTensor { shape, dtype: view.dtype(), data, integers, wide });
        }
        Ok(TensorFile { path: path.to_string(), metadata, tensors })
    }

    pub fn contains(&self, key: &str) -> bool {
        self.tensors.contains_key(key)
    }

    pub fn keys(&self) -> impl Iterator<Item = &str> {
        self.tensors.keys().map(String::as_str)
    }

    pub fn shape(&self, key: &str) -> Option<&[usize]> {
        self.tensors.get(key).map(|t| t.shape.as_slice())
    }

    /// The F32 tensor `key`: an error if it is absent, has another dtype, or holds NaN or infinity.
    pub fn f32(&self, key: &str) -> Result<HostTensor, ModelError> {
        let t = self.tensors.get(key).ok_or_else(|| ModelError::Missing {
            path: self.path.clone(),
            key: key.to_string(),
            expected: Vec::new(),
        })?;
        let data = t.data.as_ref().ok_or_else(|| ModelError::Dtype {
            path: self.path.clone(),
            key: key.to_string(),
            found: format!("{:?}", t.dtype),
        })?;
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Value {
                path: self.path.clone(),
                key: key.to_string(),
                reason: format!("element {i} is {} (NaN or infinity)", data[i]),
            });
        }
        Ok(HostTensor { shape: t.shape.clone(), data: data.clone() })
    }

    /// The integer tensor `key` (any integer dtype) with its shape: an error if it is absent or not integer.
    pub fn integers(&self, key: &str) -> Result<(Vec<usize>, Vec<i64>), ModelError> {
        let t = self.tensors.get(key).ok_or_else(|| ModelError::Missing {
            path: self.path.clone(),
            key: key.to_string(),
            expected: Vec::new(),
        })?;
        let values = t.integers.as_ref().ok_or_else(|| ModelError::Dtype {
            path: self.path.clone(),
            key: key.to_string(),
            found: format!("{:?} (expected an integer dtype)", t.dtype),
        })?;
        Ok((t.shape.clone(), values.clone()))
    }

    /// The values of the F64 tensor `key` (reference outputs of the golden files).
    pub fn f64_values(&self, key: &str) -> Result<Vec<f64>, ModelError> {
        let t = self.tensors.get(key).ok_or_else(|| ModelError::Missing {
            path: self.path.clone(),
            key: key.to_string(),
            expected: Vec::new(),
        })?;
        t.wide.clone().ok_or_else(|| ModelError::Dtype {
            path: self.path.clone(),
            key: key.to_string(),
            found: format!("{:?} (expected F64)", t.dtype),
        })
    }

    /// Like [`f32`](Self::f32), also checking the shape.
    pub fn f32_shaped(&self, key: &str, expected: &[usize]) -> Result<HostTensor, ModelError> {
        let shape = self.shape(key).ok_or_else(|| ModelError::Missing {
            path: self.path.clone(),
            key: key.to_string(),
            expected: expected.to_vec(),
        })?;
        if shape != expected {
            return Err(ModelError::Shape {
                path: self.path.clone(),
                key: key.to_string(),
                expected: expected.to_vec(),
                found: shape.to_vec(),
            });
        }
        self.f32(key)
    }
}
