//! The globals a checkpoint's pickle may name: the ones PyTorch's weights-only unpickler and the Python converter
//! accept. Naming any other is refused, since loading such a pickle with PyTorch could run code.

/// The dict subclasses and dict-like objects read as dicts: Lightning's AttributeDict under each name it has
/// had, OrderedDict (torch's state_dict), defaultdict and argparse.Namespace (whose `BUILD` state holds its
/// attributes).
pub const DICT_LIKE: [&str; 8] = [
    "collections.OrderedDict",
    "collections.defaultdict",
    "builtins.dict",
    "argparse.Namespace",
    "lightning_fabric.utilities.data.AttributeDict",
    "lightning.fabric.utilities.data.AttributeDict",
    "pytorch_lightning.utilities.parsing.AttributeDict",
    "lightning.pytorch.utilities.parsing.AttributeDict",
];

/// Whether a global may appear: what torch's weights-only unpickler allows by default (tensor rebuilds,
/// storage and tensor types, dtypes, a few builtins) and what the Python converter adds (config objects of
/// trainers: Lightning, omegaconf, argparse, pathlib, numpy scalars). Everything else would run code.
pub fn allowed(name: &str) -> bool {
    const EXACT: [&str; 22] = [
        "collections.Counter",
        "torch.nn.parameter.Parameter",
        "torch.serialization._get_layout",
        "torch.Size",
        "torch.device",
        "torch._tensor._rebuild_from_type_v2",
        "_codecs.encode",
        "builtins.bytearray",
        "builtins.set",
        "builtins.frozenset",
        "builtins.complex",
        "builtins.list",
        "builtins.tuple",
        "builtins.str",
        "builtins.int",
        "builtins.float",
        "builtins.bool",
        "typing.Any",
        "numpy.core.multiarray.scalar",
        "numpy._core.multiarray.scalar",
        "numpy.dtype",
        "torch.strided",
    ];
    let (module, item) = name.rsplit_once('.').unwrap_or(("", name));
    DICT_LIKE.contains(&name)
        || EXACT.contains(&name)
        || (module == "torch._utils" && item.starts_with("_rebuild_"))
        || (module == "torch" && (item.ends_with("Storage") || item.ends_with("Tensor") || is_dtype(item)))
        || (matches!(module, "pathlib" | "pathlib._local") && item.ends_with("Path"))
        || module == "numpy.dtypes"
        || module.split('.').next() == Some("omegaconf")
}

fn is_dtype(item: &str) -> bool {
    const DTYPES: [&str; 6] = ["float", "bfloat", "int", "uint", "bool", "complex"];
    DTYPES.iter().any(|kind| item.starts_with(kind)) || matches!(item, "half" | "double" | "long" | "short" | "cfloat")
}

/// Whether a call of `name` makes a dict that later opcodes fill.
pub fn dict_like(name: &str) -> bool {
    DICT_LIKE.contains(&name)
}
