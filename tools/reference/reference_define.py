"""PyTorch reference of the official DeFiNe / RP-DeFiNe model of tberriel/RayPatchQuerying (commit 297afbc): the
DeFiNe class of src/model.py, DeFiNeEncoder (src/encoder.py), DeFiNeDecoder (src/decoder.py), the ResNet-18 of
src/resnet.py (torchvision's ResNet with avgpool and fc deleted, returning the four layer outputs) and the
HuggingFace transformers 4.24 PerceiverModel / PerceiverBasicDecoder it builds on.

Module and attribute names follow the official modules, torchvision's and HuggingFace's, so `DeFiNe.state_dict()`
carries exactly the official Lightning keys (`encoder.conv_blocks.layer1.0.conv1.weight`,
`encoder.transformer.encoder.cross_attention.attention.self.query.weight`, `decoder_att_rgb.…`, `decoder_rp_d.…`),
registered in the official order. Neither torchvision nor transformers is needed; nothing is downloaded (the
official `resnet18()` loads ImageNet weights at construction, here the weights come from the model file).

The Perceiver maths of transformers 4.24 (modeling_perceiver.py), as the official configs use it:
  - LayerNorms have eps 1e-5: PerceiverConfig.layer_norm_eps (1e-12 in the official configs) is never read.
  - Attention: softmax(q·kᵀ / sqrt(qk head width))·v, computed as HF does (matmul, divide, softmax, matmul).
    The encoder cross-attention has one head with q/k/v width = the token width (cross_attention_shape_for_attention
    "kv"), LayerNorms on both the latents (layernorm1) and the tokens (layernorm2), and the query residual; the
    self-attention layers have `heads` heads over latent_dim, layernorm1 only, and the residual.
    The decoder cross-attention has one head of q/k/v width latent_dim and NO residual.
  - Each layer then adds mlp(layernorm(a)), mlp = dense1, exact (erf) GELU, dense2, widening factor 1.
  - No final LayerNorm; the encoder output is last_hidden_state [B, num_latents, latent_dim].
  - The attention masks HF builds (all ones -> additive 0) change nothing and are left out; dropout is inactive.

Input images: the official ScanNet loader ImageNet-normalises the input images (torchvision Normalize, mean
(0.485, 0.456, 0.406), std (0.229, 0.224, 0.225), i.e. (x - mean) / std in the image dtype) before the model sees
them. raypatch scene files hold input images in [0, 1], so DeFiNeEncoder.forward applies that normalisation itself
before the ResNet; everything else is the official forward.

Widths that the official code hard-codes can be set through the raypatch extension keys (docs/FORMATS.md):
encoder_kwargs `resnet_width` (64), `latent_dim` (512), `heads` (8). Their defaults are the official values.
"""

import math

import torch
import torch.nn.functional as F
from torch import nn

from reference.raypatch_reference import RayEncoder, RayPatchDecoder, _build, _model_sections, _query_rays

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
DEPTH_MIN = 0.1
DEPTH_MAX = 10


def imagenet_normalize(images):
    """torchvision.transforms.Normalize(IMAGENET_MEAN, IMAGENET_STD) on [..., 3, H, W]: (x - mean) / std, with mean
    and std as tensors of the image dtype."""
    mean = torch.as_tensor(IMAGENET_MEAN, dtype=images.dtype, device=images.device).view(-1, 1, 1)
    std = torch.as_tensor(IMAGENET_STD, dtype=images.dtype, device=images.device).view(-1, 1, 1)
    return (images - mean) / std


# --- ResNet-18 (torchvision.models.resnet names) ------------------------------------------------------------


class BasicBlock(nn.Module):
    """torchvision's BasicBlock: conv3x3 (stride) -> bn -> relu -> conv3x3 -> bn, + identity or downsample, relu."""

    def __init__(self, inplanes, planes, stride=1, downsample=None):
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, kernel_size=3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU()
        self.conv2 = nn.Conv2d(planes, planes, kernel_size=3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x):
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResNetSkip(nn.Module):
    """The official ResNetSkip: torchvision resnet18 without avgpool and fc, returning [x1, x2, x3, x4].

    width is the stem and layer1 width (torchvision: 64); layer2..4 are 2x, 4x, 8x it. conv1 7x7 stride 2
    padding 3, maxpool 3x3 stride 2 padding 1, so x1 is ceil(ceil(H/2)/2) rows, and each later layer maps s to
    ceil(s/2).
    """

    def __init__(self, width=64):
        super().__init__()
        self.inplanes = width
        self.conv1 = nn.Conv2d(3, width, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU()
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.layer1 = self._make_layer(width, 1)
        self.layer2 = self._make_layer(2 * width, 2)
        self.layer3 = self._make_layer(4 * width, 2)
        self.layer4 = self._make_layer(8 * width, 2)

    def _make_layer(self, planes, stride, blocks=2):
        downsample = None
        if stride != 1 or self.inplanes != planes:
            downsample = nn.Sequential(nn.Conv2d(self.inplanes, planes, kernel_size=1, stride=stride, bias=False),
                                       nn.BatchNorm2d(planes))
        layers = [BasicBlock(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes
        layers += [BasicBlock(planes, planes) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def forward(self, x):
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x1 = self.layer1(x)
        x2 = self.layer2(x1)
        x3 = self.layer3(x2)
        x4 = self.layer4(x3)
        return [x1, x2, x3, x4]


# --- HuggingFace transformers 4.24 Perceiver (modeling_perceiver.py names) -----------------------------------


class PerceiverSelfAttention(nn.Module):
    """layernorm1 on the queries' stream, layernorm2 on the inputs (cross-attention only), q/k/v projections with
    bias; softmax(q·kᵀ / sqrt(qk_channels / heads))·v over heads split as '(heads d)'."""

    def __init__(self, is_cross_attention, qk_channels, v_channels, num_heads, q_dim, kv_dim):
        super().__init__()
        if qk_channels % num_heads or v_channels % num_heads:
            raise ValueError(f"model config: attention width {qk_channels} / {v_channels} is not a multiple of "
                             f"{num_heads} heads")
        self.num_heads = num_heads
        self.layernorm1 = nn.LayerNorm(q_dim)
        self.layernorm2 = nn.LayerNorm(kv_dim) if is_cross_attention else nn.Identity()
        self.query = nn.Linear(q_dim, qk_channels)
        self.key = nn.Linear(kv_dim, qk_channels)
        self.value = nn.Linear(kv_dim, v_channels)

    def forward(self, hidden_states, inputs=None):
        hidden_states = self.layernorm1(hidden_states)
        source = hidden_states if inputs is None else self.layernorm2(inputs)
        q, k, v = (t.unflatten(-1, (self.num_heads, -1)).transpose(1, 2)
                   for t in (self.query(hidden_states), self.key(source), self.value(source)))
        scores = torch.matmul(q, k.transpose(-1, -2)) / math.sqrt(q.shape[-1])
        context = torch.matmul(torch.softmax(scores, dim=-1), v)
        return context.transpose(1, 2).flatten(2)


class PerceiverSelfOutput(nn.Module):
    def __init__(self, input_channels, output_channels):
        super().__init__()
        self.dense = nn.Linear(input_channels, output_channels)

    def forward(self, x):
        return self.dense(x)


class PerceiverAttention(nn.Module):
    """Attention + output dense, plus the (layernormed-before) query when use_query_residual.

    HF adds the residual to the query stream as it came in (before layernorm1)."""

    def __init__(self, is_cross_attention, num_heads, q_dim, kv_dim, use_query_residual):
        super().__init__()
        # HF: cross-attention q/k width = kv_dim (cross_attention_shape_for_attention "kv"), self-attention q_dim;
        # v width = q/k width; the output dense maps back to q_dim (cross) or the v width (self).
        qk_channels = kv_dim if is_cross_attention else q_dim
        self.self = PerceiverSelfAttention(is_cross_attention, qk_channels, qk_channels, num_heads, q_dim, kv_dim)
        self.output = PerceiverSelfOutput(qk_channels, q_dim if is_cross_attention else qk_channels)
        self.use_query_residual = use_query_residual

    def forward(self, hidden_states, inputs=None):
        out = self.output(self.self(hidden_states, inputs))
        return out + hidden_states if self.use_query_residual else out


class PerceiverMLP(nn.Module):
    """dense1 -> exact GELU -> dense2 (widening factor 1 in every official use)."""

    def __init__(self, input_size, widening_factor=1):
        super().__init__()
        self.dense1 = nn.Linear(input_size, widening_factor * input_size)
        self.dense2 = nn.Linear(widening_factor * input_size, input_size)

    def forward(self, x):
        return self.dense2(F.gelu(self.dense1(x)))


class PerceiverLayer(nn.Module):
    """a = attention(x[, inputs]) (+ x); out = a + mlp(layernorm(a))."""

    def __init__(self, is_cross_attention, num_heads, q_dim, kv_dim, use_query_residual=True):
        super().__init__()
        self.attention = PerceiverAttention(is_cross_attention, num_heads, q_dim, kv_dim, use_query_residual)
        self.layernorm = nn.LayerNorm(q_dim)
        self.mlp = PerceiverMLP(q_dim)

    def forward(self, hidden_states, inputs=None):
        attention_output = self.attention(hidden_states, inputs)
        return self.mlp(self.layernorm(attention_output)) + attention_output


class PerceiverEmbeddings(nn.Module):
    def __init__(self, num_latents, d_latents):
        super().__init__()
        self.latents = nn.Parameter(torch.randn(num_latents, d_latents))


class PerceiverEncoder(nn.Module):
    """One cross-attention of the latents onto the inputs (1 head, query residual), then the self-attention block
    (num_blocks = 1 in the official configs, so each layer is applied once)."""

    def __init__(self, d_latents, kv_dim, num_self_attends, num_self_attention_heads):
        super().__init__()
        self.cross_attention = PerceiverLayer(True, 1, d_latents, kv_dim, use_query_residual=True)
        self.self_attends = nn.ModuleList(
            [PerceiverLayer(False, num_self_attention_heads, d_latents, d_latents) for _ in range(num_self_attends)])

    def forward(self, latents, inputs):
        hidden_states = self.cross_attention(latents, inputs)
        for layer in self.self_attends:
            hidden_states = layer(hidden_states)
        return hidden_states


class PerceiverModel(nn.Module):
    """PerceiverModel without preprocessor or decoder: inputs [B, N, d_model] -> last_hidden_state
    [B, num_latents, d_latents]."""

    def __init__(self, d_model, d_latents, num_latents, num_self_attends, num_self_attention_heads):
        super().__init__()
        if d_latents % num_self_attention_heads:
            raise ValueError(f"model config: encoder_kwargs.latent_dim {d_latents} is not a multiple of heads "
                             f"{num_self_attention_heads}")
        self.d_model = d_model
        self.embeddings = PerceiverEmbeddings(num_latents, d_latents)
        self.encoder = PerceiverEncoder(d_latents, d_model, num_self_attends, num_self_attention_heads)

    def forward(self, inputs):
        if inputs.shape[-1] != self.d_model:
            raise ValueError(f"Perceiver inputs are {inputs.shape[-1]} wide, d_model is {self.d_model}")
        latents = self.embeddings.latents.expand(inputs.shape[0], -1, -1)
        return self.encoder(latents, inputs)


class PerceiverBasicDecoder(nn.Module):
    """PerceiverBasicDecoder(position_encoding_type "none", num_heads 1, use_query_residual False): one
    cross-attention of the queries onto the latents (q/k/v width = latent width), mlp, final_layer."""

    def __init__(self, num_channels, d_latents, output_num_channels):
        super().__init__()
        self.decoding_cross_attention = PerceiverLayer(True, 1, num_channels, d_latents, use_query_residual=False)
        self.final_layer = nn.Linear(num_channels, output_num_channels)

    def forward(self, query, z):
        return self.final_layer(self.decoding_cross_attention(query, z))


# --- DeFiNe -------------------------------------------------------------------------------------------------


class DeFiNeEncoder(nn.Module):
    """ImageNet-normalised images -> ResNet-18 features x1..x4 (x2..x4 bilinearly resized to x1's size), ray
    features at 1/4 resolution -> tokens -> Perceiver -> latents.

    Token = cat(x1, x2, x3, x4, ray, camera position, posenc(position), posenc(ray)), 15·resnet_width + 6 +
    6·(pos_octaves + ray_octaves) wide (official 960 + 186 = 1146); tokens row-major per view, views in order.
    """

    def __init__(self, num_att_blocks=8, pos_start_octave=1, pos_octaves=20, pos_end_octave=30, ray_octaves=10,
                 ray_start_octave=1, ray_end_octave=30, num_latents=2048, resnet_width=64, latent_dim=512, heads=8):
        super().__init__()
        self.ray_encoder = RayEncoder(pos_octaves, pos_start_octave, pos_end_octave,
                                      ray_octaves, ray_start_octave, ray_end_octave)
        self.conv_blocks = ResNetSkip(resnet_width)
        token_dim = 15 * resnet_width + 6 + 6 * (pos_octaves + ray_octaves)
        self.transformer = PerceiverModel(token_dim, latent_dim, num_latents, num_att_blocks, heads)

    def forward(self, images, camera_pos, rays):
        """images [b, n, 3, H, W] in [0, 1] (normalised here), camera_pos [b, n, 3], rays [b, n, H, W, 3]
        -> z [b, num_latents, latent_dim]. H and W must be multiples of 4, as the official code needs them (it
        fails where int(H/4) x int(W/4) is not the ResNet's ceil(ceil(H/2)/2) x ceil(ceil(W/2)/2))."""
        batch_size = images.shape[0]
        x = imagenet_normalize(images.flatten(0, 1))
        camera_pos = camera_pos.flatten(0, 1)
        rays = rays.flatten(0, 1)
        _, h, w, _ = rays.shape
        h4, w4 = int(h / 4), int(w / 4)
        skips = self.conv_blocks(x)
        size = skips[0].shape[2:]
        if tuple(size) != (h4, w4):
            # The official code resizes the rays to (int(h/4), int(w/4)) and concatenates them with the ResNet's
            # ceil(ceil(H/2)/2) x ... features: with images and rays of one size, sides that 4 does not divide
            # make the sizes differ and torch.cat fails.
            raise ValueError(f"DeFiNe input views must have sides divisible by 4 (images {list(x.shape[2:])}, "
                             f"rays {[h, w]}: ResNet features {list(size)}, ray features {[h4, w4]})")
        rays = F.interpolate(rays.permute(0, 3, 1, 2), size=[h4, w4], mode="bilinear", align_corners=False)
        ray_features = torch.cat([rays, camera_pos[..., None, None].expand(-1, -1, h4, w4),
                                  self.ray_encoder(camera_pos, rays.permute(0, 2, 3, 1))], dim=1)
        skips = [skips[0]] + [F.interpolate(s, size=size, mode="bilinear", align_corners=False) for s in skips[1:]]
        x = torch.cat(skips + [ray_features], dim=1)
        x = x.flatten(2).transpose(1, 2)
        return self.transformer(x.reshape(batch_size, -1, x.shape[-1]))


class DeFiNeDecoder(nn.Module):
    """q = cat(ray, camera position, posenc(position), posenc(ray)) (6 + 6·(pos_octaves + ray_octaves) wide,
    official 186) -> PerceiverBasicDecoder onto the latents -> [b, p, out_dims]."""

    def __init__(self, pos_octaves=20, pos_start_octave=1, pos_end_octave=30, ray_octaves=10, ray_start_octave=1,
                 ray_end_octave=30, out_dims=3, latent_dim=512):
        super().__init__()
        idim = 6 * (pos_octaves + ray_octaves) + 6
        self.query_encoder = RayEncoder(pos_octaves, pos_start_octave, pos_end_octave,
                                        ray_octaves, ray_start_octave, ray_end_octave)
        self.transformer = PerceiverBasicDecoder(idim, latent_dim, out_dims)

    def forward(self, z, x, rays):
        """z [b, latents, latent_dim], x (camera positions) and rays [b, p, 3] -> [b, p, out_dims]."""
        queries = torch.cat([rays, x, self.query_encoder(x, rays)], dim=-1)
        return self.transformer(queries, z)


class DeFiNe(nn.Module):
    """encoder + (decoder_rp_rgb, decoder_rp_d: Ray-Patch decoders or identities) + decoder_att_rgb, decoder_att_d.

    rgb = sigmoid(decoder_rp_rgb(decoder_att_rgb(z, pos, rays))),
    logdepth = log(sigmoid(decoder_rp_d(decoder_att_d(z, pos, rays))) · (10 - 0.1) + 0.1).
    """

    d_min = DEPTH_MIN
    d_max = DEPTH_MAX

    def __init__(self, encoder, decoder_att_rgb, decoder_att_d, decoder_rp_rgb=None, decoder_rp_d=None):
        super().__init__()
        self.encoder = encoder
        # The official registration order: the Ray-Patch decoders before the attention decoders.
        if decoder_rp_rgb is None:
            self.decoder_rp_rgb = self.decoder_rp_d = nn.Identity()
        else:
            self.decoder_rp_rgb = decoder_rp_rgb
            self.decoder_rp_d = decoder_rp_d
        self.decoder_att_rgb = decoder_att_rgb
        self.decoder_att_d = decoder_att_d

    @classmethod
    def from_config(cls, model_cfg):
        """Builds the model from a run's config.yaml model section (a plain dict) with base define.

        decoder_kwargs.out_dims is ignored (the model sets 3 / 1, or rp_kwargs.conv_features for both heads with
        featurefield); rp_kwargs.out_dims must be absent (the official DeFiNe passes out_dims itself, so a second
        one is a TypeError there).
        """
        cfg, decoder_rp_rgb = _model_sections(model_cfg, "define")
        decoder_kwargs = dict(cfg["decoder_kwargs"])
        decoder_kwargs.pop("out_dims", None)
        if decoder_rp_rgb is not None:
            if "out_dims" in cfg["rp_kwargs"]:
                raise ValueError("model config: rp_kwargs.out_dims must be absent for base define (the rgb and "
                                 "depth heads set 3 and 1)")
            decoder_rp_d = _build(RayPatchDecoder, "rp_kwargs", {**cfg["rp_kwargs"], "out_dims": 1})
            out_rgb = out_d = cfg["rp_kwargs"].get("conv_features", 128)
        else:
            decoder_rp_d = None
            out_rgb, out_d = 3, 1
        encoder = _build(DeFiNeEncoder, "encoder_kwargs", cfg["encoder_kwargs"])
        decoder_att_rgb = _build(DeFiNeDecoder, "decoder_kwargs", {**decoder_kwargs, "out_dims": out_rgb})
        decoder_att_d = _build(DeFiNeDecoder, "decoder_kwargs", {**decoder_kwargs, "out_dims": out_d})
        encoder_latent = encoder.transformer.embeddings.latents.shape[1]
        decoder_latent = decoder_att_rgb.transformer.decoding_cross_attention.attention.self.key.in_features
        if decoder_latent != encoder_latent:
            raise ValueError(f"model config: decoder_kwargs.latent_dim {decoder_latent} must equal "
                             f"encoder_kwargs.latent_dim {encoder_latent}")
        return cls(encoder, decoder_att_rgb, decoder_att_d, decoder_rp_rgb, decoder_rp_d)

    @property
    def patch_size(self):
        """k: pixels per patch-ray side (1 for a light field)."""
        return 2**self.decoder_rp_rgb.upsample if isinstance(self.decoder_rp_rgb, RayPatchDecoder) else 1

    def encode(self, images, camera_pos, rays):
        """images [B, N, 3, H, W] in [0, 1] (ImageNet-normalised inside), camera_pos [B, N, 3], rays
        [B, N, H, W, 3] -> z [B, num_latents, latent_dim]."""
        return self.encoder(images, camera_pos, rays)

    def decode(self, z, camera_pos, rays, patch_grid=None, out_size=None):
        """The official DeFiNe.decoder: camera_pos and rays [B, P, 3] -> (rgb [B, P', 3], logdepth [B, P']).

        For Ray-Patch, P = n_img·h·w patch rays on a patch_grid (h, w) (default: the configured h_in, w_in)
        and P' = n_img·H·W pixels.
        """
        rgb = self.decoder_att_rgb(z, camera_pos, rays)
        depth = self.decoder_att_d(z, camera_pos, rays)
        if isinstance(self.decoder_rp_rgb, RayPatchDecoder):
            rgb = self.decoder_rp_rgb(rgb, patch_grid, out_size)
            depth = self.decoder_rp_d(depth, patch_grid, out_size)
        logdepth = (torch.sigmoid(depth) * (self.d_max - self.d_min) + self.d_min).log()
        if rgb.dim() > 3:
            rgb = rgb.flatten(1, 3)
            logdepth = logdepth.flatten(1)
        else:
            logdepth = logdepth.squeeze(-1)
        return torch.sigmoid(rgb), logdepth

    def render_views(self, z, target_camera_pos, target_rays, target_size=None):
        """Renders whole target views: target_camera_pos [B, T, 3], target_rays [B, T, h, w, 3]
        -> (rgb [B, T, Ht, Wt, 3], logdepth [B, T, Ht, Wt]).

        Target rays and target_size as for SRT.render_views: a ray grid of the target size is full resolution, and
        for Ray-Patch its patch rays are its bilinear resize to (Ht/k, Wt/k) (align_corners=False, no antialias),
        as the official ScanNet loader makes them; a ray grid of (Ht/k, Wt/k) holds patch rays, used as given.
        """
        b, t = target_rays.shape[:2]
        camera_pos, rays, grid, out_size, (ht, wt) = _query_rays(self.patch_size, self.decoder_rp_rgb,
                                                                 target_camera_pos, target_rays, target_size)
        rgb, logdepth = self.decode(z, camera_pos, rays, grid, out_size)
        return rgb.reshape(b, t, ht, wt, 3), logdepth.reshape(b, t, ht, wt)
