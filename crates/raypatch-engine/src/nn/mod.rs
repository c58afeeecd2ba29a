//! Modules that own their weights and record their ops, mirroring the official PyTorch modules: each is
//! built from a [`Vars`] path (which fetches and declares every weight it reads) and has a `forward` that
//! records into a [`Graph`](crate::graph::Graph). Model families (`models/`) are built from these.

pub mod conv;
pub mod gru;
pub mod linear;
pub mod norm;
pub mod perceiver;
pub mod pool;
pub mod posenc;
pub mod resnet;
pub mod slot_attention;
pub mod transformer;
pub mod vars;

pub use conv::{Conv2d, ConvSpec};
pub use gru::GruCell;
pub use linear::{product_t, Linear};
pub use norm::LayerNorm;
pub use perceiver::{KeysValues, PerceiverDims, PerceiverLayer, Values};
pub use pool::MaxPool2d;
pub use posenc::FourierEncoding;
pub use resnet::ResNet18;
pub use slot_attention::SlotAttention;
pub use transformer::{Transformer, TransformerDims};
pub use vars::{build, Data, Layout, ReadLimits, Source, Vars, WeightSet};
