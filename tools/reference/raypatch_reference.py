"""PyTorch reference of the official SRT / RP-SRT model of tberriel/RayPatchQuerying (commit 297afbc); OSRT / RP-OSRT
below, DeFiNe / RP-DeFiNe in tools/reference/reference_define.py (build_model builds all three by the config's `base`).

The modules mirror the official src/layers.py, src/encoder.py, src/decoder.py and the SRT class of src/model.py
module for module and attribute for attribute, so `SRT.state_dict()` carries exactly the official Lightning
keys (`encoder.…`, `decoder_att.…`, `decoder_rp.…`). Only inference is modelled: dropout is 0 in every official
config, so its slots are `nn.Identity` placeholders that keep the `nn.Sequential` indices of the official code.

Widths that the official code hard-codes can be set through the raypatch extension keys of docs/FORMATS.md;
their defaults are the official values.

Over 600 lines on purpose: SRT and OSRT share their encoder, ray encoder and Ray-Patch decoder here, as the official
src/ files share them, so that a module and its official counterpart read side by side.
"""

import copy
import inspect
import math

import torch
import torch.nn.functional as F
from torch import nn


class PositionalEncoding(nn.Module):
    """sin/cos encoding, coordinate-major: [sin(c0·m0..m_{N-1}), sin(c1·…), …, cos(same order)]."""

    def __init__(self, num_octaves=8, start_octave=0, end_octave=None):
        super().__init__()
        self.num_octaves = num_octaves
        self.start_octave = start_octave
        self.end_octave = end_octave

    def forward(self, coords):
        # The official code builds the multipliers in float32 whatever the input dtype, so a float64 run keeps
        # the float32 multipliers f32(2^o)·f32(pi) and only the products are promoted.
        if self.end_octave is None:
            octaves = torch.arange(self.start_octave, self.start_octave + self.num_octaves, dtype=torch.float32)
            multipliers = 2**octaves * math.pi
        else:
            octaves = torch.linspace(self.start_octave, self.end_octave, self.num_octaves, dtype=torch.float32)
            multipliers = octaves * math.pi
        scaled = coords.unsqueeze(-1) * multipliers.to(coords.device)  # [..., D, N]
        return torch.cat((torch.sin(scaled).flatten(-2), torch.cos(scaled).flatten(-2)), -1)


class RayEncoder(nn.Module):
    """cat(posenc(camera position), posenc(ray direction))."""

    def __init__(self, pos_octaves=8, pos_start_octave=0, pos_end_octave=None,
                 ray_octaves=4, ray_start_octave=0, ray_end_octave=None):
        super().__init__()
        self.pos_encoding = PositionalEncoding(pos_octaves, pos_start_octave, pos_end_octave)
        self.ray_encoding = PositionalEncoding(ray_octaves, ray_start_octave, ray_end_octave)

    def forward(self, pos, rays):
        if rays.dim() == 4:
            # Encoder: pos [n, 3], rays [n, h, w, 3] -> channels-first [n, C, h, w], position broadcast per pixel.
            _, height, width, _ = rays.shape
            pos_enc = self.pos_encoding(pos)[:, :, None, None].expand(-1, -1, height, width)
            ray_enc = self.ray_encoding(rays).permute(0, 3, 1, 2)
            return torch.cat((pos_enc, ray_enc), 1)
        # Decoder: pos and rays [b, p, 3] -> [b, p, C].
        return torch.cat((self.pos_encoding(pos), self.ray_encoding(rays)), -1)


class PreNorm(nn.Module):
    """LayerNorm on the query stream only; cross-attention latents are not normalised."""

    def __init__(self, dim, fn, eps=1e-5):
        super().__init__()
        self.norm = nn.LayerNorm(dim, eps=eps)
        self.fn = fn

    def forward(self, x, **kwargs):
        return self.fn(self.norm(x), **kwargs)


class FeedForward(nn.Module):
    def __init__(self, dim, hidden_dim):
        super().__init__()
        # Official: Linear, GELU, Dropout, Linear, Dropout -> keys net.0 and net.3.
        self.net = nn.Sequential(nn.Linear(dim, hidden_dim), nn.GELU(), nn.Identity(),
                                 nn.Linear(hidden_dim, dim), nn.Identity())

    def forward(self, x):
        return self.net(x)


class Attention(nn.Module):
    """The official EfficientAttention: softmax(q·kᵀ·dim_head^-0.5)·v over heads split as '(h d)'.

    Self-attention when kv_dim is None (to_qkv), else cross-attention of x onto z (to_q, to_kv).
    """

    def __init__(self, dim, heads, dim_head, kv_dim=None):
        super().__init__()
        inner_dim = heads * dim_head
        self.heads = heads
        if kv_dim is None:
            self.to_qkv = nn.Linear(dim, 3 * inner_dim, bias=False)
        else:
            self.to_q = nn.Linear(dim, inner_dim, bias=False)
            self.to_kv = nn.Linear(kv_dim, 2 * inner_dim, bias=False)
        project_out = not (heads == 1 and dim_head == dim)
        # Official: Sequential(Dropout-or-Identity, Linear, Dropout) -> key to_out.1.
        self.to_out = (nn.Sequential(nn.Identity(), nn.Linear(inner_dim, dim), nn.Identity())
                       if project_out else nn.Identity())

    def forward(self, x, z=None):
        if z is None:
            q, k, v = self.to_qkv(x).chunk(3, dim=-1)
        else:
            q = self.to_q(x)
            k, v = self.to_kv(z).chunk(2, dim=-1)
        q, k, v = (t.unflatten(-1, (self.heads, -1)).transpose(1, 2) for t in (q, k, v))
        # The official mode "efficient" is this call; its default scale is dim_head^-0.5.
        out = F.scaled_dot_product_attention(q, k, v)
        return self.to_out(out.transpose(1, 2).flatten(2))


class Transformer(nn.Module):
    """Pre-norm transformer without a final LayerNorm; cross-attends to z when kv_dim is set."""

    def __init__(self, dim, depth, heads, dim_head, mlp_dim, kv_dim=None):
        super().__init__()
        self.layers = nn.ModuleList([
            nn.ModuleList([PreNorm(dim, Attention(dim, heads, dim_head, kv_dim)),
                           PreNorm(dim, FeedForward(dim, mlp_dim))])
            for _ in range(depth)])

    def forward(self, x, z=None):
        for attn, ff in self.layers:
            x = attn(x, z=z) + x
            x = ff(x) + x
        return x


def _norm2d(norm, channels):
    # Official: anything but "Batch" means no normalisation.
    return nn.BatchNorm2d(channels) if norm == "Batch" else nn.Identity()


class SRTConvBlock(nn.Module):
    """Conv3x3 (stride 1) -> norm -> ReLU -> Conv3x3 (stride 2) -> norm -> ReLU, convolutions without bias."""

    def __init__(self, idim, hdim=None, odim=None, norm=None):
        super().__init__()
        hdim = idim if hdim is None else hdim
        odim = 2 * hdim if odim is None else odim
        self.layers = nn.Sequential(
            nn.Conv2d(idim, hdim, kernel_size=3, stride=1, padding=1, bias=False), _norm2d(norm, hdim), nn.ReLU(),
            nn.Conv2d(hdim, odim, kernel_size=3, stride=2, padding=1, bias=False), _norm2d(norm, odim), nn.ReLU())

    def forward(self, x):
        return self.layers(x)


class SRTEncoder(nn.Module):
    """Images + ray encoding -> conv blocks -> 1x1 conv to tokens -> self-attention transformer."""

    def __init__(self, num_conv_blocks=4, num_att_blocks=10, pos_start_octave=0, num_octaves=15, max_pooling=False,
                 norm=None, latent_dim=768, conv_hidden=96, token_dim=768, heads=12, dim_head=64):
        super().__init__()
        self.ray_encoder = RayEncoder(pos_octaves=num_octaves, pos_start_octave=pos_start_octave,
                                      ray_octaves=num_octaves)
        conv_blocks = [SRTConvBlock(idim=3 + 12 * num_octaves, hdim=conv_hidden, norm=norm)]
        channels = 2 * conv_hidden
        for _ in range(1, num_conv_blocks):
            conv_blocks.append(SRTConvBlock(idim=channels, norm=norm))
            channels *= 2
        self.conv_blocks = nn.Sequential(*conv_blocks)
        self.pooling = nn.MaxPool2d(2) if max_pooling else nn.Identity()
        self.per_patch_linear = nn.Conv2d(channels, token_dim, kernel_size=1)
        self.transformer = Transformer(token_dim, num_att_blocks, heads, dim_head, mlp_dim=int(latent_dim * 2))

    def forward(self, images, camera_pos, rays):
        """images [b, n, 3, H, W] in [0, 1], camera_pos [b, n, 3], rays [b, n, H, W, 3] -> z [b, n·h·w, token_dim]."""
        batch_size = images.shape[0]
        ray_enc = self.ray_encoder(camera_pos.flatten(0, 1), rays.flatten(0, 1))
        x = torch.cat((images.flatten(0, 1), ray_enc), 1)
        x = self.per_patch_linear(self.pooling(self.conv_blocks(x)))
        x = x.flatten(2).transpose(1, 2)  # row-major tokens per image, then images in order
        return self.transformer(x.reshape(batch_size, -1, x.shape[-1]))


class RayPredictor(nn.Module):
    """Query encoding -> input_mlp -> cross-attention onto z (-> optional output_mlp).

    Built as the official SRTDecoder and SlotMixerDecoder build it, i.e. always with the input_mlp.
    """

    def __init__(self, num_att_blocks=2, pos_octaves=15, pos_start_octave=0, pos_end_octave=None, ray_octaves=15,
                 ray_start_octave=0, ray_end_octave=None, out_dims=3, output_mlp=True, latent_dim=768, heads=12,
                 input_mlp_hidden=360, return_queries=False):
        super().__init__()
        self.return_queries = return_queries
        idim = 6 * (pos_octaves + ray_octaves)
        self.query_encoder = RayEncoder(pos_octaves, pos_start_octave, pos_end_octave,
                                        ray_octaves, ray_start_octave, ray_end_octave)
        self.transformer = Transformer(idim, num_att_blocks, heads, dim_head=int(latent_dim / heads),
                                       mlp_dim=int(latent_dim * 2), kv_dim=latent_dim)
        self.input_mlp = nn.Sequential(nn.Linear(idim, input_mlp_hidden), nn.ReLU(),
                                       nn.Linear(input_mlp_hidden, idim))
        if output_mlp:
            if out_dims not in (3, 128):
                raise ValueError(f"RayPredictor output_mlp supports out_dims 3 or 128, got {out_dims}")
            self.output_mlp = nn.Sequential(nn.Linear(idim, 128), nn.ReLU(), nn.Linear(128, out_dims))
        else:
            self.output_mlp = nn.Identity()

    def forward(self, z, x, rays):
        """-> output, or (output, queries after input_mlp) with return_queries (the OSRT allocation transformer)."""
        queries = self.input_mlp(self.query_encoder(x, rays))
        output = self.output_mlp(self.transformer(queries, z))
        return (output, queries) if self.return_queries else output


class SRTDecoder(nn.Module):
    """The RayPatchQuerying "srt" decoder: RayPredictor, then a 5-layer LeakyReLU(0.01) out_mlp, no activation."""

    def __init__(self, num_att_blocks=2, pos_octaves=15, pos_start_octave=0, pos_end_octave=None, ray_octaves=15,
                 ray_start_octave=0, ray_end_octave=None, out_dims=3, out_mlp=True, latent_dim=768, mode="efficient",
                 heads=12, input_mlp_hidden=360, out_mlp_hidden=1536):
        super().__init__()
        if mode not in ("base", "efficient"):  # both official modes compute the same attention
            raise ValueError(f"decoder_kwargs.mode must be 'base' or 'efficient', got {mode!r}")
        idim = 6 * (pos_octaves + ray_octaves)
        self.ray_predictor = RayPredictor(num_att_blocks, pos_octaves, pos_start_octave, pos_end_octave,
                                          ray_octaves, ray_start_octave, ray_end_octave, out_dims=out_dims,
                                          output_mlp=not out_mlp, latent_dim=latent_dim, heads=heads,
                                          input_mlp_hidden=input_mlp_hidden)
        if out_mlp:
            hidden = out_mlp_hidden
            self.out_mlp = nn.Sequential(
                nn.Linear(idim, hidden), nn.LeakyReLU(),
                nn.Linear(hidden, hidden), nn.LeakyReLU(),
                nn.Linear(hidden, hidden), nn.LeakyReLU(),
                nn.Linear(hidden, hidden), nn.LeakyReLU(),
                nn.Linear(hidden, out_dims))
        else:
            self.out_mlp = nn.Identity()

    def forward(self, z, x, rays):
        """z [b, tokens, latent_dim], x (camera positions) and rays [b, p, 3] -> [b, p, out_dims]."""
        return self.out_mlp(self.ray_predictor(z, x, rays))


class FeatureDecoder(nn.Module):
    """GIRAFFE-style upsampler: per block nearest x2 + conv + norm + LeakyReLU(0.2), summed bilinear RGB skips."""

    def __init__(self, conv_features=128, upsample=3, out_dims=3, norm=None):
        super().__init__()
        self.upsample = upsample
        self.conv_0 = nn.Conv2d(conv_features, out_dims, 3, padding=1)
        self.conv_blocks = nn.ModuleList()
        for i in range(upsample):
            c_in, c_out = int(conv_features / 2**i), int(conv_features / 2**(i + 1))
            self.conv_blocks.append(nn.ModuleList([
                nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv2d(c_in, c_out, 3, padding=1),
                              _norm2d(norm, c_out), nn.LeakyReLU(0.2)),
                nn.Conv2d(c_out, out_dims, 3, padding=1)]))

    def forward(self, x):
        """x [n, conv_features, h, w] -> [n, out_dims, h·2^upsample, w·2^upsample]."""
        skip = F.interpolate(self.conv_0(x), scale_factor=2, mode="bilinear", align_corners=False)
        for i, (conv_block, conv_out) in enumerate(self.conv_blocks):
            x = conv_block(x)
            x_out = conv_out(x) + skip
            if i < self.upsample - 1:
                skip = F.interpolate(x_out, scale_factor=2, mode="bilinear", align_corners=False)
        return x_out


class RayPatchDecoder(nn.Module):
    """Reshapes patch features to image grids and upsamples them by k = 2^upsample."""

    def __init__(self, out_dims=3, conv_features=128, h_in=16, w_in=16, h_out=None, w_out=None, upsample=3,
                 norm=None):
        super().__init__()
        if upsample < 1 or not conv_features / 2**upsample > 1:
            raise ValueError(f"rp_kwargs need upsample >= 1 and conv_features / 2^upsample > 1, "
                             f"got conv_features {conv_features}, upsample {upsample}")
        self.h_in = h_in
        self.w_in = w_in
        self.out_size = (h_out, w_out) if h_out is not None and w_out is not None else None
        self.upsample = upsample
        self.conv_decoder = FeatureDecoder(conv_features, upsample, out_dims, norm=norm)

    def forward(self, x, grid=None, out_size=None):
        """x [b, n·h_in·w_in, conv_features] -> [b, n, H, W, out_dims].

        grid (h_in, w_in) and out_size (H, W) default to the configured values; the official code only knows
        the configured ones, the renderer passes those of the actual target.
        """
        b, _, features = x.shape
        h_in, w_in = grid or (self.h_in, self.w_in)
        out = self.conv_decoder(x.reshape(-1, h_in, w_in, features).permute(0, 3, 1, 2))
        out_size = out_size or self.out_size
        if out_size is not None:
            out = F.interpolate(out, out_size)  # official: default mode, i.e. nearest
        return out.reshape(b, -1, *out.shape[1:]).permute(0, 1, 3, 4, 2)


def _build(module_cls, section, kwargs):
    """Constructs module_cls(**kwargs), rejecting keys its constructor does not take (as the official code does)."""
    accepted = inspect.signature(module_cls.__init__).parameters
    for key in kwargs:
        if key not in accepted or key == "self":
            raise ValueError(f"model config: unknown key {section}.{key}")
    return module_cls(**kwargs)


def _model_sections(model_cfg, base):
    """A copy of a run's model section checked for `base`, and its Ray-Patch decoder: the RayPatchDecoder of
    rp_kwargs for `decoder: featurefield`, None for `lightfield`."""
    cfg = copy.deepcopy(model_cfg)
    if cfg.get("base") != base:
        raise ValueError(f"model config: base must be {base!r}, got {cfg.get('base')!r}")
    for section in ("encoder_kwargs", "decoder_kwargs"):
        if not isinstance(cfg.get(section), dict):
            raise ValueError(f"model config: missing section {section}")
    if cfg.get("decoder") == "featurefield":
        if not isinstance(cfg.get("rp_kwargs"), dict):
            raise ValueError("model config: decoder featurefield needs section rp_kwargs")
        return cfg, _build(RayPatchDecoder, "rp_kwargs", cfg["rp_kwargs"])
    if cfg.get("decoder") == "lightfield":
        return cfg, None
    raise ValueError(f"model config: decoder must be 'lightfield' or 'featurefield', got {cfg.get('decoder')!r}")


class _LightFieldModel(nn.Module):
    """encoder + decoder_att + decoder_rp (a RayPatchDecoder, or the identity for a light field)."""

    def __init__(self, encoder, decoder_att, decoder_rp):
        super().__init__()
        self.encoder = encoder
        self.decoder_att = decoder_att
        self.decoder_rp = decoder_rp

    @property
    def patch_size(self):
        """k: pixels per patch-ray side (1 for a light field)."""
        return 2**self.decoder_rp.upsample if isinstance(self.decoder_rp, RayPatchDecoder) else 1


def _query_rays(k, decoder_rp, target_camera_pos, target_rays, target_size):
    """The decoder queries of whole target views (SRT and OSRT render_views).

    target_camera_pos [B, T, 3], target_rays [B, T, h, w, 3] -> (camera_pos [B, P, 3], rays [B, P, 3], patch grid
    (gh, gw), out_size (Ht, Wt) for the Ray-Patch nearest resize or None, target size (Ht, Wt)), P = T·gh·gw.
    """
    b, t, h, w, _ = target_rays.shape
    ht, wt = target_size or (h, w)
    if (h, w) == (ht, wt) and k > 1:
        rays = F.interpolate(target_rays.flatten(0, 1).permute(0, 3, 1, 2), size=(ht // k, wt // k),
                             mode="bilinear", align_corners=False, antialias=False)
        rays = rays.permute(0, 2, 3, 1).unflatten(0, (b, t))
    elif (h, w) == (ht // k, wt // k):
        rays = target_rays
    else:
        raise ValueError(f"target rays grid {h}x{w} is neither the target size {ht}x{wt} "
                         f"nor the patch grid {ht // k}x{wt // k}")
    grid_h, grid_w = rays.shape[2:4]
    out_size = None
    if k > 1:
        if decoder_rp.out_size is not None:
            # Official test_profile.py sets h_out, w_out to the rendered size; nearest resize to it.
            out_size = (ht, wt)
        elif (grid_h * k, grid_w * k) != (ht, wt):
            raise ValueError(f"target size {ht}x{wt} is not a multiple of k={k} and rp_kwargs set no h_out/w_out")
    camera_pos = target_camera_pos[:, :, None, :].expand(b, t, grid_h * grid_w, 3).reshape(b, -1, 3)
    return camera_pos, rays.reshape(b, -1, 3), (grid_h, grid_w), out_size, (ht, wt)


class SRT(_LightFieldModel):
    """encoder + decoder_att + decoder_rp, output sigmoid(decoder_rp(decoder_att(z, pos, rays)))."""

    @classmethod
    def from_config(cls, model_cfg):
        """Builds the model from a run's config.yaml model section (a plain dict)."""
        cfg, decoder_rp = _model_sections(model_cfg, "srt")
        encoder = _build(SRTEncoder, "encoder_kwargs", cfg["encoder_kwargs"])
        decoder_kwargs = cfg["decoder_kwargs"]
        if decoder_rp is not None:
            # Official SRT.__init__ overwrites decoder_kwargs.out_dims with the patch feature width.
            decoder_kwargs["out_dims"] = cfg["rp_kwargs"].get("conv_features", 128)
            out_dims = cfg["rp_kwargs"].get("out_dims", 3)
        else:
            decoder_rp = nn.Identity()
            out_dims = decoder_kwargs.get("out_dims", 3)
        if out_dims not in (3, 4):
            raise ValueError(f"model config: out_dims must be 3 (rgb) or 4 (rgb + log-depth), got {out_dims}")
        decoder_att = _build(SRTDecoder, "decoder_kwargs", decoder_kwargs)
        return cls(encoder, decoder_att, decoder_rp)

    def encode(self, images, camera_pos, rays):
        """images [B, N, 3, H, W], camera_pos [B, N, 3], rays [B, N, H, W, 3] -> z [B, tokens, token_dim]."""
        return self.encoder(images, camera_pos, rays)

    def decode(self, z, camera_pos, rays, patch_grid=None, out_size=None):
        """The official SRT.decoder: camera_pos and rays [B, P, 3] -> (rgb [B, P', 3], logdepth [B, P'] or None).

        For Ray-Patch, P = n_img·h·w patch rays on a patch_grid (h, w) (default: the configured h_in, w_in)
        and P' = n_img·H·W pixels.
        """
        out = self.decoder_att(z, camera_pos, rays)
        if isinstance(self.decoder_rp, RayPatchDecoder):
            out = self.decoder_rp(out, patch_grid, out_size).flatten(1, 3)
        logdepth = None
        if out.shape[-1] == 4:
            logdepth = out[..., 3]
            out = out[..., :3]
        return torch.sigmoid(out), logdepth

    def render_views(self, z, target_camera_pos, target_rays, target_size=None):
        """Renders whole target views: target_camera_pos [B, T, 3], target_rays [B, T, h, w, 3]
        -> (rgb [B, T, Ht, Wt, 3], logdepth [B, T, Ht, Wt] or None).

        target_size (Ht, Wt) defaults to the ray grid. A ray grid of the target size is full resolution: for
        Ray-Patch its patch rays are made like the official MSN-Easy loader, torchvision
        Resize([Ht//k, Wt//k], antialias=False) (bilinear, align_corners=False) without renormalisation.
        A ray grid of (Ht//k, Wt//k) holds patch rays and is used as given.
        """
        b, t = target_rays.shape[:2]
        camera_pos, rays, grid, out_size, (ht, wt) = _query_rays(self.patch_size, self.decoder_rp,
                                                                 target_camera_pos, target_rays, target_size)
        rgb, logdepth = self.decode(z, camera_pos, rays, grid, out_size)
        rgb = rgb.reshape(b, t, ht, wt, 3)
        if logdepth is not None:
            logdepth = logdepth.reshape(b, t, ht, wt)
        return rgb, logdepth


# --- OSRT / RP-OSRT (the official OSRT class of src/model.py) ------------------------------------------------


class SlotAttention(nn.Module):
    """Slot Attention (Locatello et al.) as the official src/layers.py has it, with learned initial slots.

    x = LN(inputs), k = to_k(x), v = to_v(x); per iteration q = to_q(LN(slots)),
    attn = softmax_slots(q·kᵀ·slot_dim^-0.5) + eps, normalised over the inputs, slots = GRUCell(attn·v, slots),
    slots += mlp(LN(slots)).
    """

    def __init__(self, num_slots, input_dim=768, slot_dim=1536, hidden_dim=3072, iters=3, eps=1e-8,
                 randomize_initial_slots=False):
        super().__init__()
        if randomize_initial_slots:
            # The official code samples around initial_slots with an embedding_stdev it never defines.
            raise ValueError("model config: encoder_kwargs.randomize_initial_slots must be false")
        self.num_slots = num_slots
        self.iters = iters
        self.scale = slot_dim**-0.5
        self.slot_dim = slot_dim
        self.eps = eps
        self.initial_slots = nn.Parameter(torch.randn(num_slots, slot_dim))
        self.to_q = nn.Linear(slot_dim, slot_dim, bias=False)
        self.to_k = nn.Linear(input_dim, slot_dim, bias=False)
        self.to_v = nn.Linear(input_dim, slot_dim, bias=False)
        self.gru = nn.GRUCell(slot_dim, slot_dim)  # weights stacked in PyTorch's gate order r, z, n
        self.mlp = nn.Sequential(nn.Linear(slot_dim, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, slot_dim))
        self.norm_input = nn.LayerNorm(input_dim)
        self.norm_slots = nn.LayerNorm(slot_dim)
        self.norm_pre_mlp = nn.LayerNorm(slot_dim)

    def forward(self, inputs):
        """inputs [b, n, input_dim] -> slots [b, num_slots, slot_dim]."""
        b = inputs.shape[0]
        inputs = self.norm_input(inputs)
        k, v = self.to_k(inputs), self.to_v(inputs)
        slots = self.initial_slots.unsqueeze(0).expand(b, -1, -1)
        for _ in range(self.iters):
            q = self.to_q(self.norm_slots(slots))
            logits = torch.einsum("bsd,bnd->bsn", q, k) * self.scale  # [b, slots, inputs]
            attn = logits.softmax(dim=1) + self.eps  # competition between the slots for each input
            attn = attn / attn.sum(dim=-1, keepdim=True)  # weighted mean over the inputs
            updates = torch.einsum("bnd,bsn->bsd", v, attn)
            slots = self.gru(updates.flatten(0, 1), slots.flatten(0, 1)).reshape(b, self.num_slots, self.slot_dim)
            slots = slots + self.mlp(self.norm_pre_mlp(slots))
        return slots


class OSRTEncoder(nn.Module):
    """SRTEncoder (its transformer FF hidden 2·latent_dim) -> SlotAttention on its tokens.

    The official OSRTEncoder passes none of SlotAttention's input_dim / hidden_dim (768 / 3072); here they are the
    token width and slot_hidden.
    """

    def __init__(self, num_conv_blocks=3, num_att_blocks=5, num_octaves=15, pos_start_octave=0, num_slots=6,
                 slot_dim=1536, slot_iters=1, max_pooling=False, norm=None, randomize_initial_slots=False,
                 latent_dim=768, conv_hidden=96, token_dim=768, heads=12, dim_head=64, slot_hidden=3072):
        super().__init__()
        self.srt_encoder = SRTEncoder(num_conv_blocks=num_conv_blocks, num_att_blocks=num_att_blocks,
                                      pos_start_octave=pos_start_octave, num_octaves=num_octaves,
                                      max_pooling=max_pooling, norm=norm, latent_dim=latent_dim,
                                      conv_hidden=conv_hidden, token_dim=token_dim, heads=heads, dim_head=dim_head)
        self.slot_attention = SlotAttention(num_slots, input_dim=token_dim, slot_dim=slot_dim, hidden_dim=slot_hidden,
                                            iters=slot_iters, randomize_initial_slots=randomize_initial_slots)

    def forward(self, images, camera_pos, rays, return_set_latent=False):
        """-> slots [b, num_slots, slot_dim] (and the set latent [b, tokens, token_dim] with return_set_latent)."""
        set_latent = self.srt_encoder(images, camera_pos, rays)
        slots = self.slot_attention(set_latent)
        return (slots, set_latent) if return_set_latent else slots


class MixingBlock(nn.Module):
    """Per query: w = softmax over slots of to_q(x)·to_k(slots)ᵀ·att_dim^-0.5, s = Σ_slots w·slot.

    With layer_norm, norm1 normalises x before to_q and norm2 normalises s.
    """

    def __init__(self, input_dim=180, slot_dim=1536, att_dim=1536, layer_norm=False):
        super().__init__()
        self.to_q = nn.Linear(input_dim, att_dim, bias=False)
        self.to_k = nn.Linear(slot_dim, att_dim, bias=False)
        if layer_norm:
            self.norm1 = nn.LayerNorm(input_dim)
            self.norm2 = nn.LayerNorm(slot_dim)
        self.scale = att_dim**-0.5
        self.layer_norm = layer_norm

    def forward(self, x, slots):
        """x [b, p, input_dim], slots [b, s, slot_dim] -> (mix [b, p, slot_dim], weights [b, p, s])."""
        if self.layer_norm:
            x = self.norm1(x)
        logits = torch.einsum("bpd,bsd->bps", self.to_q(x), self.to_k(slots)) * self.scale
        weights = logits.softmax(dim=2)
        mix = (weights.unsqueeze(-1) * slots.unsqueeze(1)).sum(2)
        if self.layer_norm:
            mix = self.norm2(mix)
        return mix, weights


class RenderMLP(nn.Module):
    """4 x (Linear + LeakyReLU(0.01)), Linear(hidden, out): no activation for out 3, LeakyReLU(0.01) otherwise."""

    def __init__(self, input_dim=1536 + 180, hidden_dim=1536, out_dim=3):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(input_dim, hidden_dim), nn.LeakyReLU(),
            nn.Linear(hidden_dim, hidden_dim), nn.LeakyReLU(),
            nn.Linear(hidden_dim, hidden_dim), nn.LeakyReLU(),
            nn.Linear(hidden_dim, hidden_dim), nn.LeakyReLU(),
            nn.Linear(hidden_dim, out_dim), nn.Identity() if out_dim == 3 else nn.LeakyReLU())

    def forward(self, x):
        return self.net(x)


class SlotMixerDecoder(nn.Module):
    """The OSRT Slot Mixer decoder: allocation transformer (queries cross-attend to the slots), mixing block,
    render MLP on cat(slot mix, queries after input_mlp).

    Query encoding as in the official code: 15 position octaves from pos_start_octave, 15 ray octaves from 0
    (query width 180). latent_dim (the slot width) is the allocation transformer's key/value width, split into
    heads of latent_dim // heads, FF hidden 2·latent_dim.
    """

    def __init__(self, num_att_blocks=2, pos_start_octave=0, layer_norm=False, mode="efficient", out_dims=3,
                 latent_dim=1536, heads=12, input_mlp_hidden=360, att_dim=1536, render_mlp_hidden=1536):
        super().__init__()
        if mode not in ("base", "efficient"):  # both official modes compute the same attention
            raise ValueError(f"decoder_kwargs.mode must be 'base' or 'efficient', got {mode!r}")
        if latent_dim % heads:
            raise ValueError(f"model config: decoder_kwargs.latent_dim {latent_dim} is not a multiple of "
                             f"heads {heads}")
        query_dim = 6 * (15 + 15)
        self.allocation_transformer = RayPredictor(num_att_blocks, pos_octaves=15, pos_start_octave=pos_start_octave,
                                                   ray_octaves=15, ray_start_octave=0, output_mlp=False,
                                                   latent_dim=latent_dim, heads=heads,
                                                   input_mlp_hidden=input_mlp_hidden, return_queries=True)
        self.mixing_block = MixingBlock(query_dim, latent_dim, att_dim, layer_norm)
        self.render_mlp = RenderMLP(latent_dim + query_dim, render_mlp_hidden, out_dims)

    def forward(self, slots, camera_pos, rays):
        """slots [b, s, latent_dim], camera_pos and rays [b, p, 3] -> (out [b, p, out_dims], weights [b, p, s])."""
        x, queries = self.allocation_transformer(slots, camera_pos, rays)
        mix, weights = self.mixing_block(x, slots)
        return self.render_mlp(torch.cat((mix, queries), -1)), weights


class OSRT(_LightFieldModel):
    """encoder (SRT encoder + slot attention) + decoder_att (Slot Mixer) + decoder_rp (Ray-Patch or identity).

    Same API as SRT; decode and render_views also return the segmentation (slot weights per pixel).
    """

    @classmethod
    def from_config(cls, model_cfg):
        """Builds the model from a run's config.yaml model section (a plain dict) with base osrt."""
        cfg, decoder_rp = _model_sections(model_cfg, "osrt")
        encoder = _build(OSRTEncoder, "encoder_kwargs", cfg["encoder_kwargs"])
        decoder_kwargs = cfg["decoder_kwargs"]
        if decoder_rp is not None:
            out_dims = cfg["rp_kwargs"].get("out_dims", 3)
            if out_dims not in (3, 4):
                raise ValueError(f"model config: rp_kwargs.out_dims must be 3 (rgb) or 4 (rgb + log-depth), "
                                 f"got {out_dims}")
            # Official OSRT.__init__ overwrites decoder_kwargs.out_dims with the patch feature width ...
            decoder_kwargs["out_dims"] = cfg["rp_kwargs"].get("conv_features", 128)
        else:
            decoder_rp = nn.Identity()
            decoder_kwargs["out_dims"] = 3  # ... and with 3 for a light field, whatever the config says.
        decoder_att = _build(SlotMixerDecoder, "decoder_kwargs", decoder_kwargs)
        slot_dim = encoder.slot_attention.slot_dim
        latent_dim = decoder_att.mixing_block.to_k.in_features
        if latent_dim != slot_dim:
            raise ValueError(f"model config: decoder_kwargs.latent_dim {latent_dim} must equal "
                             f"encoder_kwargs.slot_dim {slot_dim}")
        return cls(encoder, decoder_att, decoder_rp)

    def encode(self, images, camera_pos, rays, return_set_latent=False):
        """images [B, N, 3, H, W], camera_pos [B, N, 3], rays [B, N, H, W, 3] -> slots [B, num_slots, slot_dim]
        (and the set latent of the SRT encoder [B, tokens, token_dim] with return_set_latent)."""
        return self.encoder(images, camera_pos, rays, return_set_latent)

    def decode(self, z, camera_pos, rays, patch_grid=None, out_size=None):
        """The official OSRT.decoder in eval mode: camera_pos and rays [B, P, 3]
        -> (rgb [B, P', 3], logdepth [B, P'] or None, segmentation [B, P', S]).

        For Ray-Patch, P = n_img·h·w patch rays on a patch_grid (h, w) (default: the configured h_in, w_in),
        P' = n_img·H·W pixels, and the segmentation is the slot weights of the patch rays bilinearly resized
        (align_corners=False, no antialiasing, not renormalised) to H x W, the size of the decoded image (after
        the h_out/w_out resize). The official code hard-codes 5 slots and 2 target views there; this does not.
        """
        out, weights = self.decoder_att(z, camera_pos, rays)
        if isinstance(self.decoder_rp, RayPatchDecoder):
            b, _, num_slots = weights.shape
            h, w = patch_grid or (self.decoder_rp.h_in, self.decoder_rp.w_in)
            out = self.decoder_rp(out, patch_grid, out_size)  # [B, n_img, H, W, C]
            weights = F.interpolate(weights.reshape(-1, h, w, num_slots).permute(0, 3, 1, 2),
                                    size=out.shape[2:4], mode="bilinear", align_corners=False)
            weights = weights.permute(0, 2, 3, 1).reshape(b, -1, num_slots)
            out = out.flatten(1, 3)
        logdepth = None
        if out.shape[-1] == 4:
            logdepth = out[..., 3]
            out = out[..., :3]
        return torch.sigmoid(out), logdepth, weights

    def render_views(self, z, target_camera_pos, target_rays, target_size=None):
        """Renders whole target views from the slots z: target_camera_pos [B, T, 3], target_rays [B, T, h, w, 3]
        -> (rgb [B, T, Ht, Wt, 3], logdepth [B, T, Ht, Wt] or None, segmentation [B, T, Ht, Wt, S]).

        Target rays and target_size as for SRT.render_views.
        """
        b, t = target_rays.shape[:2]
        camera_pos, rays, grid, out_size, (ht, wt) = _query_rays(self.patch_size, self.decoder_rp,
                                                                 target_camera_pos, target_rays, target_size)
        rgb, logdepth, segmentation = self.decode(z, camera_pos, rays, grid, out_size)
        rgb = rgb.reshape(b, t, ht, wt, 3)
        if logdepth is not None:
            logdepth = logdepth.reshape(b, t, ht, wt)
        return rgb, logdepth, segmentation.reshape(b, t, ht, wt, -1)


MODEL_CLASSES = {"srt": SRT, "osrt": OSRT}
MODEL_BASES = ("define", "osrt", "srt")


def build_model(model_cfg):
    """SRT, OSRT or DeFiNe (tools/reference/reference_define.py) from a config.yaml model section, by its `base`."""
    base = model_cfg.get("base") if isinstance(model_cfg, dict) else None
    if base not in MODEL_BASES:
        raise ValueError(f"model config: base must be one of {sorted(MODEL_BASES)}, got {base!r}")
    if base == "define":
        # Imported here, not at module level: reference_define builds on the layers of this module (no import cycle).
        from reference.reference_define import DeFiNe
        return DeFiNe.from_config(model_cfg)
    return MODEL_CLASSES[base].from_config(model_cfg)


def adjusted_rand_index(true_mask, pred_mask):
    """The official compute_adjusted_rand_index (src/utils/common.py, after DeepMind's multi_object_datasets).

    true_mask [B, G, N] one-hot ground-truth groups (all-zero columns, the background, are left out),
    pred_mask [B, S, N] predicted group probabilities (argmax taken, first maximum on ties) -> ARI [B], float64.
    Counts are exact; the ARI arithmetic is float64 in the official order. When both segmentations have a single
    foreground group the ARI is 1.
    """
    _, num_true, num_points = true_mask.shape
    num_pred = pred_mask.shape[1]
    if num_points <= num_true and num_points <= num_pred:
        raise ValueError("adjusted_rand_index needs more points than groups")
    true_ids = true_mask.argmax(1)
    pred_ids = pred_mask.argmax(1)
    true_onehot = true_mask.double()
    pred_onehot = F.one_hot(pred_ids, num_pred).double()  # [B, N, S]
    points = true_onehot.sum((1, 2))  # foreground points
    contingency = torch.einsum("bgn,bns->bgs", true_onehot, pred_onehot)  # [B, G, S] point counts
    a = contingency.sum(1)  # per predicted group
    b = contingency.sum(2)  # per true group
    rindex = (contingency * (contingency - 1)).sum((1, 2))
    aindex = (a * (a - 1)).sum(1)
    bindex = (b * (b - 1)).sum(1)
    expected = aindex * bindex / (points * (points - 1))
    maximum = (aindex + bindex) / 2
    ari = (rindex - expected) / (maximum - expected)

    background = true_mask.sum(1) == 0

    def single_foreground_group(ids):
        fg = torch.where(background, 0, ids + 1)
        return ((fg == fg.max(1, keepdim=True)[0]) | background).all(-1)

    single = single_foreground_group(true_ids) & single_foreground_group(pred_ids)
    return torch.where(single, torch.ones_like(ari), ari)


def foreground_ari(segmentation, masks):
    """FG-ARI as the official OSRT test_step computes it: segmentation [B, T, H, W, S] (slot weights), masks
    [B, T, H, W] integer instance ids (0 = background) -> [B] float64, all T views of a scene pooled."""
    true_onehot = F.one_hot(masks.long().flatten(1), int(masks.max()) + 1)  # [B, N, G]
    return adjusted_rand_index(true_onehot.transpose(1, 2)[:, 1:], segmentation.flatten(1, 3).transpose(1, 2))
