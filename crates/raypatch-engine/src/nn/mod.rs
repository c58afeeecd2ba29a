//! Modules that own their weights and record their ops, mirroring the official PyTorch modules: each is
//! built from a [`Vars`] path (which fetches and declares every weight it reads) and has a `forward` that
//! records into a [`Graph`](crate::graph::Graph). Model families (`models/`) are built from these.

pub mod conv;
pub mod gru;
pub mod linear;
pub mod norm;
pub mod posenc;
pub mod slot_attention;
pub mod transformer;
pub mod vars;

pub use conv::{Conv3x3, Resample};
pub use gru::GruCell;
pub use linear::{product_t, Linear};
pub use norm::LayerNorm;
pub use posenc::FourierEncoding;
pub use slot_attention::SlotAttention;
pub use transformer::{Transformer, TransformerDims};
pub use vars::{build, Data, GpuWeights, KeptF32, Layout, LoadOptions, Param, Source, Vars, WeightSet, WeightStorage};
