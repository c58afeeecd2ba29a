//! What a Lightning checkpoint's pickle means: the state_dict's tensors (`torch._utils._rebuild_tensor_v2` of a
//! persistent storage, optionally wrapped as a parameter), and the model section of `hyper_parameters["cfg"]`
//! as the Python converter reads them (`tools/conversion/convert_checkpoint.py`).

use super::pickle::{kind, Id, Node, Pickle};
use super::pyjson;

/// The state_dict entries a model file keeps (DeFiNe's two heads have their own prefixes).
const KEPT_PREFIXES: [&str; 7] = [
    "encoder.",
    "decoder_att.",
    "decoder_rp.",
    "decoder_att_rgb.",
    "decoder_att_d.",
    "decoder_rp_rgb.",
    "decoder_rp_d.",
];

/// Whether the state_dict entry `name` belongs in the model file (BatchNorm's counters do not).
pub fn is_kept(name: &str) -> bool {
    KEPT_PREFIXES.iter().any(|p| name.starts_with(p)) && !name.ends_with("num_batches_tracked")
}

/// The element types read from storages.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Dtype {
    F32,
    F16,
    BF16,
    F64,
}

impl Dtype {
    pub fn size(self) -> usize {
        match self {
            Dtype::F32 => 4,
            Dtype::F16 | Dtype::BF16 => 2,
            Dtype::F64 => 8,
        }
    }
}

/// The dtype of a storage type, or torch's name for one that is not read.
fn storage_dtype(name: &str) -> Result<Dtype, String> {
    Ok(match name {
        "torch.FloatStorage" => Dtype::F32,
        "torch.HalfStorage" => Dtype::F16,
        "torch.BFloat16Storage" => Dtype::BF16,
        "torch.DoubleStorage" => Dtype::F64,
        other => {
            let torch_name = match other {
                "torch.LongStorage" => "torch.int64",
                "torch.IntStorage" => "torch.int32",
                "torch.ShortStorage" => "torch.int16",
                "torch.CharStorage" => "torch.int8",
                "torch.ByteStorage" => "torch.uint8",
                "torch.BoolStorage" => "torch.bool",
                "torch.ComplexFloatStorage" => "torch.complex64",
                "torch.ComplexDoubleStorage" => "torch.complex128",
                name => name,
            };
            return Err(format!("has dtype {torch_name}, expected a floating-point tensor (f32, f16, bf16 or f64)"));
        }
    })
}

/// A tensor of the state_dict: a strided view of a storage record.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorView {
    /// The storage's record name in the archive, `data/KEY`.
    pub record: String,
    pub dtype: Dtype,
    /// Elements in the storage, as its reference declares them.
    pub storage_len: u64,
    pub offset: u64,
    pub shape: Vec<usize>,
    pub stride: Vec<u64>,
}

impl TensorView {
    pub fn numel(&self) -> u64 {
        self.shape.iter().map(|&d| d as u64).product()
    }

    /// Whether the view reads its elements in storage order.
    pub fn contiguous(&self) -> bool {
        let mut expected = 1u64;
        for (&d, &s) in self.shape.iter().zip(&self.stride).rev() {
            if d != 1 && s != expected {
                return false;
            }
            expected *= d as u64;
        }
        true
    }
}

/// The most dimensions a tensor may have (PyTorch's own kernels take at most 25; models use 4).
pub const MAX_DIMS: usize = 64;

/// A non-negative integer below 2^63 of a tensor's rebuild arguments.
fn count(p: &Pickle, id: Id, what: &str) -> Result<u64, String> {
    match p.int(id) {
        Some(v) if v >= 0 => Ok(v as u64),
        _ => Err(format!("its {what} is {}, expected a non-negative integer", p.describe(id))),
    }
}

fn counts(p: &Pickle, id: Id, what: &str) -> Result<Vec<u64>, String> {
    let items = p.items(id).ok_or_else(|| format!("its {what} is {}, expected a tuple", p.describe(id)))?;
    items.iter().map(|&i| count(p, i, what)).collect()
}

/// The tensor the value `id` rebuilds, as a view of its storage; why not, as a phrase after the entry's name.
pub fn tensor_view(p: &Pickle, id: Id) -> Result<TensorView, String> {
    let mut id = id;
    // Parameters and tensor subclasses wrap the tensor's own rebuild (a bounded number of times).
    for _ in 0..4 {
        let Some((name, args)) = p.call_of(id) else {
            return Err(format!("is not a tensor but {}", p.describe(id)));
        };
        let args = p.items(args).unwrap_or_default();
        match name {
            "torch._utils._rebuild_tensor_v2" | "torch._utils._rebuild_tensor" => return rebuild(p, args),
            "torch._utils._rebuild_parameter" | "torch._utils._rebuild_parameter_with_state" if !args.is_empty() => {
                id = args[0];
            }
            "torch._tensor._rebuild_from_type_v2" if args.len() >= 3 => {
                let func = p.node(args[0]);
                if !matches!(func, Node::Global(f) if f == "torch._utils._rebuild_tensor_v2") {
                    return Err(format!("is a tensor subclass rebuilt by {}, which is not read", kind(func)));
                }
                return rebuild(p, p.items(args[2]).unwrap_or_default());
            }
            other => return Err(format!("is not a dense tensor but an object made by {other}")),
        }
    }
    Err("is a parameter nested too deep".into())
}

/// `_rebuild_tensor_v2(storage, storage_offset, size, stride, ...)`.
fn rebuild(p: &Pickle, args: &[Id]) -> Result<TensorView, String> {
    let [storage, offset, size, stride, ..] = args else {
        return Err(format!("is a tensor rebuilt from {} arguments, expected at least 4", args.len()));
    };
    let Node::Persistent(pid) = p.node(*storage) else {
        return Err(format!("is a tensor whose storage is {}, not a storage reference", p.describe(*storage)));
    };
    // ("storage", storage type, key, location, number of elements)
    let pid_items = p.items(*pid).unwrap_or_default();
    let [tag, storage_type, key, _location, storage_len] = pid_items else {
        return Err(format!("is a tensor whose storage reference is {}", p.describe(*pid)));
    };
    if p.str(*tag) != Some("storage") {
        return Err(format!("is a tensor whose storage reference is tagged {}", p.describe(*tag)));
    }
    let dtype = match p.node(*storage_type) {
        Node::Global(name) => storage_dtype(name)?,
        other => return Err(format!("is a tensor whose storage type is {}", kind(other))),
    };
    let key = p.str(*key).ok_or_else(|| format!("is a tensor whose storage key is {}", p.describe(*key)))?;
    if key.is_empty() || !key.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_') {
        return Err(format!("is a tensor whose storage key {key:?} is not a record name"));
    }
    // Bounded before the axes are read: each element's index is walked axis by axis (`materialise`), so axes
    // beyond any model's would cost their number per element, and a shared shape tuple costs a memo read.
    if let Some(axes) = p.items(*size).map(<[Id]>::len).filter(|&n| n > MAX_DIMS) {
        return Err(format!("is a tensor of {axes} dimensions, more than the {MAX_DIMS} read"));
    }
    let shape = counts(p, *size, "size")?;
    let stride = counts(p, *stride, "stride")?;
    if stride.len() != shape.len() {
        return Err(format!("is a tensor of size {shape:?} with stride {stride:?} (lengths differ)"));
    }
    let view = TensorView {
        record: format!("data/{key}"),
        dtype,
        storage_len: count(p, *storage_len, "storage size")?,
        offset: count(p, *offset, "storage offset")?,
        shape: shape.iter().map(|&d| usize::try_from(d).unwrap_or(usize::MAX)).collect(),
        stride,
    };
    check_bounds(&view)?;
    Ok(view)
}

/// The view's elements must lie inside its storage, and its size must be countable.
fn check_bounds(v: &TensorView) -> Result<(), String> {
    let outside = || {
        format!(
            "is a view (size {:?}, stride {:?}, offset {}) outside its {}-element storage",
            v.shape, v.stride, v.offset, v.storage_len
        )
    };
    let numel = v.shape.iter().try_fold(1u64, |n, &d| n.checked_mul(d as u64));
    let Some(numel) = numel else { return Err(format!("has size {:?}, too many elements", v.shape)) };
    if numel == 0 {
        return Ok(());
    }
    let last =
        v.shape.iter().zip(&v.stride).try_fold(v.offset, |at, (&d, &s)| at.checked_add((d as u64 - 1).checked_mul(s)?));
    match last {
        Some(last) if last < v.storage_len => Ok(()),
        _ => Err(outside()),
    }
}

/// Writes the view's elements, read from its storage's bytes (little-endian), as little-endian f32 into `out`
/// (4 bytes per element): in bulk where the view is contiguous, element by element otherwise.
pub fn materialise(v: &TensorView, storage: &[u8], out: &mut [u8]) {
    let size = v.dtype.size();
    let convert = |src: &[u8], dst: &mut [u8]| match v.dtype {
        Dtype::F32 => dst.copy_from_slice(src),
        Dtype::F16 => {
            for (s, d) in src.chunks_exact(2).zip(dst.chunks_exact_mut(4)) {
                d.copy_from_slice(&f16_to_f32(u16::from_le_bytes([s[0], s[1]])).to_le_bytes());
            }
        }
        Dtype::BF16 => {
            for (s, d) in src.chunks_exact(2).zip(dst.chunks_exact_mut(4)) {
                d.copy_from_slice(&[0, 0, s[0], s[1]]);
            }
        }
        Dtype::F64 => {
            for (s, d) in src.chunks_exact(8).zip(dst.chunks_exact_mut(4)) {
                let x = f64::from_le_bytes(s.try_into().expect("8 bytes"));
                d.copy_from_slice(&(x as f32).to_le_bytes());
            }
        }
    };
    let numel = v.numel() as usize;
    if v.contiguous() {
        let start = v.offset as usize * size;
        convert(&storage[start..start + numel * size], out);
        return;
    }
    let mut index = vec![0usize; v.shape.len()];
    for i in 0..numel {
        let at: u64 = v.offset + index.iter().zip(&v.stride).map(|(&k, &s)| k as u64 * s).sum::<u64>();
        let at = at as usize * size;
        convert(&storage[at..at + size], &mut out[4 * i..4 * i + 4]);
        for axis in (0..index.len()).rev() {
            index[axis] += 1;
            if index[axis] < v.shape[axis] {
                break;
            }
            index[axis] = 0;
        }
    }
}

/// An IEEE half as f32 (exact: every half is an f32).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = u32::from(h >> 15) << 31;
    let exponent = u32::from((h >> 10) & 0x1f);
    let mantissa = u32::from(h & 0x3ff);
    match exponent {
        // Zero and subnormals: mantissa x 2^-24, exact in f32.
        0 => {
            let magnitude = mantissa as f32 * f32::from_bits(0x3380_0000);
            f32::from_bits(sign | magnitude.to_bits())
        }
        0x1f => f32::from_bits(sign | 0x7f80_0000 | (mantissa << 13)),
        e => f32::from_bits(sign | ((e + 112) << 23) | (mantissa << 13)),
    }
}

/// The model section of the checkpoint's config, as the Python converter's JSON text of it: the official
/// train.py stores the run's `model` section as `hyper_parameters["cfg"]`; a whole run config there (with a
/// `model` section) is read too.
pub fn model_config(p: &Pickle) -> Result<String, String> {
    let missing = || "no model section in hyper_parameters[\"cfg\"] (not a RayPatchQuerying checkpoint?)".to_string();
    let hyper_parameters = p.get(p.root, "hyper_parameters").ok_or_else(missing)?;
    let omegaconf = |id: Id| match p.call_of(id) {
        Some((name, _)) if name.starts_with("omegaconf.") => Err(format!(
            "the checkpoint's config is an omegaconf object ({name}), which is not read here: convert it with \
             tools/conversion/convert_checkpoint.py"
        )),
        _ => Ok(()),
    };
    omegaconf(hyper_parameters)?;
    let cfg = p.get(hyper_parameters, "cfg").ok_or_else(missing)?;
    omegaconf(cfg)?;
    let section = if p.get(cfg, "base").is_some() { cfg } else { p.get(cfg, "model").ok_or_else(missing)? };
    omegaconf(section)?;
    if !matches!(p.node(section), Node::Dict(_)) {
        return Err(missing());
    }
    let (mut text, mut budget) = (String::new(), pyjson::MAX_CONFIG_VALUES);
    pyjson::config(p, section, "", 0, &mut budget, &mut text)?;
    Ok(text)
}
