"""MuJoCo picks its GL backend when `mujoco` is first imported. test_render's comparisons against
mujoco.Renderer need the headless EGL backend, and test_domains imports mujoco first, so the
choice is made here, before any test module of this folder is imported (without it a whole-folder
run fell back to GLFW, failed test_segmentation_* and aborted the process)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
