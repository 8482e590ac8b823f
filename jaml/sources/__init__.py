"""On-manifold data for AML: analytic curves, closed-form block-on-incline, off-manifold."""

from jaml.sources.analytic import HyperboloidPlaneCurve
from jaml.sources.base import Source
from jaml.sources.incline import DRAG_KINDS, BlockOnIncline, downhill_acceleration, flow
from jaml.sources.off_manifold import bounding_box, thicken, uniform_in_box
from jaml.sources.presets import PRESETS, make

__all__ = [
    "DRAG_KINDS",
    "PRESETS",
    "BlockOnIncline",
    "HyperboloidPlaneCurve",
    "Source",
    "bounding_box",
    "downhill_acceleration",
    "flow",
    "make",
    "thicken",
    "uniform_in_box",
]
