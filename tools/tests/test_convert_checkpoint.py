"""Tests of tools/conversion/convert_checkpoint.py (about 25 s):

    python3 -m pytest tools/tests/test_convert_checkpoint.py

Roundtrips of SRT / RP-SRT, OSRT / RP-OSRT (official size too) and DeFiNe / RP-DeFiNe Lightning checkpoints with
plain-dict and omegaconf configs (omegaconf cases skipped where it is not installed), and the refusals: pickles
that would run code or hold objects that are not plain data, decompression bombs and files that are not torch.save
zip archives, state_dict entries that are not finite floating-point tensors, configs that do not fit or would
build an unbounded model, and output paths that are the input, not regular files, in missing folders or too
long. Every refusal is exit code 2 with `convert_checkpoint: IN: reason` lines on stderr and nothing written.
Over 600 lines on purpose: one file per tool under test, a test per attack class.
"""

import argparse
import builtins
import collections
import contextlib
import copy
import io
import json
import os
import pathlib
import pickle
import struct
import subprocess
import sys
import tarfile
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors import safe_open

from checkpoint_helpers import PAYLOAD_PLACES, with_payload
from conversion import convert_checkpoint
from data import make_golden
from data.random_models import k4_config, random_define, random_model
from reference.official_configs import RPOSRT_MDBN_8_64
from reference.raypatch_reference import build_model

CONVERTER = Path(__file__).resolve().parents[1] / "conversion" / "convert_checkpoint.py"

try:
    import omegaconf
except ImportError:
    omegaconf = None

CONFIG_KINDS = ("dict", "omegaconf")
SYSTEM = f"{os.system.__module__}.{os.system.__name__}"  # posix.system


# --- helpers ----------------------------------------------------------------------------------------------------


def make_config(value, kind):
    """value as the config object a trainer stores: a plain dict, or an omegaconf DictConfig."""
    if kind == "dict":
        return value
    if omegaconf is None:
        pytest.skip("omegaconf is not installed")
    return omegaconf.OmegaConf.create(value)


def fake_checkpoint(model, model_cfg, cfg_kind="dict", model_section_only=False):
    """A Lightning checkpoint as the official training writes it, with metric and loss modules in the state_dict.

    The official train.py builds Model(cfg["model"]), so hyper_parameters["cfg"] is the model section itself
    (model_section_only); the default stores a whole run config there, which the converter also takes."""
    state_dict = dict(model.state_dict())
    state_dict["val_metrics.psnr.total"] = torch.tensor(3.0)
    state_dict["loss_colour.net.0.weight"] = torch.zeros(2, 2)
    cfg = {"data": {"dataset": "msn_easy", "kwargs": {"h": 120, "w": 160}}, "model": model_cfg,
           "training": {"batch_size": 32}}
    return {"epoch": 3, "global_step": 1000, "state_dict": state_dict,
            "hyper_parameters": {"cfg": make_config(model_cfg if model_section_only else cfg, cfg_kind), "lr": 1e-4,
                                 "log_id": None}}


def convert(in_path, out_path):
    """Runs the converter in-process; returns (exit code, stderr)."""
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        code = convert_checkpoint.main([str(in_path), str(out_path)])
    return code, stderr.getvalue()


def run_converter(checkpoint, directory, name="run.ckpt"):
    """Saves the checkpoint, converts it in-process; returns (exit code, stderr, output path)."""
    in_path, out_path = Path(directory) / name, Path(directory) / (name + ".safetensors")
    torch.save(checkpoint, in_path)
    code, stderr = convert(in_path, out_path)
    return code, stderr, out_path


def assert_refused(code, stderr, in_path, *fragments, lines=1):
    """Exit code 2, `lines` lines `convert_checkpoint: IN: ...` holding every fragment, no traceback."""
    assert code == 2, (code, stderr)
    assert len(stderr.splitlines()) == lines, stderr
    assert all(line.startswith(f"convert_checkpoint: {in_path}: ") for line in stderr.splitlines()), stderr
    assert "Traceback" not in stderr
    for fragment in fragments:
        assert fragment in stderr, (fragment, stderr)


def assert_nothing_written(directory, before):
    """The folder holds what it held before (no output, no temporary)."""
    assert sorted(os.listdir(directory)) == sorted(before)


def assert_converted(out_path, expected, model_cfg):
    with safe_open(str(out_path), "pt") as converted:
        assert sorted(converted.keys()) == sorted(expected)
        for name, tensor in expected.items():
            assert torch.equal(converted.get_tensor(name), tensor), name
        metadata = converted.metadata()
    assert json.loads(metadata["config"]) == model_cfg
    return metadata


def model_tensors(model):
    return {name: tensor for name, tensor in model.state_dict().items() if not name.endswith("num_batches_tracked")}


@pytest.fixture(scope="module")
def k4():
    model_cfg = k4_config()
    return model_cfg, random_model(model_cfg)


@pytest.fixture
def saved(tmp_path, k4):
    """A good checkpoint file in tmp_path."""
    model_cfg, model = k4
    path = tmp_path / "run.ckpt"
    torch.save(fake_checkpoint(model, model_cfg), path)
    return path


def repack(source, destination, skip=(), compresslevel=6):
    """Copies a zip archive entry by entry with ZIP_DEFLATED (leaving out the names ending in `skip`)."""
    with zipfile.ZipFile(source) as original, \
            zipfile.ZipFile(destination, "w", zipfile.ZIP_DEFLATED, compresslevel=compresslevel) as packed:
        for info in original.infolist():
            if info.filename.endswith(tuple(skip)):
                continue
            with original.open(info) as reader, packed.open(info.filename, "w") as writer:
                while chunk := reader.read(1 << 22):
                    writer.write(chunk)


# --- roundtrips -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfg_kind", CONFIG_KINDS)
def test_roundtrip(tmp_path, k4, cfg_kind):
    model_cfg, model = k4
    code, stderr, out_path = run_converter(fake_checkpoint(model, model_cfg, cfg_kind), tmp_path)
    assert code == 0, stderr
    metadata = assert_converted(out_path, model_tensors(model), model_cfg)
    assert metadata["format"] == "raypatch-model/1" and metadata["source"] == "run.ckpt"
    assert sorted(os.listdir(tmp_path)) == ["run.ckpt", "run.ckpt.safetensors"]  # no temporary left


def test_to_plain_takes_config_objects():
    nested = {"a": [1, {"b": None}, (2.5, True)], "c": "text", "d": argparse.Namespace(e=np.float32(0.5)),
              "f": pathlib.PurePosixPath("/x/y"), "g": np.int64(7), "h": np.dtype("float16")}
    plain = {"a": [1, {"b": None}, [2.5, True]], "c": "text", "d": {"e": 0.5}, "f": "/x/y", "g": 7, "h": "float16"}
    assert convert_checkpoint.to_plain(nested) == plain
    if omegaconf is not None:
        config = omegaconf.OmegaConf.create({"a": [1, {"b": None}, [2.5, True]], "c": "text"})
        assert convert_checkpoint.to_plain(config) == {"a": [1, {"b": None}, [2.5, True]], "c": "text"}
    with pytest.raises(convert_checkpoint.ConversionError, match=r"config value x\[1\] is a set"):
        convert_checkpoint.to_plain({"x": [0, {1}]})
    assert convert_checkpoint.to_plain({"name": "${not an interpolation in a plain dict}"})["name"].startswith("${")


def test_lightning_and_other_config_objects_are_read(tmp_path, k4, monkeypatch):
    """Lightning's AttributeDict (under each name it has had; Lightning need not be installed), argparse.Namespace,
    paths, numpy scalars and dtypes, defaultdicts in hyper_parameters and callback state are read."""
    model_cfg, model = k4
    classes = {}
    for name in convert_checkpoint.ATTRIBUTE_DICT_NAMES:
        module_name, class_name = name.rsplit(".", 1)
        parts = module_name.split(".")
        for depth in range(1, len(parts) + 1):
            monkeypatch.setitem(sys.modules, ".".join(parts[:depth]), types.ModuleType(".".join(parts[:depth])))
        attribute_dict = type(class_name, (dict,), {"__module__": module_name,
                                                    "__getattr__": lambda self, key: self[key]})
        setattr(sys.modules[module_name], class_name, attribute_dict)
        classes[name] = attribute_dict
    checkpoint = fake_checkpoint(model, model_cfg, model_section_only=True)
    lightning = classes["lightning_fabric.utilities.data.AttributeDict"]
    checkpoint["hyper_parameters"] = lightning(checkpoint["hyper_parameters"])
    checkpoint["hparams_type"] = lightning
    checkpoint["callbacks"] = {name: kind(best=np.float64(1.5), path=pathlib.Path("/runs/x.ckpt"))
                               for name, kind in classes.items()}
    checkpoint["extra"] = {"args": argparse.Namespace(lr=np.float32(1e-4), dtype=np.dtype("float32"), n=np.int64(3)),
                           "counts": collections.defaultdict(list, a=[1])}
    code, stderr, out_path = run_converter(checkpoint, tmp_path)
    assert code == 0, stderr
    assert_converted(out_path, model_tensors(model), model_cfg)


@pytest.mark.parametrize("size", ["official", "small"])
def test_osrt_roundtrip(tmp_path, size):
    """Official-size RP-OSRT (rposrt_MDBN_8_64, 95 M parameters) and a small OSRT: Lightning checkpoint with the
    official stored out_dims -> model file with the same names, shapes and values, num_batches_tracked dropped."""
    if size == "official":
        model_cfg = copy.deepcopy(RPOSRT_MDBN_8_64)
        model_cfg["decoder_kwargs"]["out_dims"] = 128  # what the official OSRT.__init__ stores
        cfg_kind = "dict"
    else:
        model_cfg, cfg_kind = make_golden.small_osrt_config(), "omegaconf"
    torch.manual_seed(0)
    model = build_model(model_cfg)
    assert any(name.endswith("num_batches_tracked") for name in model.state_dict())
    code, stderr, out_path = run_converter(fake_checkpoint(model, model_cfg, cfg_kind), tmp_path)
    assert code == 0, stderr
    assert_converted(out_path, model_tensors(model), model_cfg)


def test_osrt_tensors_must_fit_the_config(tmp_path):
    model_cfg = make_golden.small_osrt_config()
    torch.manual_seed(0)
    checkpoint = fake_checkpoint(build_model(model_cfg), model_cfg)
    checkpoint["state_dict"]["encoder.slot_attention.initial_slots"] = torch.zeros(6, 32)
    del checkpoint["state_dict"]["decoder_att.mixing_block.to_k.weight"]
    code, stderr, out_path = run_converter(checkpoint, tmp_path, "bad.ckpt")
    assert_refused(code, stderr, tmp_path / "bad.ckpt", "initial_slots", "[6, 32]", "[5, 32]", "to_k", lines=2)
    assert not out_path.exists()


DEFINE_RP = dict(upsample=4, h_in=30, w_in=40, conv_features=32, norm="Batch")


@pytest.mark.parametrize("case", ["define-section-omegaconf", "rpdefine-section-omegaconf", "rpdefine-run-dict",
                                  "rpdefine-run-omegaconf"])
def test_define_roundtrip(tmp_path, case):
    """DeFiNe and RP-DeFiNe Lightning checkpoints (hyper_parameters["cfg"] = the model section, as the official
    train.py stores it, or a whole run config): the encoder., decoder_att_rgb/d. and decoder_rp_rgb/d. tensors with
    their names, shapes and values, num_batches_tracked, val_metrics.* and loss_colour.* dropped."""
    model_name, layout, cfg_kind = case.split("-")
    model_cfg = (make_golden.small_define_config() if model_name == "define"
                 else make_golden.small_define_config("featurefield", rp_kwargs=DEFINE_RP))
    model = random_define(model_cfg)
    expected = model_tensors(model)
    prefixes = {name.split(".")[0] for name in expected}
    assert prefixes == ({"encoder", "decoder_att_rgb", "decoder_att_d"}
                        | ({"decoder_rp_rgb", "decoder_rp_d"} if "rp_kwargs" in model_cfg else set()))
    checkpoint = fake_checkpoint(model, model_cfg, cfg_kind, model_section_only=layout == "section")
    code, stderr, out_path = run_converter(checkpoint, tmp_path)
    assert code == 0, stderr
    assert_converted(out_path, expected, model_cfg)


def test_define_tensors_must_fit_the_config(tmp_path):
    model_cfg = make_golden.small_define_config("featurefield", rp_kwargs=DEFINE_RP)
    checkpoint = fake_checkpoint(random_define(model_cfg), model_cfg, model_section_only=True)
    checkpoint["state_dict"]["decoder_rp_d.conv_decoder.conv_0.weight"] = torch.zeros(3, 32, 3, 3)
    del checkpoint["state_dict"]["encoder.transformer.embeddings.latents"]
    code, stderr, out_path = run_converter(checkpoint, tmp_path, "bad.ckpt")
    assert_refused(code, stderr, tmp_path / "bad.ckpt", "[3, 32, 3, 3]", "[1, 32, 3, 3]", "embeddings.latents",
                   lines=2)
    assert not out_path.exists()
    checkpoint["hyper_parameters"]["cfg"] = {"data": {}}
    code, stderr, _ = run_converter(checkpoint, tmp_path, "nocfg.ckpt")
    assert_refused(code, stderr, tmp_path / "nocfg.ckpt", "no model section")


# --- config and tensor refusals ---------------------------------------------------------------------------------


def test_rejects_bad_tensors(tmp_path, k4):
    model_cfg, model = k4
    checkpoint = fake_checkpoint(model, model_cfg)
    wrong, missing = "encoder.conv_blocks.0.layers.0.weight", "decoder_rp.conv_decoder.conv_0.bias"
    checkpoint["state_dict"][wrong] = torch.zeros(4, 180, 3, 3)
    del checkpoint["state_dict"][missing]
    code, stderr, out_path = run_converter(checkpoint, tmp_path)
    assert_refused(code, stderr, tmp_path / "run.ckpt", lines=2)
    lines = stderr.splitlines()
    assert any(wrong in line and "[4, 180, 3, 3]" in line and "[4, 183, 3, 3]" in line for line in lines), stderr
    assert any(missing in line and "missing" in line and "[3]" in line for line in lines), stderr
    assert not out_path.exists()

    no_rp = fake_checkpoint(model, {k: v for k, v in model_cfg.items() if k != "rp_kwargs"})
    code, stderr, out_path = run_converter(no_rp, tmp_path, "no_rp.ckpt")
    assert_refused(code, stderr, tmp_path / "no_rp.ckpt", "rp_kwargs")
    assert not out_path.exists()


WEIGHT = "encoder.conv_blocks.0.layers.0.weight"


def with_element(tensor, index, value):
    tensor = tensor.clone()
    tensor.view(-1)[index] = value
    return tensor


BAD_ENTRIES = {  # id: (state_dict key, value made from the good WEIGHT tensor, message fragments)
    "int": ("encoder.x", lambda weight: 3, ["'encoder.x'", "not a tensor", "int 3"]),
    "str": ("decoder_rp.y", lambda weight: "text", ["'decoder_rp.y'", "not a tensor", "str 'text'"]),
    "list": ("encoder.z", lambda weight: [weight], ["'encoder.z'", "not a tensor", "list"]),
    "none": ("encoder.n", lambda weight: None, ["'encoder.n'", "not a tensor", "NoneType"]),
    "int-key": (3, lambda weight: weight, ["state_dict key 3", "not a string"]),
    "int64": (WEIGHT, lambda weight: weight.long(), [WEIGHT, "torch.int64", "floating-point"]),
    "complex": (WEIGHT, lambda weight: weight.to(torch.complex64), [WEIGHT, "torch.complex64"]),
    "nan": (WEIGHT, lambda weight: with_element(weight, 5, float("nan")), [WEIGHT, "NaN or infinity",
                                                                          "element 5 is nan"]),
    "inf": (WEIGHT, lambda weight: with_element(weight, 5, float("inf")), [WEIGHT, "NaN or infinity",
                                                                          "element 5 is inf"]),
    # 4 bytes of storage seen as 10^12 elements: refused before anything is allocated for them.
    "expanded": (WEIGHT, lambda weight: torch.zeros(1).expand(10 ** 12), ["have 10000000", "elements, more than the",
                                                                                 "bytes of data"]),
}


@pytest.mark.parametrize("case", BAD_ENTRIES)
def test_non_tensor_or_bad_state_dict_entries(tmp_path, k4, case):
    model_cfg, model = k4
    checkpoint = fake_checkpoint(model, model_cfg)
    name, make_value, fragments = BAD_ENTRIES[case]
    checkpoint["state_dict"][name] = make_value(checkpoint["state_dict"][WEIGHT])
    code, stderr, out_path = run_converter(checkpoint, tmp_path)
    assert_refused(code, stderr, tmp_path / "run.ckpt", *fragments)
    assert not out_path.exists()


def test_config_refusals(tmp_path, k4):
    model_cfg, model = k4
    # A config that would build a model of millions of layers stops at a budget set by the state_dict's size.
    huge = copy.deepcopy(model_cfg)
    huge["encoder_kwargs"]["num_att_blocks"] = 10 ** 7
    code, stderr, _ = run_converter(fake_checkpoint(model, huge), tmp_path, "huge.ckpt")
    assert_refused(code, stderr, tmp_path / "huge.ckpt", "more than", "state_dict entries")
    # Values that are not plain config data.
    odd = copy.deepcopy(model_cfg)
    odd["encoder_kwargs"]["norm"] = torch.zeros(2)
    code, stderr, _ = run_converter(fake_checkpoint(model, odd), tmp_path, "odd.ckpt")
    assert_refused(code, stderr, tmp_path / "odd.ckpt", "config value encoder_kwargs.norm is a Tensor")
    odd["encoder_kwargs"]["norm"] = float("nan")
    code, stderr, _ = run_converter(fake_checkpoint(model, odd), tmp_path, "nan.ckpt")
    assert_refused(code, stderr, tmp_path / "nan.ckpt", "config value encoder_kwargs.norm is nan")
    # A value the reference cannot build from is one line, whatever the reference raises.
    odd["encoder_kwargs"]["norm"] = "Batch"
    odd["encoder_kwargs"]["heads"] = [4]
    code, stderr, _ = run_converter(fake_checkpoint(model, odd), tmp_path, "heads.ckpt")
    assert_refused(code, stderr, tmp_path / "heads.ckpt")
    assert not [name for name in os.listdir(tmp_path) if name.endswith((".safetensors", ".tmp"))]


def test_omegaconf_interpolations_are_not_evaluated(tmp_path, k4):
    model_cfg, model = k4
    cfg = copy.deepcopy(model_cfg)
    cfg["encoder_kwargs"]["token_dim"] = "${oc.env:HOME}"
    code, stderr, _ = run_converter(fake_checkpoint(model, cfg, "omegaconf", model_section_only=True), tmp_path)
    assert_refused(code, stderr, tmp_path / "run.ckpt", "config value encoder_kwargs.token_dim is '${oc.env:HOME}'",
                   "omegaconf interpolation")
    assert os.environ.get("HOME", "/") not in stderr.replace("${oc.env:HOME}", "")


# --- code execution ---------------------------------------------------------------------------------------------


class RunsCode:
    """Unpickling it calls function(*args)."""

    def __init__(self, function, *args):
        self.function, self.args = function, args

    def __reduce__(self):
        return self.function, self.args


def payloads(marker):
    """name -> (object whose unpickling runs a command, the names the refusal may give its callable: protocol 2
    pickles name subprocess.call by its Python 2 name)."""
    return {"os.system": (RunsCode(os.system, f"touch {marker}"), (SYSTEM,)),
            "exec": (RunsCode(builtins.exec, f"open({str(marker)!r}, 'w').close()"), ("builtins.exec",)),
            "subprocess": (RunsCode(subprocess.call, ["touch", str(marker)]), ("subprocess.call", "commands.call"))}


@pytest.mark.parametrize("payload", ["os.system", "exec", "subprocess"])
@pytest.mark.parametrize("where", PAYLOAD_PLACES)
def test_pickles_that_run_code_are_refused_unrun(tmp_path, k4, where, payload):
    """A checkpoint whose pickle would run a command (in a state_dict entry, nested in callback state, in a
    hyper_parameters entry, or as the whole pickle) is refused with one line naming the callable; nothing runs."""
    model_cfg, model = k4
    marker = tmp_path / "MARKER"
    evil, names = payloads(marker)[payload]
    checkpoint = with_payload(fake_checkpoint(model, model_cfg), where, evil)
    code, stderr, out_path = run_converter(checkpoint, tmp_path)
    assert not marker.exists(), "the pickle ran code"
    assert_refused(code, stderr, tmp_path / "run.ckpt", "could run code")
    assert any(f"refusing to unpickle {name}: " in stderr for name in names), stderr
    assert not out_path.exists()


class TrainerState:
    """A class of some trainer's: not plain data, even if harmless."""

    def __init__(self):
        self.step = 3


def test_objects_of_other_classes_are_refused_by_name(tmp_path, k4):
    model_cfg, model = k4
    checkpoint = fake_checkpoint(model, model_cfg)
    checkpoint["loops"] = {"state": TrainerState()}
    code, stderr, _ = run_converter(checkpoint, tmp_path)
    assert_refused(code, stderr, tmp_path / "run.ckpt",
                   f"refusing to unpickle {TrainerState.__module__}.TrainerState", "not a tensor")


def test_without_omegaconf_an_omegaconf_config_asks_for_it(tmp_path, k4, monkeypatch):
    model_cfg, model = k4
    torch.save(fake_checkpoint(model, model_cfg, "omegaconf"), tmp_path / "run.ckpt")  # skips without omegaconf
    monkeypatch.setitem(sys.modules, "omegaconf", None)  # import omegaconf now fails
    convert_checkpoint.allowed_globals.cache_clear()
    try:
        code, stderr = convert(tmp_path / "run.ckpt", tmp_path / "run.safetensors")
    finally:
        monkeypatch.undo()
        convert_checkpoint.allowed_globals.cache_clear()
    assert_refused(code, stderr, tmp_path / "run.ckpt", "omegaconf.dictconfig.DictConfig", "pip install omegaconf")
    assert not (tmp_path / "run.safetensors").exists()


# --- archives ---------------------------------------------------------------------------------------------------


def test_decompression_bomb_is_refused_unread(tmp_path, k4):
    """A checkpoint re-packed with ZIP_DEFLATED whose 100 MB zero storage deflates to a few hundred KB is refused
    from the central directory (both sizes in the message); a re-deflated small checkpoint still converts."""
    model_cfg, model = k4
    checkpoint = fake_checkpoint(model, model_cfg)
    torch.save(checkpoint, tmp_path / "small.ckpt")
    repack(tmp_path / "small.ckpt", tmp_path / "deflated.ckpt")
    code, stderr = convert(tmp_path / "deflated.ckpt", tmp_path / "deflated.safetensors")
    assert code == 0, stderr
    assert_converted(tmp_path / "deflated.safetensors", model_tensors(model), model_cfg)

    checkpoint["optimizer_states"] = [{"state": {0: {"exp_avg": torch.zeros(25_000_000)}}}]  # 100 MB of zeros
    torch.save(checkpoint, tmp_path / "big.ckpt")
    repack(tmp_path / "big.ckpt", tmp_path / "bomb.ckpt", compresslevel=1)
    (tmp_path / "big.ckpt").unlink()
    size = (tmp_path / "bomb.ckpt").stat().st_size
    assert size < 2_000_000
    with zipfile.ZipFile(tmp_path / "bomb.ckpt") as archive:
        inflated = sum(info.file_size for info in archive.infolist())
    assert inflated > 4 * size + (64 << 20)
    code, stderr = convert(tmp_path / "bomb.ckpt", tmp_path / "bomb.safetensors")
    assert_refused(code, stderr, tmp_path / "bomb.ckpt", f"inflate to {inflated} bytes", f"its {size} bytes",
                   "64 MiB")
    assert not (tmp_path / "bomb.safetensors").exists()


def not_zip_files(directory, good):
    """name -> bytes of files that are not torch.save zip archives, or damaged ones."""
    data = good.read_bytes()
    legacy = io.BytesIO()
    torch.save({"state_dict": {"encoder.x": torch.zeros(2)}}, legacy, _use_new_zipfile_serialization=False)
    protocol4 = io.BytesIO()
    torch.save({"state_dict": {"encoder.x": torch.zeros(2)}}, protocol4, pickle_protocol=4)
    tar = io.BytesIO()
    with tarfile.open(fileobj=tar, mode="w") as archive:
        archive.add(good, arcname="run.ckpt")
    with zipfile.ZipFile(good) as archive:
        first_entry = archive.infolist()[1].header_offset
        pickle_entry = archive.infolist()[0]
    assert pickle_entry.filename.endswith("/data.pkl")
    name_length, extra_length = struct.unpack("<HH", data[pickle_entry.header_offset + 26:][:4])
    pickle_start = pickle_entry.header_offset + 30 + name_length + extra_length
    repack(good, directory / "no-storage.zip", skip=("/data/0",))
    return {
        "legacy": (legacy.getvalue(), "not a zip archive"),
        "tar": (tar.getvalue(), "not a zip archive"),
        "pickle": (pickle.dumps({"state_dict": {}}), "not a zip archive"),
        "empty": (b"", "not a zip archive"),
        "truncated": (data[:len(data) // 2], "not a readable zip archive"),
        "junk": (b"PK\x03\x04" + bytes(range(256)) * 8, "not a readable zip archive"),
        "prepended": (data[:first_entry] + data, "displaced central directory"),
        "damaged-pickle": (data[:pickle_start + 20] + bytes(200) + data[pickle_start + 220:], "unpickler refused"),
        "missing-storage": ((directory / "no-storage.zip").read_bytes(), "cannot load checkpoint: RuntimeError"),
        "protocol-4": (protocol4.getvalue(), "pickle protocol 4 or above"),
    }


def test_files_that_are_not_checkpoints_are_one_line(tmp_path, saved):
    for name, (data, fragment) in not_zip_files(tmp_path, saved).items():
        path = tmp_path / f"{name}.ckpt"
        path.write_bytes(data)
        code, stderr = convert(path, tmp_path / f"{name}.safetensors")
        assert_refused(code, stderr, path, fragment)
        assert not (tmp_path / f"{name}.safetensors").exists(), name


def test_inputs_must_be_regular_files(tmp_path):
    os.mkfifo(tmp_path / "fifo")  # refused unread: opening it would wait for a writer
    for path in (tmp_path / "fifo", tmp_path, Path("/dev/zero")):
        code, stderr = convert(path, tmp_path / "out.safetensors")
        assert_refused(code, stderr, path, "not a regular file")
    code, stderr = convert(tmp_path / "none.ckpt", tmp_path / "out.safetensors")
    assert_refused(code, stderr, tmp_path / "none.ckpt", "No such file")
    assert sorted(os.listdir(tmp_path)) == ["fifo"]


# --- output paths -----------------------------------------------------------------------------------------------


def test_output_may_not_be_the_input(tmp_path, saved, monkeypatch):
    original = saved.read_bytes()
    monkeypatch.chdir(tmp_path)
    os.symlink("run.ckpt", tmp_path / "link.safetensors")
    os.link(saved, tmp_path / "hard.safetensors")
    before = os.listdir(tmp_path)
    for out in (saved, "run.ckpt", "./run.ckpt", f"../{tmp_path.name}/run.ckpt", tmp_path / "link.safetensors",
                tmp_path / "hard.safetensors"):
        code, stderr = convert("run.ckpt", out)
        assert_refused(code, stderr, "run.ckpt", "is the input checkpoint itself")
        assert saved.read_bytes() == original
        assert_nothing_written(tmp_path, before)


def test_output_paths_that_are_refused(tmp_path, saved):
    (tmp_path / "folder").mkdir()
    os.mkfifo(tmp_path / "fifo")
    os.symlink("elsewhere.safetensors", tmp_path / "dangling.safetensors")
    (tmp_path / "target.safetensors").write_bytes(b"kept")
    os.symlink("target.safetensors", tmp_path / "link.safetensors")
    before = os.listdir(tmp_path)
    cases = [(tmp_path / "missing" / "out.safetensors", "output folder", "does not exist"),
             (tmp_path / "folder", "is a folder"),
             (tmp_path / "fifo", "is a FIFO"),
             (Path("/dev/null"), "is a device"),
             (tmp_path / "dangling.safetensors", "is a symlink"),
             (tmp_path / "link.safetensors", "is a symlink"),
             (f"{tmp_path}/folder/", "not a file name"),
             (tmp_path / ("x" * 256), "256 bytes long")]
    for out, *fragments in cases:
        code, stderr = convert(saved, out)
        assert_refused(code, stderr, saved, *fragments)
        assert_nothing_written(tmp_path, before)
        assert os.listdir(tmp_path / "folder") == []
    assert (tmp_path / "target.safetensors").read_bytes() == b"kept"


def test_existing_output_is_replaced_only_by_a_good_conversion(tmp_path, k4):
    model_cfg, model = k4
    out_path = tmp_path / "run.ckpt.safetensors"
    out_path.write_bytes(b"previous")
    bad = fake_checkpoint(model, model_cfg)
    bad["state_dict"]["encoder.x"] = 3
    code, stderr, _ = run_converter(bad, tmp_path)
    assert code == 2 and out_path.read_bytes() == b"previous", stderr
    code, stderr, _ = run_converter(fake_checkpoint(model, model_cfg), tmp_path)
    assert code == 0, stderr
    assert_converted(out_path, model_tensors(model), model_cfg)


def test_long_output_names_convert(tmp_path, saved, k4):
    """A 250-byte output name (the writer's `.NAME.PID.tmp` temporary would pass 255 bytes) converts, and no
    temporary is left; so does a name of multi-byte characters near the limit."""
    model_cfg, model = k4
    for name in ("m" * 240 + ".safetensors", "é" * 121 + ".safetensors"):
        assert len(name.encode()) in (252, 254)
        code, stderr = convert(saved, tmp_path / name)
        assert code == 0, stderr
        assert_converted(tmp_path / name, model_tensors(model), model_cfg)
        assert not [entry for entry in os.listdir(tmp_path) if entry.endswith(".tmp")]


# --- command line -----------------------------------------------------------------------------------------------


def test_command_line(tmp_path, k4):
    """The script itself: a good checkpoint converts (exit 0); a malicious one is exit 2 with one line, and its
    command does not run."""
    model_cfg, model = k4
    good, out_path = tmp_path / "lf.ckpt", tmp_path / "lf.safetensors"
    torch.save(fake_checkpoint(model, model_cfg), good)
    script = [sys.executable, str(CONVERTER)]
    result = subprocess.run(script + [str(good), str(out_path)], capture_output=True, text=True)
    assert result.returncode == 0 and out_path.exists(), result.stderr
    assert result.stdout.startswith(f"wrote {out_path}: ")

    marker = tmp_path / "MARKER"
    evil = fake_checkpoint(model, model_cfg)
    evil["hyper_parameters"]["evil"] = RunsCode(os.system, f"touch {marker}")
    torch.save(evil, tmp_path / "evil.ckpt")
    result = subprocess.run(script + [str(tmp_path / "evil.ckpt"), str(tmp_path / "evil.safetensors")],
                            capture_output=True, text=True)
    assert not marker.exists()
    assert result.returncode == 2 and result.stdout == "", result
    assert result.stderr.splitlines() == [f"convert_checkpoint: {tmp_path / 'evil.ckpt'}: refusing to unpickle "
                                          f"{SYSTEM}: not a tensor or a plain container/config object (unpickling "
                                          "it could run code)"]
    assert not (tmp_path / "evil.safetensors").exists()
