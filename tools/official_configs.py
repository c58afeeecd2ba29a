"""Model sections of the official MSN-Easy and ScanNet run configs of tberriel/RayPatchQuerying (297afbc), transcribed
from runs/msn_easy/srt_MDBN_32/config.yaml, runs/msn_easy/rpsrt_MDBN_4_32/config.yaml,
runs/msn_easy/osrt_MDBN_64/config.yaml, runs/msn_easy/rposrt_MDBN_8_64/config.yaml,
runs/scannet/define_32_stereo_acc/config.yaml and runs/scannet/rpdefine_16_32_stereo_acc/config.yaml
(YAML Null -> None).

A checkpoint stores these with one change: the official SRT.__init__ / OSRT.__init__ writes the attention decoder
width into decoder_kwargs.out_dims (128 for the Ray-Patch runs) before Lightning saves the hyper-parameters.
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

# runs/msn_easy/osrt_MDBN_64/config.yaml and runs/msn_easy/rposrt_MDBN_8_64/config.yaml. A checkpoint stores
# decoder_kwargs.out_dims as well (3 for the light field, 128 = conv_features for Ray-Patch), written by the
# official OSRT.__init__.
OSRT_MDBN_64 = {
    "base": "osrt",
    "encoder_kwargs": {"max_pooling": False, "pos_start_octave": -5, "num_conv_blocks": 3, "num_att_blocks": 5,
                       "num_slots": 5, "norm": "Batch", "latent_dim": 1536},
    "decoder": "lightfield",
    "decoder_kwargs": {"pos_start_octave": -5},
    "lr_config": "linear",
    "lr": 0.0001,
    "decay_it": 4000000,
    "lr_warmup": 2500,
    "gamma": 0.16,
}

RPOSRT_MDBN_8_64 = {
    "base": "osrt",
    "encoder_kwargs": {"max_pooling": False, "pos_start_octave": -5, "num_conv_blocks": 3, "num_att_blocks": 5,
                       "num_slots": 5, "norm": "Batch", "latent_dim": 1536},
    "decoder": "featurefield",
    "decoder_kwargs": {"pos_start_octave": -5},
    "rp_kwargs": {"out_dims": 3, "norm": "Batch", "upsample": 3, "h_in": 15, "w_in": 20, "h_out": 120, "w_out": 160},
    "lr_config": "linear",
    "lr": 0.0001,
    "decay_it": 4000000,
    "lr_warmup": 2500,
    "gamma": 0.16,
}

# runs/scannet/define_32_stereo_acc/config.yaml and runs/scannet/rpdefine_16_32_stereo_acc/config.yaml. The official
# DeFiNe class writes nothing into the config (the heads' out_dims are passed beside it); a checkpoint's model
# section also holds `wandb` (added by train.py). rp_kwargs.conv_features is left at its default, 128.
DEFINE_32_STEREO_ACC = {
    "base": "define",
    "encoder_kwargs": {"pos_start_octave": 1, "num_att_blocks": 8},
    "decoder": "lightfield",
    "decoder_kwargs": {"pos_start_octave": 1},
    "lr_config": "step",
    "lr": 0.0002,
    "lr_warmup": 2500,
}

RPDEFINE_16_32_STEREO_ACC = {
    "base": "define",
    "encoder_kwargs": {"pos_start_octave": 1, "num_att_blocks": 8},
    "decoder": "featurefield",
    "decoder_kwargs": {"pos_start_octave": 1},
    "rp_kwargs": {"h_in": 30, "w_in": 40, "upsample": 4, "norm": "Batch"},
    "lr_config": "step",
    "lr": 0.0002,
    "lr_warmup": 2500,
}
