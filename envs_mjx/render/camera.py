"""MuJoCo cameras: resolve a camera by name or id, precompute per-pixel rays, move them to world."""

from __future__ import annotations

import jax.numpy as jnp
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


def world_rays(rays_cam, cam_xpos, cam_xmat):
    """Rotate camera-frame rays into the world. rays_cam: [P, 3]; cam_xpos: [3]; cam_xmat: [3, 3].

    Returns (origin [3], directions [P, 3]); directions keep their length (see camera_rays).
    """
    # A broadcast sum rather than a [P, 3] x [3, 3] matmul, which XLA:CPU runs unfused.
    return cam_xpos, jnp.sum(rays_cam[:, None, :] * cam_xmat[None], axis=-1)
