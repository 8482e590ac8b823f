"""MuJoCo cameras: resolve a camera by name or id, precompute per-pixel rays."""

from __future__ import annotations

import mujoco
import numpy as np


def camera_id(mj_model: mujoco.MjModel, camera: str | int) -> int:
    """The id of `camera` (a name or an id); a ValueError lists the valid cameras otherwise."""
    obj = mujoco.mjtObj.mjOBJ_CAMERA
    names = [mujoco.mj_id2name(mj_model, obj, i) for i in range(mj_model.ncam)]
    valid = ", ".join(f"{i}: {n!r}" for i, n in enumerate(names)) or "none (no cameras)"
    if isinstance(camera, str):
        if camera in names:
            return names.index(camera)
    elif isinstance(camera, int | np.integer) and 0 <= int(camera) < mj_model.ncam:
        return int(camera)
    raise ValueError(f"unknown camera {camera!r}; valid cameras are {valid}")


def camera_rays(fovy_deg: float, height: int, width: int) -> np.ndarray:
    """Camera-frame ray directions through pixel centres, row-major from the top row: [H*W, 3].

    MuJoCo's camera looks along -z with +y up and +x right; fovy spans the image height and the
    horizontal extent follows the aspect ratio, as in mjv's perspective frustum. The z component
    is -1, so a hit distance t along a ray equals the linear depth MuJoCo reports.
    """
    half_h = np.tan(np.deg2rad(fovy_deg) / 2.0)
    half_w = half_h * width / height
    # Pixel centres sit at (k + 0.5) / n of the normalised extent; row 0 is the top of the image.
    x = (2.0 * (np.arange(width) + 0.5) / width - 1.0) * half_w
    y = (1.0 - 2.0 * (np.arange(height) + 0.5) / height) * half_h
    xx, yy = np.meshgrid(x, y)
    rays = np.stack([xx, yy, -np.ones_like(xx)], axis=-1)
    return rays.reshape(-1, 3).astype(np.float32)


def ray_table(fovy_deg: float, height: int, width: int) -> np.ndarray:
    """Per-pixel constants the renderer reads, feature-major: [8, H*W] float32.

    Rows: x, y of the camera-frame ray (x, y, -1); its unit direction (3 rows); the unit half
    vector between the headlight (towards +z in the camera frame) and the view (3 rows).
    """
    rays = camera_rays(fovy_deg, height, width).astype(np.float64)
    view = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    half = np.array([0.0, 0.0, 1.0]) - view
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    return np.concatenate([rays[:, :2], view, half], axis=1).T.astype(np.float32)
