"""Model sections of the official MSN-Easy run configs of tberriel/RayPatchQuerying (297afbc), transcribed from
runs/msn_easy/srt_MDBN_32/config.yaml and runs/msn_easy/rpsrt_MDBN_4_32/config.yaml (YAML Null -> None).

A checkpoint stores these with one change: the official SRT.__init__ writes the attention decoder width into
decoder_kwargs.out_dims (128 for the Ray-Patch run) before Lightning saves the hyper-parameters.
"""

SRT_MDBN_32 = {
    "base": "srt",
    "encoder_kwargs": {"pos_start_octave": -5, "num_att_blocks": 5, "num_conv_blocks": 3, "norm": "Batch"},
    "decoder": "lightfield",
    "decoder_kwargs": {"pos_octaves": 15, "ray_octaves": 15, "pos_start_octave": -5, "pos_end_octave": None,
                       "ray_start_octave": 0, "ray_end_octave": None, "latent_dim": 768, "mode": "efficient",
                       "out_dims": 3},
    "lr_config": "linear",
    "gamma": None,
    "lr": 0.0001,
    "decay_it": 500000,
    "lr_warmup": 2500,
}

RPSRT_MDBN_4_32 = {
    "base": "srt",
    "encoder_kwargs": {"pos_start_octave": -5, "num_att_blocks": 5, "num_conv_blocks": 3, "norm": "Batch"},
    "decoder": "featurefield",
    "decoder_kwargs": {"pos_octaves": 15, "ray_octaves": 15, "pos_start_octave": -5, "pos_end_octave": None,
                       "ray_start_octave": 0, "ray_end_octave": None, "latent_dim": 768, "mode": "efficient"},
    "rp_kwargs": {"upsample": 2, "h_in": 30, "w_in": 40, "conv_features": 128, "norm": "Batch"},
    "lr_config": "linear",
    "gamma": None,
    "decay_it": 500000,
    "lr": 0.0001,
    "lr_warmup": 2500,
}
