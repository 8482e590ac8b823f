"""Named sources for the CLI and tests: the paper's analytic domain and block-on-incline setups."""

from __future__ import annotations

import math
from collections.abc import Callable

from jaml.sources.analytic import HyperboloidPlaneCurve
from jaml.sources.base import Source
from jaml.sources.incline import BlockOnIncline

PRESETS: dict[str, Callable[[], Source]] = {
    # Fig. 5: the hyperboloid ∩ plane ellipse.
    "ellipse": HyperboloidPlaneCurve,
    # Fig. 7 top row: a 45° incline, no friction, no drag.
    "block45": lambda: BlockOnIncline(incline=math.pi / 4, name="block45"),
    # Fig. 7 middle row / the check: a 36° incline, μ = 0.2, quadratic drag.
    "block36-drag": lambda: BlockOnIncline(
        incline=math.pi / 5, friction=0.2, drag="quadratic", drag_coef=1.0, name="block36-drag"
    ),
    # Fig. 7 bottom row: high drag, incline angle drawn per row in [π/20, π/2.5].
    "block-drag-range": lambda: BlockOnIncline(
        incline=(math.pi / 20, math.pi / 2.5),
        drag="quadratic",
        drag_coef=2.0,
        name="block-drag-range",
    ),
}


def make(name: str) -> Source:
    """The preset source called `name` (see PRESETS)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown source {name!r}; valid sources: {sorted(PRESETS)}") from None
