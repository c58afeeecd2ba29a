//! The layout of a safetensors file, checked before the safetensors crate parses it, so that a malformed file
//! gets a message naming the tensor and the byte ranges at fault (the crate rejects the same files, with less
//! specific messages for some of them).

use safetensors::Dtype;
use serde_json::Value;

/// Checks the header length, each tensor's dtype, and that the tensors' byte ranges match their shapes, lie
/// inside the data section, do not overlap, and cover it. Returns the reason the layout is wrong.
pub fn check_layout(bytes: &[u8]) -> Result<(), String> {
    let Some(len_bytes) = bytes.get(..8) else {
        return Err(format!("{} bytes: too short for the 8-byte header length", bytes.len()));
    };
    let header_len = u64::from_le_bytes(len_bytes.try_into().expect("8 bytes"));
    let available = bytes.len() as u64 - 8;
    if header_len > available {
        return Err(format!(
            "header length {header_len} is more than the {available} bytes after it (truncated file?)"
        ));
    }
    let header = &bytes[8..8 + header_len as usize];
    let data_len = available - header_len;
    let root: Value = serde_json::from_slice(header).map_err(|e| format!("invalid JSON in header: {e}"))?;
    let entries = root.as_object().ok_or("the header is not a JSON object")?;

    let mut ranges: Vec<(u64, u64, &str)> = Vec::new();
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
        ranges.push((start, end, name));
    }
    ranges.sort();
    let mut covered = 0;
    for pair in ranges.windows(2) {
        let ((s0, e0, a), (s1, e1, b)) = (pair[0], pair[1]);
        if s1 < e0 {
            return Err(format!("tensors `{a}` [{s0}, {e0}] and `{b}` [{s1}, {e1}] overlap"));
        }
    }
    for &(start, end, name) in &ranges {
        if start != covered {
            return Err(format!("bytes [{covered}, {start}) before tensor `{name}` belong to no tensor"));
        }
        covered = end;
    }
    if covered != data_len {
        return Err(format!("the tensors end at byte {covered} of the {data_len}-byte data section (trailing bytes)"));
    }
    Ok(())
}
