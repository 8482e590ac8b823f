"""Useful FLOPs of a JAX function, counted from its jaxpr: the convolutions and matmuls it asks
for, before any backend chooses how to run them.

XLA's `cost_analysis()` on a GPU counts none of the cuDNN convolutions, and a backend may run a
transposed convolution as a dense one over a zero-dilated input (more multiply-adds than the
model needs). This count is the model's: a convolution contributes 2 · batch · (output
features) · (input features per group) · (kernel taps that land on real input, summed over
output positions: padding and the zeros of an input dilation are not work); a `dot_general`
2 · batch · M · N · K. Elementwise work is
not counted (it is a few percent of these networks' FLOPs and bound by memory, not compute).
"""

from __future__ import annotations

import math

import jax
from jax.extend import core


def conv_flops(eqn) -> float:
    """2 · multiply-adds of one `conv_general_dilated` that touch real input: taps on padding
    and on the zeros an input dilation inserts are not counted."""
    lhs, rhs = (v.aval for v in eqn.invars)
    out = eqn.outvars[0].aval
    dims, p = eqn.params["dimension_numbers"], eqn.params
    spatial = len(dims.lhs_spec) - 2
    lhs_dilation = p["lhs_dilation"] or (1,) * spatial
    rhs_dilation = p["rhs_dilation"] or (1,) * spatial
    taps = 1
    for i in range(spatial):
        taps *= _valid_taps(lhs.shape[dims.lhs_spec[2 + i]], rhs.shape[dims.rhs_spec[2 + i]],
                            out.shape[dims.out_spec[2 + i]], p["window_strides"][i],
                            p["padding"][i][0], lhs_dilation[i], rhs_dilation[i])
    batch, features = out.shape[dims.out_spec[0]], out.shape[dims.out_spec[1]]
    kernel_in = rhs.shape[dims.rhs_spec[1]]  # input features per group
    return 2.0 * batch * features * kernel_in * taps / p["batch_group_count"]


def _valid_taps(size: int, kernel: int, out: int, stride: int, pad_lo: int, lhs_dilation: int,
                rhs_dilation: int) -> int:
    """Σ over output positions of the kernel taps that land on a real input element of one
    spatial dimension (the count is separable across dimensions)."""
    last = (size - 1) * lhs_dilation
    count = 0
    for o in range(out):
        for k in range(kernel):
            pos = o * stride + k * rhs_dilation - pad_lo
            count += 0 <= pos <= last and pos % lhs_dilation == 0
    return count


def dot_flops(eqn) -> float:
    """2 · multiply-adds of one `dot_general`."""
    lhs = eqn.invars[0].aval
    (lhs_contract, _), _ = eqn.params["dimension_numbers"]
    contract = math.prod(lhs.shape[i] for i in lhs_contract)
    out = eqn.outvars[0].aval
    return 2.0 * math.prod(out.shape) * contract


_COUNTED = {"conv_general_dilated": conv_flops, "dot_general": dot_flops}


def jaxpr_flops(jaxpr) -> dict[str, float]:
    """{primitive: FLOPs} of a (closed) jaxpr, nested calls, loops and conditionals included
    (a `scan` body counted `length` times; a `cond` counted by its costliest branch; a
    `while` body once, its trip count being unknown)."""
    totals: dict[str, float] = {}

    def add(counts: dict, times: float = 1.0) -> None:
        for name, value in counts.items():
            totals[name] = totals.get(name, 0.0) + times * value

    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        if name in _COUNTED:
            add({name: _COUNTED[name](eqn)})
            continue
        subs = [v for v in eqn.params.values() if isinstance(v, core.ClosedJaxpr | core.Jaxpr)]
        branches = eqn.params.get("branches")
        if name == "cond" and branches:
            add(max((jaxpr_flops(_open(b)) for b in branches), key=lambda c: sum(c.values())))
        elif name == "scan":
            add(jaxpr_flops(_open(eqn.params["jaxpr"])), eqn.params["length"])
        else:
            for sub in subs:
                add(jaxpr_flops(_open(sub)))
    return totals


def _open(jaxpr):
    return jaxpr.jaxpr if isinstance(jaxpr, core.ClosedJaxpr) else jaxpr


def flops(fn, *args, **kwargs) -> float:
    """Useful FLOPs of one call `fn(*args, **kwargs)` (traced, not run)."""
    return sum(jaxpr_flops(jax.make_jaxpr(fn)(*args, **kwargs).jaxpr).values())
