"""On-manifold data for AML: analytic curves, closed-form block-on-incline, MJX incline rollouts
(`InclineEnvSource`, imported on first use since it loads envs_mjx), a user's rows from a
.npy / .csv file (`FileSource`), off-manifold samplers."""

from jaml.sources.analytic import HyperboloidPlaneCurve
from jaml.sources.base import Source
from jaml.sources.file import FileSource
from jaml.sources.incline import DRAG_KINDS, BlockOnIncline, downhill_acceleration, flow
from jaml.sources.off_manifold import bounding_box, thicken, uniform_in_box
from jaml.sources.presets import PRESETS, make

__all__ = [
    "DRAG_KINDS",
    "PRESETS",
    "BlockOnIncline",
    "FileSource",
    "HyperboloidPlaneCurve",
    "InclineEnvSource",
    "Source",
    "bounding_box",
    "downhill_acceleration",
    "flow",
    "make",
    "thicken",
    "uniform_in_box",
]


def __getattr__(name: str):
    if name == "InclineEnvSource":
        from jaml.sources.incline_env import InclineEnvSource

        return InclineEnvSource
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
