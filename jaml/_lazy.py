"""A package's names imported from its modules on first use (PEP 562), so that importing the
package (and its configs) does not import JAX."""

from __future__ import annotations

import importlib
import sys


def exports(package: str, names: dict[str, str]):
    """(`__getattr__`, `__dir__`) for `package`: names[n] is "module" (the same name there) or
    "module:attr". A value is cached in the package once read."""
    namespace = vars(sys.modules[package])

    def __getattr__(name: str):
        if name not in names:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, _, attr = names[name].partition(":")
        value = getattr(importlib.import_module(f"{package}.{module}"), attr or name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(names))

    return __getattr__, __dir__
