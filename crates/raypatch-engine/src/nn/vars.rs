//! Weights by path, in the spirit of candle's `VarBuilder`: a module fetches each of its weights with
//! `vars.pp("to_out.1").matrix("weight", out, in)`, which declares the official name and shape and returns a
//! [`Param`] in the same call. Building a model's module tree over a [`LoadedModel`] checks the file (every
//! tensor present, of its shape, and nothing else); over [`Source::Declare`] it lists the tensors a config
//! implies, with no file and no GPU. The prepared host weights ([`WeightSet`]) go to the GPU once
//! (`weights.rs`: `WeightSet::upload`, which decides how each is stored); the float64 reference reads the same set.

use std::cell::RefCell;
use std::collections::BTreeSet;

use raypatch_model::{HostTensor, LoadedModel};

use crate::error::{EngineError, Result};
use crate::graph::Param;

/// What a module tree may read from a model file, each checked before a tensor is read: no tensor larger than
/// one GPU buffer (it could never be bound), and no more in all than the host can hold (the weights sit on the
/// host before they go to the GPU). Tensors the model does not fetch are never read and do not count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadLimits {
    pub tensor_bytes: u64,
    pub total_bytes: u64,
}

impl ReadLimits {
    /// No limit (files already in memory, tests).
    pub const NONE: ReadLimits = ReadLimits { tensor_bytes: u64::MAX, total_bytes: u64::MAX };
}

/// Where a module tree's weights come from.
pub enum Source<'a> {
    /// A model file: each fetch is checked against the file and the limits.
    File { model: &'a LoadedModel, limits: ReadLimits },
    /// No file: each fetch is recorded and returns zeros (to list the tensors a config implies).
    Declare,
}

/// How a prepared weight is laid out on the GPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// A `[rows, cols]` linear weight: may be stored as f16 (see `Precision`).
    Matrix { rows: usize, cols: usize },
    /// A `[1, len]` row: biases, norm scales.
    Row,
    /// A `[rows, cols]` tensor read as data, not as a linear weight (learned initial slots): always f32.
    Dense { rows: usize, cols: usize },
    /// A conv weight `[cout, cin, kernel, kernel]`, packed for `conv.wgsl` at upload (`pack_conv`).
    Conv { cout: usize, cin: usize, kernel: usize },
}

/// A weight ready for the GPU, in float64 when it was computed (BatchNorm folded) rather than read.
pub struct Prepared {
    /// The official name it was read from (the conv weight's, for a folded conv).
    pub name: String,
    pub layout: Layout,
    pub data: Data,
}

pub enum Data {
    F32(Vec<f32>),
    F64(Vec<f64>),
}

impl Data {
    pub fn to_f64(&self) -> Vec<f64> {
        match self {
            Data::F32(v) => v.iter().map(|&x| x as f64).collect(),
            Data::F64(v) => v.clone(),
        }
    }
    pub(crate) fn to_f32(&self) -> std::borrow::Cow<'_, [f32]> {
        match self {
            Data::F32(v) => v.as_slice().into(),
            Data::F64(v) => v.iter().map(|&x| x as f32).collect::<Vec<_>>().into(),
        }
    }
}

/// Everything a module tree fetched: the prepared weights (by [`Param`]) and the official names read.
#[derive(Default)]
pub struct WeightSet {
    pub prepared: Vec<Prepared>,
    /// Official `(name, shape)` of every tensor fetched, in fetch order.
    pub declared: Vec<(String, Vec<usize>)>,
}

impl WeightSet {
    pub fn get(&self, p: Param) -> &Prepared {
        &self.prepared[p.index()]
    }
}

struct Store<'a> {
    source: Source<'a>,
    set: WeightSet,
    /// Bytes read from the file so far.
    read: u64,
}

/// A path into the module tree, over a shared store.
#[derive(Clone)]
pub struct Vars<'s, 'a> {
    store: &'s RefCell<Store<'a>>,
    path: String,
}

/// Builds a module tree over `source` with `build`, and returns it with its weights. Over a file, also
/// checks that the tree fetched every tensor of the file.
pub fn build<T>(source: Source<'_>, build: impl FnOnce(&Vars) -> Result<T>) -> Result<(T, WeightSet)> {
    let file = match source {
        Source::File { model, .. } => Some(model),
        Source::Declare => None,
    };
    let store = RefCell::new(Store { source, set: WeightSet::default(), read: 0 });
    let root = Vars { store: &store, path: String::new() };
    let tree = build(&root)?;
    let set = store.into_inner().set;
    if let Some(file) = file {
        let fetched: BTreeSet<String> = set.declared.iter().map(|(name, _)| name.clone()).collect();
        file.check_all_fetched(&fetched)?;
    }
    Ok((tree, set))
}

impl Vars<'_, '_> {
    /// The sub-path `name` (dot-separated parts allowed): `vars.pp("transformer.layers").pp(l)`.
    pub fn pp(&self, name: impl std::fmt::Display) -> Self {
        let path = if self.path.is_empty() { name.to_string() } else { format!("{}.{name}", self.path) };
        Vars { store: self.store, path }
    }

    /// This path: the module's name in the official state_dict, and its ops' label.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Fetches the tensor `name` under this path, declaring its shape.
    pub fn tensor(&self, name: &str, shape: &[usize]) -> Result<HostTensor> {
        let key = self.pp(name).path;
        let mut store = self.store.borrow_mut();
        let tensor = match store.source {
            Source::File { model, limits } => {
                if let Some((_, bytes)) = model.tensor_size(&key).filter(|(found, _)| *found == shape) {
                    let read = store.read;
                    if bytes > limits.tensor_bytes {
                        let what = format!("{}: tensor `{key}`", model.path);
                        return Err(EngineError::TooLarge { what, bytes, max: limits.tensor_bytes });
                    }
                    if read.saturating_add(bytes) > limits.total_bytes {
                        return Err(EngineError::OutOfMemory(format!(
                            "{}: tensor `{key}` ({bytes} bytes) after {read} bytes of weights: more than the \
                             {} bytes of memory the host has free",
                            model.path, limits.total_bytes
                        )));
                    }
                    store.read = read + bytes;
                }
                model.weight(&key, shape)?
            }
            Source::Declare => HostTensor { shape: shape.to_vec(), data: vec![0.0; shape.iter().product()] },
        };
        store.set.declared.push((key, shape.to_vec()));
        Ok(tensor)
    }

    /// Adds a prepared weight to the set.
    pub fn prepared(&self, name: &str, layout: Layout, data: Data) -> Param {
        let mut store = self.store.borrow_mut();
        store.set.prepared.push(Prepared { name: self.pp(name).path, layout, data });
        Param::new(store.set.prepared.len() - 1)
    }

    /// A linear weight `name` of shape `shape` (`[out, in]`, or `[out, in, 1, 1]` for a 1×1 conv).
    pub fn matrix(&self, name: &str, shape: &[usize]) -> Result<Param> {
        let t = self.tensor(name, shape)?;
        let (rows, cols) = (shape[0], shape[1..].iter().product());
        Ok(self.prepared(name, Layout::Matrix { rows, cols }, Data::F32(t.data)))
    }

    /// A `[rows, cols]` tensor `name` read as data (kept f32 whatever the weight storage).
    pub fn dense(&self, name: &str, rows: usize, cols: usize) -> Result<Param> {
        let t = self.tensor(name, &[rows, cols])?;
        Ok(self.prepared(name, Layout::Dense { rows, cols }, Data::F32(t.data)))
    }

    /// A vector `name` of `len` values, kept as a `[1, len]` row.
    pub fn row(&self, name: &str, len: usize) -> Result<Param> {
        let t = self.tensor(name, &[len])?;
        Ok(self.prepared(name, Layout::Row, Data::F32(t.data)))
    }
}
