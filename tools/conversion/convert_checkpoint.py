"""Converts an official RayPatchQuerying Lightning checkpoint (SRT / RP-SRT, OSRT / RP-OSRT or DeFiNe / RP-DeFiNe:
config base srt, osrt or define) into a raypatch model file (docs/FORMATS.md).

    python tools/conversion/convert_checkpoint.py IN.ckpt OUT.safetensors

Keeps the `encoder.`, `decoder_att.` and `decoder_rp.` tensors (DeFiNe: `decoder_att_rgb.`, `decoder_att_d.`,
`decoder_rp_rgb.`, `decoder_rp_d.`) as float32, drops `num_batches_tracked` and everything else (`val_metrics.…`,
`loss_colour.…`), checks every name and shape against the reference model built from the checkpoint's config, and
stores the config's model section as metadata. Exit code 2 and no output file on any error.

A checkpoint is untrusted input. It must be a zip archive as torch.save writes it (PyTorch >= 1.6) whose entries
do not inflate to more than 4 times the file's size + 64 MiB, and it is unpickled with torch.load(weights_only=True):
tensors, dicts, lists, tuples, strings, numbers, booleans, None, plus the config objects other trainers store
(omegaconf DictConfig / ListConfig when omegaconf is installed, Lightning's AttributeDict, argparse.Namespace,
pathlib paths, numpy scalars and dtypes). Any other object is refused unread, naming it.
"""

import argparse
import contextlib
import functools
import json
import math
import os
import pathlib
import pickle
import reprlib
import stat
import sys
import typing
import warnings
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from reference.raypatch_reference import build_model  # noqa: E402
from reference.safetensors_io import save_safetensors  # noqa: E402

MODEL_FORMAT = "raypatch-model/1"
KEPT_PREFIXES = ("encoder.", "decoder_att.", "decoder_rp.",
                 "decoder_att_rgb.", "decoder_att_d.", "decoder_rp_rgb.", "decoder_rp_d.")
MAX_PROBLEM_LINES = 20
# A checkpoint's zip entries may inflate to at most MAX_INFLATION x the file's size + INFLATION_SLACK bytes
# (torch.save stores entries uncompressed, so its own archives inflate by a factor of 1).
MAX_INFLATION = 4
INFLATION_SLACK = 64 << 20
# Building the reference model from the checkpoint's config may register at most this many modules,
# parameters and buffers per state_dict entry (the official configs register 1.8 to 2.5), plus a constant.
REGISTRATIONS_PER_ENTRY, REGISTRATIONS_SLACK = 8, 1024
ZIP_MAGIC = b"PK\x03\x04"
# The dict subclass Lightning keeps hyperparameters in, under the names it has had; it is read as a plain dict
# (the weights-only unpickler fills only exact dicts), so Lightning need not be installed.
ATTRIBUTE_DICT_NAMES = ("lightning_fabric.utilities.data.AttributeDict",
                        "lightning.fabric.utilities.data.AttributeDict",
                        "pytorch_lightning.utilities.parsing.AttributeDict",
                        "lightning.pytorch.utilities.parsing.AttributeDict")


class ConversionError(Exception):
    """A user-facing reason why a checkpoint cannot be converted: one line per problem."""


def one_line(text):
    """A foreign (exception) message as one line."""
    return "; ".join(line.strip() for line in str(text).splitlines() if line.strip()) or "(no message)"


# --- loading ----------------------------------------------------------------------------------------------------


def defaultdict_as_dict(default_factory=None, *args):
    """Stands in for collections.defaultdict (omegaconf keeps an empty one in its metadata): a plain dict, the only
    mapping kind besides OrderedDict and Counter that the weights-only unpickler fills."""
    return {}


@functools.lru_cache(maxsize=1)
def allowed_globals():
    """The (object, "module.Name") pairs that torch.load(weights_only=True) may build besides its defaults."""
    pairs = [(dict, name) for name in ATTRIBUTE_DICT_NAMES]
    pairs += [(argparse.Namespace, "argparse.Namespace"), (defaultdict_as_dict, "collections.defaultdict"),
              (typing.Any, "typing.Any")]
    pairs += [(kind, f"builtins.{kind.__name__}") for kind in (dict, list, tuple, str, int, float, bool)]
    # Paths (pathlib._local is where Python 3.13 keeps them); a Windows path is read as a pure one.
    for module in ("pathlib", "pathlib._local"):
        pairs += [(kind, f"{module}.{kind.__name__}")
                  for kind in (pathlib.PurePath, pathlib.PurePosixPath, pathlib.PureWindowsPath, pathlib.Path,
                               pathlib.PosixPath)]
        pairs.append((pathlib.PureWindowsPath, f"{module}.WindowsPath"))
    with contextlib.suppress(ImportError):
        import numpy
        scalar = (numpy._core if hasattr(numpy, "_core") else numpy.core).multiarray.scalar
        pairs += [(scalar, "numpy.core.multiarray.scalar"), (scalar, "numpy._core.multiarray.scalar"),
                  (numpy.dtype, "numpy.dtype")]
        # The dtype classes of booleans and numbers (a dtype is rebuilt as numpy.dtype, then given its state).
        pairs += [(type(numpy.dtype(code)), f"numpy.dtypes.{type(numpy.dtype(code)).__name__}")
                  for code in "?bBhHiIlLqQefdgFDG"]
    with contextlib.suppress(ImportError):
        import omegaconf
        from omegaconf import base, nodes
        kinds = [omegaconf.DictConfig, omegaconf.ListConfig, base.ContainerMetadata, base.Metadata]
        kinds += [kind for kind in vars(nodes).values()
                  if isinstance(kind, type) and issubclass(kind, nodes.ValueNode)]
        pairs += [(kind, f"{kind.__module__}.{kind.__qualname__}") for kind in kinds]
    return pairs


def omegaconf_installed():
    try:
        import omegaconf  # noqa: F401
    except ImportError:
        return False
    return True


def refusal(names):
    """The one-line reason for refusing a checkpoint that holds the pickle globals `names`."""
    names = sorted(names)
    configs = [name for name in names if name.split(".")[0] == "omegaconf"]
    if configs and len(configs) == len(names) and not omegaconf_installed():
        configs.sort(key=lambda name: (not name.endswith("Config"), name))  # DictConfig, ListConfig first
        return (f"the checkpoint's config is an omegaconf object ({', '.join(configs[:2])}, ...): pip install "
                "omegaconf to read it")
    shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return (f"refusing to unpickle {shown}: not a tensor or a plain container/config object (unpickling it could run "
            "code)")


def inspect_archive(file, file_size):
    """Checks, from the zip central directory only, that the checkpoint's entries inflate to a bounded size;
    returns that size in bytes."""
    try:
        archive = zipfile.ZipFile(file)
    except Exception as error:  # zipfile raises several kinds on a damaged archive
        raise ConversionError(f"not a readable zip archive ({type(error).__name__}: {one_line(error)})")
    with archive:
        entries = archive.infolist()
        total = sum(entry.file_size for entry in entries)
        limit = MAX_INFLATION * file_size + INFLATION_SLACK
        if total > limit:
            raise ConversionError(f"its zip entries would inflate to {total} bytes, more than {MAX_INFLATION} times "
                                  f"its {file_size} bytes + {INFLATION_SLACK >> 20} MiB ({limit} bytes): refused "
                                  "(a decompression bomb?)")
        methods = {entry.compress_type for entry in entries} - {zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED}
        if methods:
            raise ConversionError(f"zip entries compressed with method {sorted(methods)}; torch.load reads stored "
                                  "or deflated entries only")
        # PyTorch's zip reader reads the central directory where the end record says it is; zipfile reads it just
        # before the end record. Only when both agree are the sizes checked here the ones torch.load allocates.
        file.seek(0)
        end = zipfile._EndRecData(file) if hasattr(zipfile, "_EndRecData") else None
        if end is not None and (getattr(archive, "start_dir", end[zipfile._ECD_OFFSET]) != end[zipfile._ECD_OFFSET]
                                or end[zipfile._ECD_ENTRIES_TOTAL] != len(entries)):
            raise ConversionError("a zip archive with data before its entries or a displaced central directory, "
                                  "not as torch.save writes it")
    return total


def unpickling_message(error):
    """The weights-only unpickler's own reason (torch wraps it in a long explanation)."""
    cause = one_line(error.__context__ if isinstance(error.__context__, pickle.UnpicklingError) else error)
    if "Unsupported operand" in cause:
        cause += " (pickle protocol 4 or above, or a damaged file: torch.save writes protocol 2)"
    return cause


def load_checkpoint(path):
    """torch.load(weights_only=True) of a regular file holding a bounded zip archive; returns (checkpoint, the
    archive's inflated size in bytes)."""
    if not (hasattr(torch.serialization, "safe_globals")
            and hasattr(torch.serialization, "get_unsafe_globals_in_checkpoint")):
        raise ConversionError(f"needs PyTorch >= 2.5 to load checkpoints safely (found {torch.__version__})")
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise ConversionError("not a regular file (a folder, FIFO or device is refused unread)")
        # O_NONBLOCK: a FIFO swapped in after the check does not block the open.
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError) as error:  # ValueError: a NUL in the path
        raise ConversionError(f"cannot load checkpoint: {getattr(error, 'strerror', None) or one_line(error)}")
    with os.fdopen(descriptor, "rb") as file:
        info = os.fstat(file.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise ConversionError("not a regular file (a folder, FIFO or device is refused unread)")
        if file.read(len(ZIP_MAGIC)) != ZIP_MAGIC:
            raise ConversionError("not a zip archive: expected a checkpoint written by torch.save of PyTorch >= 1.6 "
                                  "(legacy torch.save files, tar archives and raw pickles are not read)")
        inflated = inspect_archive(file, info.st_size)
        with torch.serialization.safe_globals(allowed_globals()), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            file.seek(0)
            try:
                unsafe = torch.serialization.get_unsafe_globals_in_checkpoint(file)
            except Exception:  # what it cannot parse, torch.load below refuses with its own reason
                unsafe = []
            if unsafe:
                raise ConversionError(refusal(unsafe))
            file.seek(0)
            try:
                checkpoint = torch.load(file, map_location="cpu", weights_only=True, mmap=False)
            except pickle.UnpicklingError as error:
                raise ConversionError(f"the weights-only unpickler refused it: {unpickling_message(error)}")
            except Exception as error:  # a damaged archive or pickle fails in many ways
                raise ConversionError(f"cannot load checkpoint: {type(error).__name__}: {one_line(error)}")
    return checkpoint, inflated


# --- config -----------------------------------------------------------------------------------------------------


def is_omegaconf(value):
    return type(value).__module__.split(".")[0] == "omegaconf"


def plain_container(value):
    """An omegaconf container as plain dicts and lists, interpolations left unresolved; a Namespace as a dict."""
    if is_omegaconf(value):
        from omegaconf import Container, OmegaConf
        if isinstance(value, Container):
            return OmegaConf.to_container(value, resolve=False, enum_to_str=True)
    if isinstance(value, argparse.Namespace):
        return vars(value)
    return value


def to_plain(value, key="", interpolations=False):
    """Recursively turns mappings (dict, omegaconf DictConfig, Namespace, …) into dicts with string keys and
    sequences into lists, with JSON leaves (numpy scalars and paths as numbers and strings); anything else is a
    ConversionError naming its key. So is an omegaconf interpolation (`${…}`, which could read the environment),
    when `interpolations` says the value came from omegaconf or it is an omegaconf container."""
    interpolations = interpolations or is_omegaconf(value)
    value = plain_container(value)
    where = f"config value {key}" if key else "the config"
    if isinstance(value, Mapping):
        return {str(name): to_plain(item, f"{key}.{name}" if key else str(name), interpolations)
                for name, item in value.items()}
    if isinstance(value, (list, tuple)) or (isinstance(value, Sequence) and not isinstance(value, (str, bytes))):
        return [to_plain(item, f"{key}[{index}]", interpolations) for index, item in enumerate(value)]
    if type(value).__module__.split(".")[0] == "numpy":
        import numpy
        if isinstance(value, numpy.generic):
            value = value.item()
        elif isinstance(value, numpy.dtype):
            value = str(value)
    if isinstance(value, pathlib.PurePath):
        value = str(value)
    if isinstance(value, float) and not math.isfinite(value):
        raise ConversionError(f"{where} is {value}, not a finite number")
    if interpolations and isinstance(value, str) and "${" in value:
        raise ConversionError(f"{where} is {value!r}, an omegaconf interpolation: the converter does not evaluate "
                              "interpolations (store the value itself)")
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise ConversionError(f"{where} is a {type(value).__name__}, not a plain config value")


def model_config_from_checkpoint(checkpoint):
    """The run's config.yaml model section. The official train.py builds the model as Model(cfg["model"]) and
    GenericModel.save_hyperparameters() stores that argument, so Lightning holds the model section itself as
    hyper_parameters["cfg"]; a whole run config there (hyper_parameters["cfg"]["model"]) is taken too."""
    hyper_parameters = checkpoint.get("hyper_parameters")
    from_omegaconf = is_omegaconf(hyper_parameters)
    hyper_parameters = plain_container(hyper_parameters)
    cfg = hyper_parameters.get("cfg") if isinstance(hyper_parameters, Mapping) else None
    from_omegaconf = from_omegaconf or is_omegaconf(cfg)
    cfg = plain_container(cfg)
    model_cfg = None
    if isinstance(cfg, Mapping):
        model_cfg = cfg if "base" in cfg else cfg.get("model")
    if not isinstance(model_cfg, (Mapping, argparse.Namespace)) and not is_omegaconf(model_cfg):
        raise ConversionError('no model section in hyper_parameters["cfg"] (not a RayPatchQuerying checkpoint?)')
    model_cfg = to_plain(model_cfg, interpolations=from_omegaconf)
    if not isinstance(model_cfg, Mapping):
        raise ConversionError('no model section in hyper_parameters["cfg"] (not a RayPatchQuerying checkpoint?)')
    return model_cfg


# --- tensors ----------------------------------------------------------------------------------------------------


def is_kept(name):
    return isinstance(name, str) and name.startswith(KEPT_PREFIXES) and not name.endswith("num_batches_tracked")


def inference_tensors(state_dict):
    """The model tensors of a Lightning state_dict, without num_batches_tracked, as contiguous float32."""
    return {name: tensor.detach().to(torch.float32).contiguous()
            for name, tensor in state_dict.items() if is_kept(name)}


def raise_problems(problems):
    if problems:
        shown = problems[:MAX_PROBLEM_LINES]
        if len(problems) > len(shown):
            shown.append(f"... and {len(problems) - len(shown)} more problems")
        raise ConversionError("\n".join(shown))


def checked_tensors(state_dict, data_bytes):
    """inference_tensors of a loaded state_dict whose kept entries are all dense, finite, floating-point CPU
    tensors holding no more elements than the checkpoint has bytes of data (no expanded or overlapping views)."""
    problems, kept = [], {}
    for name, value in state_dict.items():
        if not isinstance(name, str):
            problems.append(f"state_dict key {reprlib.repr(name)} is not a string but {type(name).__name__}")
        elif not is_kept(name):
            continue
        elif not isinstance(value, torch.Tensor):
            problems.append(f"state_dict entry {name!r} is not a tensor but {type(value).__name__} "
                            f"{reprlib.repr(value)}")
        elif value.layout != torch.strided or value.is_nested or value.device.type != "cpu":
            problems.append(f"tensor {name!r} is not a dense tensor with data (layout {value.layout}, device "
                            f"{value.device.type})")
        elif not value.is_floating_point():
            problems.append(f"tensor {name!r} has dtype {value.dtype}, expected a floating-point tensor")
        else:
            kept[name] = value
    raise_problems(problems)
    elements = sum(tensor.numel() for tensor in kept.values())
    if elements > data_bytes:
        raise ConversionError(f"its model tensors have {elements} elements, more than the {data_bytes} bytes of "
                              "data in the checkpoint (expanded or overlapping views?)")
    tensors = inference_tensors(kept)
    for name, tensor in tensors.items():
        bad = torch.nonzero(~torch.isfinite(tensor.reshape(-1)))
        if len(bad):
            index = bad[0].item()
            problems.append(f"tensor {name!r} holds NaN or infinity (element {index} is "
                            f"{tensor.reshape(-1)[index].item()})")
    raise_problems(problems)
    return tensors


@contextlib.contextmanager
def registration_budget(limit, entries):
    """Stops building a model (ConversionError) after `limit` module, parameter and buffer registrations: a config
    cannot make the build take more time or memory than a model of about `entries` tensors."""
    count = 0

    def hook(*_):
        nonlocal count
        count += 1
        if count > limit:
            raise ConversionError(f"its config makes a model of more than {limit} modules, parameters and buffers, "
                                  f"far more than its {entries} state_dict entries")

    modules = torch.nn.modules.module
    handles = [modules.register_module_module_registration_hook(hook),
               modules.register_module_parameter_registration_hook(hook),
               modules.register_module_buffer_registration_hook(hook)]
    try:
        yield
    finally:
        for handle in handles:
            handle.remove()


def expected_shapes(model_cfg, entries=None):
    """Name -> shape of every tensor the reference model built from model_cfg holds (num_batches_tracked aside);
    given the checkpoint's number of state_dict entries, within a registration budget proportional to it."""
    budget = (contextlib.nullcontext() if entries is None
              else registration_budget(REGISTRATIONS_PER_ENTRY * entries + REGISTRATIONS_SLACK, entries))
    with torch.device("meta"), budget:  # shapes only, no memory or init cost
        model = build_model(model_cfg)
    return {name: list(tensor.shape) for name, tensor in model.state_dict().items()
            if not name.endswith("num_batches_tracked")}


def shape_problems(tensors, model_cfg, entries=None):
    """One line per missing, unexpected or wrongly shaped tensor."""
    expected = expected_shapes(model_cfg, entries)
    problems = [f"missing tensor {name!r} (expected shape {shape})"
                for name, shape in expected.items() if name not in tensors]
    for name, tensor in tensors.items():
        if name not in expected:
            problems.append(f"unexpected tensor {name!r} (shape {list(tensor.shape)})")
        elif list(tensor.shape) != expected[name]:
            problems.append(f"tensor {name!r} has shape {list(tensor.shape)}, expected {expected[name]}")
    return problems


# --- output -----------------------------------------------------------------------------------------------------


def file_kind(mode):
    for test, kind in ((stat.S_ISDIR, "folder"), (stat.S_ISLNK, "symlink"), (stat.S_ISFIFO, "FIFO"),
                       (stat.S_ISCHR, "device"), (stat.S_ISBLK, "device"), (stat.S_ISSOCK, "socket")):
        if test(mode):
            return kind
    return "special file"


def check_output(in_path, out_path):
    """Refuses, before anything is read, an output that is the input, is not a regular file where one exists,
    has no folder or has a name its folder cannot hold."""
    out = os.fspath(out_path)
    name = os.path.basename(out)
    if out.endswith(os.sep) or name in ("", ".", ".."):
        raise ConversionError(f"output {out!r} is not a file name")
    folder = os.path.dirname(out) or "."
    if not os.path.isdir(folder):
        raise ConversionError(f"output folder {folder} does not exist (or is not a folder)")
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        name_max = 255
    if len(os.fsencode(name)) > name_max:
        raise ConversionError(f"output name is {len(os.fsencode(name))} bytes long, more than the {name_max} its "
                              "folder allows")
    try:
        same = os.path.samefile(in_path, out)  # also through ./, symlinks and hard links
    except (OSError, ValueError):  # either is missing
        same = False
    if same:
        raise ConversionError(f"output {out} is the input checkpoint itself: choose another output path")
    try:
        mode = os.lstat(out).st_mode
    except FileNotFoundError:
        mode = None
    except (OSError, ValueError) as error:
        raise ConversionError(f"cannot write {out}: {getattr(error, 'strerror', None) or one_line(error)}")
    if mode is not None and not stat.S_ISREG(mode):
        raise ConversionError(f"output {out} is a {file_kind(mode)}: an existing output must be a regular file")


def write_model(path, state_dict, model_cfg, extra_metadata=None):
    """Writes a raypatch model file (float32 tensors, format and config metadata) atomically."""
    metadata = {"format": MODEL_FORMAT, "config": json.dumps(model_cfg, allow_nan=False)}
    metadata.update(extra_metadata or {})
    save_safetensors(path, {name: tensor.to(torch.float32) for name, tensor in state_dict.items()}, metadata)


def convert(in_path, out_path):
    check_output(in_path, out_path)
    checkpoint, data_bytes = load_checkpoint(in_path)
    if not isinstance(checkpoint, Mapping) or not isinstance(checkpoint.get("state_dict"), Mapping):
        raise ConversionError("no state_dict (not a Lightning checkpoint?)")
    state_dict = checkpoint["state_dict"]
    tensors = checked_tensors(state_dict, data_bytes)
    model_cfg = model_config_from_checkpoint(checkpoint)
    try:
        problems = shape_problems(tensors, model_cfg, len(state_dict))
    except ConversionError:
        raise
    except ValueError as error:  # the reference's own config errors
        raise ConversionError(one_line(error))
    except Exception as error:  # a config the reference cannot build from fails in many ways
        raise ConversionError(f"cannot build the model from its config: {type(error).__name__}: {one_line(error)}")
    raise_problems(problems)
    try:
        write_model(out_path, tensors, model_cfg, {"source": Path(in_path).name})
    except OSError as error:
        raise ConversionError(f"cannot write {out_path}: {error.strerror or one_line(error)}")
    return len(tensors)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="official Lightning .ckpt file")
    parser.add_argument("output", help="raypatch model .safetensors file to write")
    args = parser.parse_args(argv)
    try:
        with warnings.catch_warnings():  # stderr holds the error lines only
            warnings.simplefilter("ignore")
            count = convert(args.checkpoint, args.output)
    except Exception as error:  # never a traceback: an unforeseen failure is one line too
        lines = (str(error).splitlines() if isinstance(error, ConversionError)
                 else [f"unexpected error: {type(error).__name__}: {one_line(error)}"])
        for line in lines:
            print(f"convert_checkpoint: {args.checkpoint}: {line}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}: {count} tensors")
    return 0


if __name__ == "__main__":
    sys.exit(main())
