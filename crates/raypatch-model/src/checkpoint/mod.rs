//! Official Lightning checkpoints (`.ckpt`, a `torch.save` zip archive) read without Python: the archive
//! ([`zip`]), its pickle interpreted without executing anything ([`pickle`]), the state_dict's tensors and the
//! config decoded ([`torch`]), and the result made into the bytes of the model file that
//! `tools/conversion/convert_checkpoint.py` writes for it (the same tensors as contiguous f32, the same
//! metadata, the same header: [`pyjson`]). A checkpoint is then read as that model file is, so the config goes
//! through the same key lists and family descriptors, and every tensor through the same checks.

pub mod globals;
pub mod pickle;
pub mod pyjson;
pub mod torch;
pub mod zip;

#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use crate::error::ModelError;
use crate::tensor_file::{TensorFile, MODEL_FORMAT};
use torch::TensorView;

/// How every zip archive, and so every checkpoint, starts.
pub const ZIP_MAGIC: &[u8; 4] = b"PK\x03\x04";
/// The largest `data.pkl` read: an official checkpoint's is about 100 KB.
pub const MAX_PICKLE_BYTES: u64 = 64 << 20;
/// At most this many state_dict problems are counted in the one-line error.
const MAX_PROBLEMS: usize = 1000;

/// Whether a file that starts with `first` is a zip archive (a checkpoint, if it is a model).
pub fn is_checkpoint(first: &[u8]) -> bool {
    first.starts_with(ZIP_MAGIC)
}

fn checkpoint_err(path: &str) -> impl Fn(String) -> ModelError + '_ {
    move |reason| ModelError::Checkpoint { path: path.to_string(), reason }
}

/// The file at `path` as a model file if it is a checkpoint (a zip archive by its first bytes, whatever its
/// name), or None if it is not one.
pub fn open_if_checkpoint(path: &Path) -> Result<Option<TensorFile>, ModelError> {
    let shown = path.display().to_string();
    let io = |e: std::io::Error| ModelError::Io { path: shown.clone(), source: e };
    let (mut file, len) = crate::files::open_regular(path).map_err(|e| io(e.into()))?;
    let mut first = [0u8; 4];
    let got = file.by_ref().take(4).read(&mut first).map_err(io)?;
    if !is_checkpoint(&first[..got]) {
        return Ok(None);
    }
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    let source = path.file_name().map_or(shown.clone(), |n| n.to_string_lossy().into_owned());
    let bytes = convert(BufReader::new(file), len, &source).map_err(checkpoint_err(&shown))?;
    TensorFile::from_bytes(&shown, bytes).map(Some)
}

/// [`open_if_checkpoint`] of a file's bytes; `name` names it in messages and in the `source` metadata.
pub fn parse_if_checkpoint(name: &str, bytes: &[u8]) -> Result<Option<TensorFile>, ModelError> {
    if !is_checkpoint(bytes) {
        return Ok(None);
    }
    let source = Path::new(name).file_name().map_or(name.to_string(), |n| n.to_string_lossy().into_owned());
    let converted = convert(std::io::Cursor::new(bytes), bytes.len() as u64, &source).map_err(checkpoint_err(name))?;
    TensorFile::from_bytes(name, converted).map(Some)
}

/// The model file of the checkpoint of `len` bytes in `reader`, as the Python converter writes it for an input
/// named `source`; or why not, as one phrase.
pub fn convert<R: Read + Seek>(reader: R, len: u64, source: &str) -> Result<Vec<u8>, String> {
    let mut archive = zip::Archive::open(reader, len)?;
    if archive.has("byteorder") {
        let order = archive.read("byteorder", 16)?;
        if order != b"little" {
            return Err(format!(
                "byteorder {:?}: only little-endian checkpoints are read",
                String::from_utf8_lossy(&order)
            ));
        }
    }
    let data = archive.read("data.pkl", MAX_PICKLE_BYTES)?;
    let p = pickle::interpret(&data).map_err(|e| format!("{}: {e}", archive.record("data.pkl")))?;
    let tensors = state_dict(&p)?;
    let config = torch::model_config(&p)?;
    let elements: u64 = tensors.values().map(TensorView::numel).sum();
    if elements > archive.inflated {
        return Err(format!(
            "its model tensors have {elements} elements, more than the {} bytes of data in the checkpoint \
             (expanded or overlapping views?)",
            archive.inflated
        ));
    }
    let metadata = [("config", config.as_str()), ("format", MODEL_FORMAT), ("source", source)];
    model_file(&tensors, &metadata, |record, bytes| archive.read(record, bytes))
}

/// The kept tensors of the checkpoint's state_dict by name; an error names the first bad entry (and counts
/// the others).
pub fn state_dict(p: &pickle::Pickle) -> Result<BTreeMap<String, TensorView>, String> {
    let state_dict = p.get(p.root, "state_dict").filter(|&id| matches!(p.node(id), pickle::Node::Dict(_)));
    let state_dict = state_dict.ok_or("no state_dict (not a Lightning checkpoint?)")?;
    let mut tensors = BTreeMap::new();
    let mut problems: Vec<String> = Vec::new();
    for (key, value) in p.dict_items(state_dict).expect("a dict") {
        let Some(name) = p.str(key) else {
            problems.push(format!("state_dict key {} is not a string", p.describe(key)));
            continue;
        };
        if !torch::is_kept(name) {
            continue;
        }
        match torch::tensor_view(p, value) {
            Ok(view) => {
                tensors.insert(name.to_string(), view);
            }
            Err(why) => problems.push(format!("state_dict entry {} {why}", pickle::quoted(name))),
        }
        if problems.len() >= MAX_PROBLEMS {
            break;
        }
    }
    match problems.len() {
        0 => Ok(tensors),
        1 => Err(problems.swap_remove(0)),
        n => Err(format!("{} (and {} more problems)", problems[0], n - 1)),
    }
}

/// The bytes of a safetensors file of `tensors` (as f32, in name order) and `metadata` (in key order), laid
/// out as `tools/reference/safetensors_io.py` lays it out; `read(record, bytes)` gives a storage record of
/// that many bytes, read once for all the tensors that view it.
fn model_file(
    tensors: &BTreeMap<String, TensorView>,
    metadata: &[(&str, &str)],
    mut read: impl FnMut(&str, u64) -> Result<Vec<u8>, String>,
) -> Result<Vec<u8>, String> {
    let mut header = String::from("{\"__metadata__\":{");
    for (i, (key, value)) in metadata.iter().enumerate() {
        if i > 0 {
            header.push(',');
        }
        pyjson::string(key, &mut header);
        header.push(':');
        pyjson::string(value, &mut header);
    }
    header.push('}');
    let mut spans = Vec::with_capacity(tensors.len());
    let mut offset = 0u64;
    for (name, view) in tensors {
        let end = offset + 4 * view.numel();
        header.push(',');
        pyjson::string(name, &mut header);
        let shape: Vec<String> = view.shape.iter().map(usize::to_string).collect();
        header.push_str(&format!(
            ":{{\"dtype\":\"F32\",\"shape\":[{}],\"data_offsets\":[{offset},{end}]}}",
            shape.join(",")
        ));
        spans.push((offset as usize, end as usize));
        offset = end;
    }
    header.push('}');
    header.push_str(&" ".repeat((8 - header.len() % 8) % 8));
    let start = 8 + header.len();
    let mut bytes = Vec::with_capacity(start + offset as usize);
    bytes.extend_from_slice(&(header.len() as u64).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.resize(start + offset as usize, 0);
    let views: Vec<&TensorView> = tensors.values().collect();
    let mut by_record: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, view) in views.iter().enumerate() {
        by_record.entry(view.record.as_str()).or_default().push(i);
    }
    for (record, users) in by_record {
        let view = views[users[0]];
        let storage = read(record, view.storage_len * view.dtype.size() as u64)?;
        for i in users {
            let other = views[i];
            let expected = other.storage_len * other.dtype.size() as u64;
            if expected != storage.len() as u64 {
                return Err(format!(
                    "storage {record} is {} bytes, but a tensor reads it as {} elements of {} bytes",
                    storage.len(),
                    other.storage_len,
                    other.dtype.size()
                ));
            }
            let (s, e) = spans[i];
            torch::materialise(other, &storage, &mut bytes[start + s..start + e]);
        }
    }
    Ok(bytes)
}
