"""What the checkpoint tests share (the Python converter's, test_convert_checkpoint.py, and the Rust reader's,
test_checkpoint_reader.py): where a hostile checkpoint hides its payload."""

# Each place a payload may sit in a Lightning checkpoint: a state_dict entry, callback state, a hyper-parameter,
# or the whole pickle.
PAYLOAD_PLACES = ("state_dict", "callbacks", "hyper_parameters", "top_level")


def with_payload(checkpoint: dict, where: str, payload):
    """`checkpoint` (a Lightning checkpoint dict) with `payload` at `where` (one of PAYLOAD_PLACES)."""
    if where == "state_dict":
        checkpoint["state_dict"]["encoder.evil"] = payload
    elif where == "callbacks":
        checkpoint["callbacks"] = {"ModelCheckpoint": {"best_k_models": {"a.ckpt": [payload]}}}
    elif where == "hyper_parameters":
        checkpoint["hyper_parameters"]["evil"] = payload
    else:
        return payload
    return checkpoint
