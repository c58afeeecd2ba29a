"""The PyTorch reference's SRT / RP-SRT (tools/reference/raypatch_reference.py) and the MSN-Easy cameras
(tools/reference/cameras.py): official key names, order, shapes and parameter totals (against
`assets/official/keys/`), config errors, attention, patch rays, rendering paths, input sizes and depth.

    python3 -m pytest tools/tests/test_reference_srt.py
"""

import copy

import numpy as np
import torch
import torch.nn.functional as F

from data import make_golden
from data.random_models import k4_config, random_model
from reference.cameras import get_camera_rays, look_at_positions
from reference.official_configs import RPSRT_MDBN_4_32, SRT_MDBN_32
from reference.raypatch_reference import SRT, Attention
from reference_helpers import assert_refused, compare_with_official_keys, scene_tensors


def test_official_state_dict_keys():
    """Official-size srt_MDBN_32 and rpsrt_MDBN_4_32: the same names, order and shapes as the official model."""
    compare_with_official_keys((("srt_MDBN_32", SRT_MDBN_32, 41_037_615),
                                ("rpsrt_MDBN_4_32", RPSRT_MDBN_4_32, 41_328_245)))


def test_config_errors_are_clear():
    bad = copy.deepcopy(SRT_MDBN_32)
    bad["encoder_kwargs"]["num_heads"] = 4
    for cfg, message in ((bad, "unknown key encoder_kwargs.num_heads"),
                         ({**SRT_MDBN_32, "base": "osrt"}, "base must be 'srt'"),
                         ({**RPSRT_MDBN_4_32, "rp_kwargs": None}, "needs section rp_kwargs")):
        assert_refused(SRT.from_config, cfg, message)


def test_attention_is_scaled_softmax():
    torch.manual_seed(0)
    attention = Attention(dim=20, heads=4, dim_head=8, kv_dim=12).double()
    x, z = torch.randn(2, 7, 20, dtype=torch.float64), torch.randn(2, 5, 12, dtype=torch.float64)
    q = attention.to_q(x).view(2, 7, 4, 8).transpose(1, 2)
    k, v = (t.view(2, 5, 4, 8).transpose(1, 2) for t in attention.to_kv(z).chunk(2, -1))
    weights = torch.softmax(q @ k.transpose(-1, -2) * 8**-0.5, -1)
    expected = attention.to_out((weights @ v).transpose(1, 2).reshape(2, 7, 32))
    assert torch.allclose(attention(x, z), expected, atol=1e-12)


def test_patch_rays_average_the_central_pixels():
    """Bilinear resize by 1/k (align_corners=False) = mean of the 2x2 central rays of each kxk patch."""
    rays = torch.randn(2, 3, 32, 48)
    for k in (2, 4, 8, 16):
        resized = F.interpolate(rays, size=(32 // k, 48 // k), mode="bilinear", align_corners=False,
                                antialias=False)
        centre = rays[:, :, k // 2 - 1::k, k // 2 - 1::k] + rays[:, :, k // 2 - 1::k, k // 2::k] \
            + rays[:, :, k // 2::k, k // 2 - 1::k] + rays[:, :, k // 2::k, k // 2::k]
        assert torch.allclose(resized, centre / 4, atol=1e-6), f"k={k}"


def test_render_paths_agree():
    """Full-resolution rays and given patch rays render the same; float32 and float64 agree; flat decode agrees."""
    case, scene = scene_tensors("rpsrt_k4")
    model = random_model(case.model_cfg)
    full = make_golden.run_model(model, scene, case.target_size, torch.float32)
    patches = make_golden.run_model(model, make_golden.patch_rays_of(model, scene), case.target_size,
                                    torch.float32)
    assert torch.equal(full["rgb"], patches["rgb"])
    assert full["rgb"].shape == (2, 32, 48, 3) and full["latent"].shape == (2 * 3 * 4, 16)
    double = make_golden.run_model(copy.deepcopy(model).double(), scene, case.target_size, torch.float64)
    assert (full["rgb"].double() - double["rgb"]).abs().max() < 5e-3

    # Light field: render_views is decode on the flattened rays.
    lightfield = random_model(make_golden.small_config("lightfield", width=16))
    with torch.no_grad():
        z = lightfield.encode(scene["input_images"].permute(0, 3, 1, 2)[None], scene["input_camera_pos"][None],
                              scene["input_rays"][None])
        rgb, logdepth = lightfield.render_views(z, scene["target_camera_pos"][None], scene["target_rays"][None])
        positions = scene["target_camera_pos"][:, None].expand(2, 32 * 48, 3).reshape(1, -1, 3)
        flat, _ = lightfield.decode(z, positions, scene["target_rays"].reshape(1, -1, 3))
    assert logdepth is None and torch.equal(rgb.reshape(1, -1, 3), flat)


def test_target_size_rules():
    """Sizes not divisible by k need rp h_out/w_out (nearest resize to the target size); bad grids are errors."""
    case, scene = scene_tensors("rpsrt_k4")
    rays = scene["target_rays"][:, :30, :46]  # 30x46: patch grid 7x11 -> 28x44
    model = random_model(k4_config())
    with torch.no_grad():
        z = model.encode(scene["input_images"].permute(0, 3, 1, 2)[None], scene["input_camera_pos"][None],
                         scene["input_rays"][None])
        for bad_rays, target_size in ((rays, None), (scene["target_rays"], (32, 40))):
            try:
                model.render_views(z, scene["target_camera_pos"][None], bad_rays[None], target_size)
            except ValueError:
                pass
            else:
                raise AssertionError(f"no error for a {list(bad_rays.shape[1:3])} ray grid, target {target_size}")
        resizing = random_model(k4_config(h_out=120, w_out=160))
        rgb, _ = resizing.render_views(z, scene["target_camera_pos"][None], rays[None])
    assert rgb.shape == (1, 2, 30, 46, 3)


def test_input_sizes_give_ceil_tokens():
    """Inputs of any size encode, as in PyTorch: 3 stride-2 convs (padding 1) give ceil(H/8) x ceil(W/8) tokens a
    view (60x80: 8x10, 40x60: 5x8, height x width)."""
    model = random_model(make_golden.small_config("lightfield", width=16))
    for num_views, height, width in ((1, 60, 80), (2, 40, 60), (1, 7, 9), (1, 1, 1)):
        position = look_at_positions(np.full(num_views, 30.0), np.full(num_views, 8.0), np.full(num_views, 20.0))
        rays = torch.from_numpy(np.stack([get_camera_rays(p, width, height) for p in position]))
        images = torch.rand(num_views, 3, height, width)
        with torch.no_grad():
            z = model.encode(images[None], torch.from_numpy(position)[None], rays[None])
        assert z.shape == (1, num_views * -(-height // 8) * -(-width // 8), 16), (num_views, height, width, z.shape)


def test_depth_channel():
    case, scene = scene_tensors("srt_k1_depth")
    out = make_golden.run_model(random_model(case.model_cfg), scene, case.target_size, torch.float32)
    assert out["rgb"].shape == (1, 16, 24, 3) and out["logdepth"].shape == (1, 16, 24)


# --- cameras ------------------------------------------------------------------------------------------------


def test_camera_rays():
    position = look_at_positions(35.0, 9.0, 30.0)[0]
    assert abs(np.linalg.norm(position) - 9.0) < 1e-5 and abs(position[2] - 4.5) < 1e-5
    height, width = 12, 16
    rays = get_camera_rays(position, width, height)
    assert rays.shape == (height, width, 3) and rays.dtype == np.float32
    assert np.allclose(np.linalg.norm(rays, axis=-1), 1, atol=1e-6)

    forward = -position / np.linalg.norm(position)
    right = np.cross(forward, (0, 0, 1))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    # Pixel (0, 0) is the top-left pixel centre of a 32 mm wide sensor at 35 mm focal length.
    half_width, half_height = 0.016, 0.032 / width * height / 2
    corner = 0.035 * forward + (-half_width + half_width / width) * right + (-half_height + half_height / height) * down
    assert np.allclose(rays[0, 0], corner / np.linalg.norm(corner), atol=1e-6)
    centre = rays[height // 2 - 1:height // 2 + 1, width // 2 - 1:width // 2 + 1].mean((0, 1))
    assert np.allclose(centre / np.linalg.norm(centre), forward, atol=1e-6)
    assert rays[0, :, 2].mean() > rays[-1, :, 2].mean(), "row 0 must be the top row"
