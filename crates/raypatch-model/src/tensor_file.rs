//! Reading safetensors files into f32 host tensors, with errors that name the file and the tensor.

use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::sync::Mutex;

use safetensors::Dtype;

use crate::error::ModelError;
use crate::layout::{Layout, TensorEntry};

/// The largest tensor read unless the caller sets another bound ([`TensorFile::set_max_tensor_bytes`]): above
/// the largest scene tensor the scene limits allow (2^26 pixels x 3 x 4 bytes), a bound on what one tensor of a
/// bad file can make the reader allocate.
pub const DEFAULT_MAX_TENSOR_BYTES: u64 = 1 << 30;

/// The metadata `format` value of model files (written by the converters, checked when a model is loaded).
pub const MODEL_FORMAT: &str = "raypatch-model/1";

/// What a file that is not safetensors looks like, from its first bytes.
fn sniff(bytes: &[u8]) -> Option<&'static str> {
    let kinds: [(&[u8], &str); 5] = [
        (b"\x89PNG", "a PNG image"),
        (b"\xff\xd8\xff", "a JPEG image"),
        (b"PK\x03\x04", "a zip archive (a PyTorch checkpoint? only models are read from checkpoints)"),
        (b"\x80", "a pickle (a legacy PyTorch checkpoint? only torch.save zip archives, PyTorch >= 1.6, are read)"),
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

fn is_integer(dtype: Dtype) -> bool {
    matches!(dtype, Dtype::U8 | Dtype::I8 | Dtype::U16 | Dtype::I16 | Dtype::U32 | Dtype::I32 | Dtype::I64)
}

/// The values of an integer tensor of `dtype` ([`is_integer`]), widened to i64.
fn integers(dtype: Dtype, bytes: &[u8]) -> Vec<i64> {
    fn le<const N: usize>(bytes: &[u8], f: impl Fn([u8; N]) -> i64) -> Vec<i64> {
        bytes.chunks_exact(N).map(|b| f(b.try_into().expect("chunk of N bytes"))).collect()
    }
    match dtype {
        Dtype::U8 => bytes.iter().map(|&b| i64::from(b)).collect(),
        Dtype::I8 => bytes.iter().map(|&b| i64::from(b as i8)).collect(),
        Dtype::U16 => le(bytes, |b| i64::from(u16::from_le_bytes(b))),
        Dtype::I16 => le(bytes, |b| i64::from(i16::from_le_bytes(b))),
        Dtype::U32 => le(bytes, |b| i64::from(u32::from_le_bytes(b))),
        Dtype::I32 => le(bytes, |b| i64::from(i32::from_le_bytes(b))),
        Dtype::I64 => le(bytes, i64::from_le_bytes),
        other => unreachable!("{other:?} is not an integer dtype"),
    }
}

/// Where a file's bytes are: read whole (a file given as bytes), or in the file, read a tensor at a time.
#[derive(Debug)]
enum Contents {
    Memory { bytes: Vec<u8>, data_start: u64 },
    File { file: Mutex<std::fs::File>, data_start: u64 },
}

/// A safetensors file whose header has been checked ([`crate::layout`]); each tensor's bytes are read only
/// when it is asked for, after its shape and size are checked.
#[derive(Debug)]
pub struct TensorFile {
    pub path: String,
    pub metadata: HashMap<String, String>,
    tensors: BTreeMap<String, TensorEntry>,
    contents: Contents,
    max_tensor_bytes: u64,
}

/// A format error `e` of a file that should have been `expected`, saying what its `first` bytes look like.
fn expected_instead(e: ModelError, first: &[u8], expected: &str) -> ModelError {
    match e {
        ModelError::Format { path, reason } => {
            let looks_like = sniff(first).map_or(String::new(), |kind| format!("it looks like {kind}; "));
            ModelError::Format { path, reason: format!("{reason} ({looks_like}expected {expected})") }
        }
        other => other,
    }
}

impl TensorFile {
    /// Opens a safetensors file (a regular file, see [`crate::files`]) and reads its header.
    pub fn open(path: &Path) -> Result<TensorFile, ModelError> {
        Self::open_sniffing(path).map_err(|(e, _)| e)
    }

    /// Like [`open`](Self::open), for a file that should be `expected` (e.g. "a model .safetensors file"):
    /// a file that is not safetensors at all is reported as what it looks like, and what was expected.
    pub fn open_as(path: &Path, expected: &str) -> Result<TensorFile, ModelError> {
        Self::open_sniffing(path).map_err(|(e, first)| expected_instead(e, &first, expected))
    }

    /// [`open_as`](Self::open_as) of file contents held in memory (a browser's files): the same messages.
    pub fn parse_as(path: &str, bytes: &[u8], expected: &str) -> Result<TensorFile, ModelError> {
        Self::parse(path, bytes).map_err(|e| expected_instead(e, &bytes[..bytes.len().min(8)], expected))
    }

    /// [`open`](Self::open), with the file's first bytes beside an error (to say what the file looks like).
    fn open_sniffing(path: &Path) -> Result<TensorFile, (ModelError, Vec<u8>)> {
        let shown = path.display().to_string();
        let io = |e: std::io::Error| (ModelError::Io { path: shown.clone(), source: e }, Vec::new());
        let (mut file, len) = crate::files::open_regular(path).map_err(|e| io(e.into()))?;
        let mut first8 = [0u8; 8];
        let got = read_up_to(&mut file, &mut first8).map_err(io)?;
        let format_err = |reason: String| (ModelError::Format { path: shown.clone(), reason }, first8[..got].to_vec());
        let header_len = crate::layout::header_len(&first8[..got], len).map_err(format_err)?;
        let mut header = vec![0u8; header_len as usize];
        file.read_exact(&mut header).map_err(io)?;
        let layout = crate::layout::parse_header(&header, len - 8 - header_len).map_err(format_err)?;
        let contents = Contents::File { file: Mutex::new(file), data_start: 8 + header_len };
        Ok(Self::new(shown, layout, contents))
    }

    /// Parses file contents held in memory; `path` names the file in errors.
    pub fn parse(path: &str, bytes: &[u8]) -> Result<TensorFile, ModelError> {
        Self::from_bytes(path, bytes.to_vec())
    }

    /// [`parse`](Self::parse), keeping `bytes` (a checkpoint made into a model file) without a copy.
    pub fn from_bytes(path: &str, bytes: Vec<u8>) -> Result<TensorFile, ModelError> {
        let format_err = |reason: String| ModelError::Format { path: path.to_string(), reason };
        let (layout, data_start) = crate::layout::read_layout(&bytes).map_err(format_err)?;
        let contents = Contents::Memory { bytes, data_start: data_start as u64 };
        Ok(Self::new(path.to_string(), layout, contents))
    }

    /// The whole file's bytes, where they are held in memory (a file given as bytes or read from a checkpoint).
    pub fn memory_bytes(&self) -> Option<&[u8]> {
        match &self.contents {
            Contents::Memory { bytes, .. } => Some(bytes),
            Contents::File { .. } => None,
        }
    }

    fn new(path: String, layout: Layout, contents: Contents) -> TensorFile {
        let tensors = layout.tensors.into_iter().collect();
        TensorFile { path, metadata: layout.metadata, tensors, contents, max_tensor_bytes: DEFAULT_MAX_TENSOR_BYTES }
    }

    /// The largest tensor this file will read (a tensor beyond it is an error naming it, before it is read).
    pub fn set_max_tensor_bytes(&mut self, bytes: u64) {
        self.max_tensor_bytes = bytes;
    }

    /// The tensor `key` and its bytes, read now: an error if it is absent or larger than the bound.
    fn read(&self, key: &str) -> Result<(&TensorEntry, Vec<u8>), ModelError> {
        let t = self.entry(key, &[])?;
        let bound = self.max_tensor_bytes;
        if t.bytes() > bound {
            let reason = format!("{} bytes, more than the {bound} bytes one tensor of this file may have", t.bytes());
            return Err(self.value_err(key, reason));
        }
        let bytes = match &self.contents {
            Contents::Memory { bytes, data_start } => {
                bytes[(data_start + t.start) as usize..(data_start + t.end) as usize].to_vec()
            }
            Contents::File { file, data_start } => {
                let mut data = vec![0u8; t.bytes() as usize];
                let mut file = file.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
                file.seek(SeekFrom::Start(data_start + t.start))
                    .and_then(|_| file.read_exact(&mut data))
                    .map_err(|e| ModelError::Io { path: self.path.clone(), source: e })?;
                data
            }
        };
        Ok((t, bytes))
    }

    fn entry(&self, key: &str, expected: &[usize]) -> Result<&TensorEntry, ModelError> {
        self.tensors.get(key).ok_or_else(|| ModelError::Missing {
            path: self.path.clone(),
            key: key.to_string(),
            expected: expected.to_vec(),
        })
    }

    fn value_err(&self, key: &str, reason: String) -> ModelError {
        ModelError::Value { path: self.path.clone(), key: key.to_string(), reason }
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

    /// Bytes of the tensor `key`, if present.
    pub fn tensor_bytes(&self, key: &str) -> Option<u64> {
        self.tensors.get(key).map(TensorEntry::bytes)
    }

    /// The F32 tensor `key`: an error if it is absent, has another dtype, or holds NaN or infinity.
    pub fn f32(&self, key: &str) -> Result<HostTensor, ModelError> {
        let dtype = self.entry(key, &[])?.dtype;
        if dtype != Dtype::F32 {
            return Err(ModelError::Dtype {
                path: self.path.clone(),
                key: key.to_string(),
                found: format!("{dtype:?}"),
            });
        }
        let (t, bytes) = self.read(key)?;
        let data: Vec<f32> = bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(self.value_err(key, format!("element {i} is {} (NaN or infinity)", data[i])));
        }
        Ok(HostTensor { shape: t.shape.clone(), data })
    }

    /// The integer tensor `key` (any integer dtype) with its shape: an error if it is absent or not integer.
    pub fn integers(&self, key: &str) -> Result<(Vec<usize>, Vec<i64>), ModelError> {
        let dtype = self.entry(key, &[])?.dtype;
        if !is_integer(dtype) {
            let found = format!("{dtype:?} (expected an integer dtype)");
            return Err(ModelError::Dtype { path: self.path.clone(), key: key.to_string(), found });
        }
        let (t, bytes) = self.read(key)?;
        Ok((t.shape.clone(), integers(dtype, &bytes)))
    }

    /// The values of the F64 tensor `key` (reference outputs of the golden files).
    pub fn f64_values(&self, key: &str) -> Result<Vec<f64>, ModelError> {
        let dtype = self.entry(key, &[])?.dtype;
        if dtype != Dtype::F64 {
            let found = format!("{dtype:?} (expected F64)");
            return Err(ModelError::Dtype { path: self.path.clone(), key: key.to_string(), found });
        }
        let (_, bytes) = self.read(key)?;
        Ok(bytes.chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))).collect())
    }

    /// Like [`f32`](Self::f32), also checking the shape (before reading).
    pub fn f32_shaped(&self, key: &str, expected: &[usize]) -> Result<HostTensor, ModelError> {
        let t = self.entry(key, expected)?;
        if t.shape != expected {
            return Err(ModelError::Shape {
                path: self.path.clone(),
                key: key.to_string(),
                expected: expected.to_vec(),
                found: t.shape.clone(),
            });
        }
        self.f32(key)
    }
}

/// Reads into `buf` until it is full or the file ends; the bytes read.
fn read_up_to(file: &mut std::fs::File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match file.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}
