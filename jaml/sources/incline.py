"""Block-on-incline (paper Fig. 7, App. B.3.3): closed-form 1-D sliding with friction and drag.

The block moves along the incline; s is the distance travelled downhill and v = ds/dt. Gravity
and kinetic friction give a constant downhill acceleration c = g (sin θ − μ cos θ); drag adds
−r v (linear) or −r v|v| (quadratic):

    s' = v,   v' = c − D(v),   D(v) ∈ {0, r v, r v|v|}.

As in the reference implementation, friction is a constant up-slope deceleration (the block is
taken to slide downhill): that makes the flow closed-form for every initial velocity. The
quadratic-drag solution needs c > 0.

Rows are time-major, τ = (s(t_0), v(t_0), s(t_1), v(t_1), …), the paper's τ = [s_t, s_{t+1}, …]
(the reference stored them state-major (s0, s1, v0, v1) under mislabeled names; see docs).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp

DRAG_KINDS = ("none", "linear", "quadratic")

Param = float | tuple[float, float]


def downhill_acceleration(gravity, incline, friction):
    """c = g (sin θ − μ cos θ): the drag-free acceleration along the incline."""
    return gravity * (jnp.sin(incline) - friction * jnp.cos(incline))


def flow(s0, v0, t, c, drag_coef, drag: str):
    """Closed-form (s(t), v(t)) from (s0, v0) under s' = v, v' = c − D(v). Broadcasts.

    Args:
      s0, v0: initial position and velocity.
      t: elapsed time (≥ 0).
      c: drag-free acceleration (see `downhill_acceleration`).
      drag_coef: r, the drag coefficient (ignored for drag='none').
      drag: one of DRAG_KINDS.
    """
    if drag == "none":
        return s0 + v0 * t + 0.5 * c * t**2, v0 + c * t
    if drag == "linear":
        r = drag_coef
        terminal = c / r
        gap = terminal - v0
        decay = jnp.exp(-r * t)
        return s0 + terminal * t + (gap / r) * (decay - 1.0), terminal - gap * decay
    if drag == "quadratic":
        return _quadratic_drag_flow(s0, v0, t, c, drag_coef)
    raise ValueError(f"unknown drag {drag!r}; expected one of {DRAG_KINDS}")


def _quadratic_drag_flow(s0, v0, t, c, r):
    terminal = jnp.sqrt(c / r)  # V
    rate = r * terminal  # b = √(c r)
    u = v0 / terminal
    bt = rate * t
    # v0 ≥ 0: v = V (u + tanh bt) / (1 + u tanh bt), s − s0 = ln(cosh bt + u sinh bt) / r.
    # (This one expression covers both 0 ≤ v0 < V, the tanh branch, and v0 > V, the coth branch.)
    tanh_bt = jnp.tanh(bt)
    v_down = terminal * (u + tanh_bt) / (1.0 + u * tanh_bt)
    # log(cosh bt + u sinh bt) = bt + log((1 + u) + (1 − u) e^{−2bt}) − log 2, overflow-free.
    s_down = (bt + jnp.log((1.0 + u) + (1.0 - u) * jnp.exp(-2.0 * bt)) - jnp.log(2.0)) / r
    # v0 < 0: climbing; both gravity and drag oppose motion. a = arctan(u) < 0; the block stops
    # at b t* = −a, then slides down from rest.
    a = jnp.arctan(jnp.minimum(u, 0.0))
    climbing = bt < -a
    phase = a + bt
    safe_up = jnp.where(climbing, phase, 0.0)
    v_up = terminal * jnp.tan(safe_up)
    s_up = -jnp.log(jnp.cos(safe_up) / jnp.cos(a)) / r
    safe_fall = jnp.where(climbing, 0.0, phase)
    v_fall = terminal * jnp.tanh(safe_fall)
    log_cosh = jnp.abs(safe_fall) + jnp.log1p(jnp.exp(-2.0 * jnp.abs(safe_fall))) - jnp.log(2.0)
    s_fall = (log_cosh - 0.5 * jnp.log1p(u**2)) / r
    v_neg = jnp.where(climbing, v_up, v_fall)
    s_neg = jnp.where(climbing, s_up, s_fall)
    downhill = v0 >= 0
    return s0 + jnp.where(downhill, s_down, s_neg), jnp.where(downhill, v_down, v_neg)


def _draw(key, param: Param, n: int):
    if isinstance(param, tuple):
        lo, hi = param
        return jax.random.uniform(key, (n,), minval=lo, maxval=hi)
    return jnp.full((n,), param)


def _check_param(name: str, param: Param):
    if isinstance(param, tuple) and (len(param) != 2 or not param[0] <= param[1]):
        raise ValueError(f"{name} range must be (lo, hi) with lo ≤ hi, got {param}")


@dataclasses.dataclass(frozen=True)
class BlockOnIncline:
    """A block sliding on an incline, observed at `times` after a random start.

    Each physical parameter is a constant or a (lo, hi) range drawn per row; parameters are not
    part of τ, except the incline angle θ as τ's last entry with `observe_incline` (then
    relations learned over a range of angles can be read at one angle). Initial position and
    velocity are uniform in their ranges times `scale` (use scale 2 for "twice the training
    range" generalization tests).
    """

    gravity: Param = 9.8
    incline: Param = jnp.pi / 4
    friction: Param = 0.0
    drag: str = "none"
    drag_coef: Param = 0.0
    times: tuple[float, ...] = (0.0, 1.0)
    position_range: tuple[float, float] = (0.0, 1.0)
    velocity_range: tuple[float, float] = (-1.0, 1.0)
    scale: float = 1.0
    observe_incline: bool = False
    name: str = "block"

    def __post_init__(self):
        if self.drag not in DRAG_KINDS:
            raise ValueError(f"unknown drag {self.drag!r}; expected one of {DRAG_KINDS}")
        for field in ("gravity", "incline", "friction", "drag_coef"):
            _check_param(field, getattr(self, field))
        if len(self.times) < 2 or any(
            b <= a for a, b in zip(self.times, self.times[1:], strict=False)
        ):
            raise ValueError(f"times must be ≥ 2 strictly increasing values, got {self.times}")
        if self.drag != "none" and _lowest(self.drag_coef) <= 0:
            raise ValueError(f"drag {self.drag!r} needs drag_coef > 0, got {self.drag_coef}")
        if self.drag == "quadratic":
            lo_c = min(
                float(downhill_acceleration(_lowest(self.gravity), th, mu))
                for th in _ends(self.incline)
                for mu in _ends(self.friction)
            )
            if lo_c <= 0:
                raise ValueError(
                    "quadratic drag needs a downhill acceleration g(sin θ − μ cos θ) > 0 for "
                    f"every parameter in range; got {lo_c:.4g}"
                )

    @property
    def dim_names(self) -> tuple[str, ...]:
        names = tuple(f"{q}_{i}" for i in range(len(self.times)) for q in ("position", "velocity"))
        return (*names, "incline") if self.observe_incline else names

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        kg, kt, kf, kr, ks, kv = jax.random.split(key, 6)
        incline = _draw(kt, self.incline, n)
        c = downhill_acceleration(_draw(kg, self.gravity, n), incline, _draw(kf, self.friction, n))
        r = _draw(kr, self.drag_coef, n)
        lo, hi = self.position_range
        s0 = self.scale * jax.random.uniform(ks, (n,), minval=lo, maxval=hi)
        lo, hi = self.velocity_range
        v0 = self.scale * jax.random.uniform(kv, (n,), minval=lo, maxval=hi)
        columns = []
        for t in self.times:
            s, v = flow(s0, v0, t - self.times[0], c, r, self.drag)
            columns += [s, v]
        if self.observe_incline:
            columns.append(incline)
        return jnp.stack(columns, axis=-1)

    def widened(self, scale: float) -> BlockOnIncline:
        """The same dynamics with initial states drawn from `scale` × the ranges."""
        return dataclasses.replace(self, scale=scale)


def _ends(param: Param) -> Sequence[float]:
    return param if isinstance(param, tuple) else (param,)


def _lowest(param: Param) -> float:
    return min(_ends(param))
