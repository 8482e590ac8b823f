"""JAX software renderer: ray-cast MuJoCo scenes to small RGB, depth and segmentation images.

    ctx = make_context(mj_model, camera, height=64, width=64)   # host-side, once
    out = render(ctx, data)                                     # jittable, vmappable over data
"""

from envs_mjx.render.context import RenderContext, decimate, make_context
from envs_mjx.render.raycast import RenderOutput, render

__all__ = ["RenderContext", "RenderOutput", "decimate", "make_context", "render"]
