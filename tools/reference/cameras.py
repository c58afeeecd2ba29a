"""MultiShapeNet-Easy style cameras: pinhole cameras that look at the world origin with +z up.

get_camera_rays follows the official src/utils/nerf.py get_camera_rays of tberriel/RayPatchQuerying (no noise,
origin as track point): computed in float64, returned as float32 like the official loader.
"""

import numpy as np

WORLD_UP = np.array((0.0, 0.0, 1.0))


def get_camera_rays(c_pos, width, height, focal_length=0.035, sensor_width=0.032):
    """Unit ray directions [height, width, 3] (float32) through the pixel centres; row 0 is the top row."""
    c_pos = np.asarray(c_pos, dtype=np.float64)
    c_dir = -c_pos / np.linalg.norm(c_pos)
    img_plane_center = c_pos + c_dir * focal_length

    horizontal = np.cross(c_dir, WORLD_UP)  # image "right"
    horizontal_norm = np.linalg.norm(horizontal)
    if horizontal_norm < 1e-9:
        raise ValueError(f"camera at {c_pos.tolist()} looks along the world up axis")
    horizontal = horizontal / horizontal_norm
    vertical = np.cross(c_dir, horizontal)  # image "down", so negative offsets (row 0) are at the top
    vertical = vertical / np.linalg.norm(vertical)

    sensor_height = (sensor_width / width) * height
    horizontal_edges = np.linspace(-1, 1, width + 1) * sensor_width / 2
    vertical_edges = np.linspace(-1, 1, height + 1) * sensor_height / 2
    horizontal_offsets = (horizontal_edges[:-1] + horizontal_edges[1:]) / 2
    vertical_offsets = (vertical_edges[:-1] + vertical_edges[1:]) / 2

    image_plane = (horizontal_offsets[None, :, None] * horizontal[None, None, :]
                   + vertical_offsets[:, None, None] * vertical[None, None, :])
    rays = image_plane + img_plane_center[None, None, :] - c_pos[None, None, :]
    rays = rays / np.linalg.norm(rays, axis=2, keepdims=True)
    return rays.astype(np.float32)


def look_at_positions(azimuths_deg, distances, elevations_deg):
    """Camera centres [N, 3] (float32) on spheres around the origin; the arguments broadcast against each other.

    Azimuth is measured in the xy plane from +x towards +y, elevation from the xy plane towards +z.
    """
    azimuth, distance, elevation = np.broadcast_arrays(np.radians(azimuths_deg), np.asarray(distances, float),
                                                       np.radians(elevations_deg))
    positions = np.stack((distance * np.cos(elevation) * np.cos(azimuth),
                          distance * np.cos(elevation) * np.sin(azimuth),
                          distance * np.sin(elevation)), -1)
    return np.atleast_2d(positions).astype(np.float32)
