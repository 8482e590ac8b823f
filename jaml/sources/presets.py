"""Named sources for the CLI and tests: the paper's analytic domain, block-on-incline setups, and
rows from the MJX incline domains (the source and target of §5's latent space transfer)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

from jaml.sources import file
from jaml.sources.analytic import Circle, HyperboloidPlaneCurve
from jaml.sources.base import Source
from jaml.sources.incline import BlockOnIncline


def _incline_env(name: str) -> Callable[..., Source]:
    def build(**options) -> Source:
        from jaml.sources import incline_env  # local: importing envs_mjx is slow

        return incline_env.make(name, **options)

    return build


PRESETS: dict[str, Callable[..., Source]] = {
    # Fig. 5: the hyperboloid ∩ plane ellipse.
    "ellipse": HyperboloidPlaneCurve,
    # The unit circle in R²: one relation, codimension 1.
    "circle": Circle,
    # Fig. 7 top row: a 45° incline, no friction, no drag.
    "block45": lambda: BlockOnIncline(incline=math.pi / 4, name="block45"),
    # A 36° incline, μ = 0.2, quadratic drag.
    "block36-drag": lambda: BlockOnIncline(
        incline=math.pi / 5, friction=0.2, drag="quadratic", drag_coef=1.0, name="block36-drag"
    ),
    # Fig. 7 middle row (paper): a 35° incline with high kinetic friction μ_k = 0.8. The
    # downhill acceleration is negative (the block decelerates), friction staying up-slope.
    "block35-friction": lambda: BlockOnIncline(
        incline=math.radians(35.0), friction=0.8, name="block35-friction"
    ),
    # Fig. 7 bottom row: high drag, incline angle drawn per row in [π/20, π/2.5].
    "block-drag-range": lambda: BlockOnIncline(
        incline=(math.pi / 20, math.pi / 2.5),
        drag="quadratic",
        drag_coef=2.0,
        name="block-drag-range",
    ),
    # The same with θ as τ's last entry, so that a slice at one angle (Fig. 7's 10°) is defined.
    "block-drag-range-theta": lambda: BlockOnIncline(
        incline=(math.pi / 20, math.pi / 2.5),
        drag="quadratic",
        drag_coef=2.0,
        observe_incline=True,
        name="block-drag-range-theta",
    ),
    # §5: (θ, s0, v0, a0, s1, v1) from MJX GeomOnIncline (the source domain) and MeshOnIncline
    # (the stand-in for YCB-on-incline, the target), in their normalised LD units.
    "geom-on-incline": _incline_env("geom-on-incline"),
    "mesh-on-incline": _incline_env("mesh-on-incline"),
}
# Presets whose keyword options are not dataclass fields (see `make`).
_KEYWORD_PRESETS = ("geom-on-incline", "mesh-on-incline")


def make(name: str, **overrides) -> Source:
    """The preset source called `name` (see PRESETS), with keyword overrides, or the rows of a
    user's `.npy` / `.csv` file when `name` is a path ending in one of those (`FileSource`).

    For "geom-on-incline" / "mesh-on-incline" the overrides are `InclineEnvSource` options
    (action_range, rollout_steps, pool_size, drop_clipped) or fields of the env's config, e.g.
    `make("geom-on-incline", friction_range=(0.0, 0.0), action_range=(0.0, 0.0))`. For the
    others they replace fields of the source's dataclass, e.g. `make("block45", friction=0.1)`.
    """
    if name not in PRESETS and (str(name).lower().endswith(file.SUFFIXES)
                                or Path(name).is_file()):
        if overrides:
            raise ValueError(f"{name}: a file source takes no options, got {sorted(overrides)}")
        return file.FileSource.load(name)
    try:
        factory = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown source {name!r}; valid sources: {sorted(PRESETS)}, or the "
                         "path of a .npy / .csv file of [N, D] rows") from None
    if name in _KEYWORD_PRESETS:
        return factory(**overrides)
    source = factory()
    if not overrides:
        return source
    valid = {f.name for f in dataclasses.fields(source)}
    unknown = sorted(set(overrides) - valid)
    if unknown:
        raise ValueError(f"{name}: unknown source overrides {unknown}; valid: {sorted(valid)}")
    return dataclasses.replace(source, **overrides)
