//! The layout of a safetensors file, read from its header alone: the header is parsed and checked against
//! the length of the data section, so that a file's tensors can be read one at a time, only when asked for,
//! and a malformed file gets a message naming the tensor and the byte ranges at fault.

use std::collections::HashMap;

use safetensors::Dtype;
use serde_json::Value;

/// The largest header accepted: far above an official model's (~50 KB for ~400 tensors), a bound on what a
/// bad header makes the reader allocate and parse before anything is checked.
pub const MAX_HEADER_BYTES: u64 = 16 << 20;

/// One tensor of a file: its dtype, shape, and byte range in the data section.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorEntry {
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    /// `[start, end)` from the start of the data section.
    pub start: u64,
    pub end: u64,
}

impl TensorEntry {
    /// Bytes of data.
    pub fn bytes(&self) -> u64 {
        self.end - self.start
    }
}

/// A checked header: string metadata and the tensors by name.
#[derive(Debug, Default)]
pub struct Layout {
    pub metadata: HashMap<String, String>,
    pub tensors: Vec<(String, TensorEntry)>,
}

/// The header length in the first 8 bytes of a file of `file_len` bytes, checked against the file and
/// [`MAX_HEADER_BYTES`].
pub fn header_len(first8: &[u8], file_len: u64) -> Result<u64, String> {
    let Some(len_bytes) = first8.get(..8) else {
        return Err(format!("{file_len} bytes: too short for the 8-byte header length"));
    };
    let header_len = u64::from_le_bytes(len_bytes.try_into().expect("8 bytes"));
    let available = file_len - 8;
    if header_len > available {
        return Err(format!(
            "header length {header_len} is more than the {available} bytes after it (truncated file?)"
        ));
    }
    if header_len > MAX_HEADER_BYTES {
        return Err(format!("header length {header_len} is more than the {MAX_HEADER_BYTES} bytes accepted"));
    }
    Ok(header_len)
}

/// Parses the layout of a whole file held in memory; returns it and where the data section starts.
pub fn read_layout(bytes: &[u8]) -> Result<(Layout, usize), String> {
    let header_len = header_len(bytes, bytes.len() as u64)? as usize;
    let data_len = (bytes.len() - 8 - header_len) as u64;
    Ok((parse_header(&bytes[8..8 + header_len], data_len)?, 8 + header_len))
}

/// Parses a header and checks each tensor's dtype, and that the tensors' byte ranges match their shapes, lie
/// inside a data section of `data_len` bytes, do not overlap, and cover it; metadata values must be strings.
pub fn parse_header(header: &[u8], data_len: u64) -> Result<Layout, String> {
    let root: Value = serde_json::from_slice(header).map_err(|e| format!("invalid JSON in header: {e}"))?;
    let entries = root.as_object().ok_or("the header is not a JSON object")?;
    let mut layout = Layout::default();
    if let Some(metadata) = entries.get("__metadata__") {
        let map = metadata.as_object().ok_or("`__metadata__` is not a JSON object")?;
        for (key, value) in map {
            let text = value.as_str().ok_or_else(|| format!("metadata `{key}` is {value}, expected a string"))?;
            layout.metadata.insert(key.clone(), text.to_string());
        }
    }
    for (name, info) in entries.iter().filter(|(name, _)| name.as_str() != "__metadata__") {
        let dtype_value = info.get("dtype").cloned().unwrap_or(Value::Null);
        let dtype: Dtype = serde_json::from_value(dtype_value.clone())
            .map_err(|_| format!("tensor `{name}` has unknown dtype {dtype_value}"))?;
        let shape: Option<Vec<u64>> = info.get("shape").and_then(|s| serde_json::from_value(s.clone()).ok());
        let offsets: Option<[u64; 2]> = info.get("data_offsets").and_then(|o| serde_json::from_value(o.clone()).ok());
        let (Some(shape), Some([start, end])) = (shape, offsets) else {
            return Err(format!(
                "tensor `{name}`: expected a `shape` list and `data_offsets` [start, end] of integers"
            ));
        };
        if start > end || end > data_len {
            return Err(format!(
                "tensor `{name}` has data_offsets [{start}, {end}] outside the {data_len}-byte data section (truncated file?)"
            ));
        }
        let bits = shape.iter().try_fold(dtype.bitsize() as u64, |n, &d| n.checked_mul(d));
        if bits != Some(8 * (end - start)) {
            return Err(format!(
                "tensor `{name}`: shape {shape:?} of {dtype:?} does not fill data_offsets [{start}, {end}] ({} bytes)",
                end - start
            ));
        }
        // A zero-size tensor may declare any other dimensions: their product must still fit, so that code
        // multiplying them never overflows.
        let fits = shape.iter().filter(|&&d| d != 0).try_fold(1u64, |n, &d| n.checked_mul(d));
        let dims: Option<Vec<usize>> = fits.and_then(|_| shape.iter().map(|&d| usize::try_from(d).ok()).collect());
        let shape = dims.ok_or_else(|| format!("tensor `{name}`: shape {shape:?} is too large"))?;
        layout.tensors.push((name.clone(), TensorEntry { dtype, shape, start, end }));
    }
    let mut ranges: Vec<(u64, u64, &str)> =
        layout.tensors.iter().map(|(name, t)| (t.start, t.end, name.as_str())).collect();
    ranges.sort();
    for pair in ranges.windows(2) {
        let ((s0, e0, a), (s1, e1, b)) = (pair[0], pair[1]);
        if s1 < e0 {
            return Err(format!("tensors `{a}` [{s0}, {e0}] and `{b}` [{s1}, {e1}] overlap"));
        }
    }
    let mut covered = 0;
    for &(start, end, name) in &ranges {
        if start != covered {
            return Err(format!("bytes [{covered}, {start}) before tensor `{name}` belong to no tensor"));
        }
        covered = end;
    }
    if covered != data_len {
        return Err(format!("the tensors end at byte {covered} of the {data_len}-byte data section (trailing bytes)"));
    }
    Ok(layout)
}
