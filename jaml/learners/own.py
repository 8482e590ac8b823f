"""Learners of your own: `--learner MODULE:FACTORY` names `FACTORY(ld_dim=D)`, which returns a
`jaml.learners.Learner` (the protocol: docs/own_learner.md)."""

from __future__ import annotations

import importlib
import inspect

from jaml.learners.learner import Learner


def own_learner(name: str, ld_dim: int) -> Learner:
    """The learner of your own that `name`, "MODULE:FACTORY", names: `factory(ld_dim=D)`
    returning a `jaml.learners.Learner` (the protocol: docs/own_learner.md)."""
    module, _, attr = name.partition(":")
    try:
        factory = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as error:
        raise ValueError(f"learner {name!r}: cannot import {attr} from {module} ({error}); give "
                         "MODULE:FACTORY with MODULE importable (on PYTHONPATH)") from None
    try:
        inspect.signature(factory).bind(ld_dim=ld_dim)
    except TypeError:
        raise ValueError(f"learner {name!r}: {attr} must take the keyword ld_dim (the stream "
                         f"calls {attr}(ld_dim=D), D the env's LD-state size; "
                         "docs/own_learner.md); define it as `def "
                         f"{attr}(ld_dim): ...`") from None
    except ValueError:  # no signature to read (a builtin): let the call say
        pass
    learner = factory(ld_dim=ld_dim)
    if not isinstance(learner, Learner):
        raise ValueError(f"learner {name!r}: {attr}(ld_dim=...) returned a "
                         f"{type(learner).__name__}, not a jaml.learners.Learner")
    return learner
