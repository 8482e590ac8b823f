"""On-manifold data for AML: analytic curves, closed-form block-on-incline, a user's rows from a
.npy / .csv file (`FileSource`), off-manifold samplers; MJX incline rollouts in
`jaml.sources.incline_env` (`InclineEnvSource`, through `make("geom-on-incline")`), a module
of its own since it imports MuJoCo and the domains, which the rest does not need."""

from jaml.sources.analytic import Circle, HyperboloidPlaneCurve
from jaml.sources.base import Source
from jaml.sources.file import FileSource
from jaml.sources.incline import DRAG_KINDS, BlockOnIncline, downhill_acceleration, flow
from jaml.sources.off_manifold import bounding_box, thicken, uniform_in_box
from jaml.sources.presets import PRESETS, make

__all__ = [
    "DRAG_KINDS",
    "PRESETS",
    "BlockOnIncline",
    "Circle",
    "FileSource",
    "HyperboloidPlaneCurve",
    "Source",
    "bounding_box",
    "downhill_acceleration",
    "flow",
    "make",
    "thicken",
    "uniform_in_box",
]

