"""A jitted `lax.scan` over many optimizer steps that stops in place once training is done.

Both g_k and syzygy training use it: `train_step(state, args) -> (state, metrics)` decides
`done` itself; once done, later steps of the chunk are skipped by `lax.cond`, so a relation
stops exactly at the step its stopping rule fires. Python sees one call per chunk: logging and
progress bars live there, not on the hot path.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import struct

RUNNING, CONVERGED, CAPPED, NONFINITE = 0, 1, 2, 3
# XLA:CPU backend (LLVM) optimisation for the training loops: level 1 compiles them faster than
# the default 3 at the same step rate; programs run once (initialisation, recorded means, the
# rank check) take level 0. See docs/notes/relations.md, "Cold path".
LOOP_COMPILER_OPTIONS = {"xla_backend_optimization_level": 1}
ONCE_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}
PASS_RATE = 0.9  # share of recent steps on which the stopping rule must hold
STATUS_NAMES = {RUNNING: "running", CONVERGED: "done", CAPPED: "capped", NONFINITE: "non-finite"}


@struct.dataclass
class LoopState:
    params: dict
    opt_state: optax.OptState
    key: jax.Array
    step: jax.Array  # optimizer steps taken
    status: jax.Array  # RUNNING / CONVERGED / CAPPED / NONFINITE
    pass_rate: jax.Array  # running average of whether the stopping rule held (window ≈ patience)

    @property
    def done(self):
        return self.status != RUNNING


def init_state(params, optimizer: optax.GradientTransformation, key) -> LoopState:
    zero = jnp.zeros((), jnp.int32)
    return LoopState(
        params, optimizer.init(params), key, zero, jnp.asarray(RUNNING, jnp.int32),
        jnp.zeros((), jnp.float32),
    )


def optimizer_step(
    state: LoopState,
    objective: Callable,
    optimizer: optax.GradientTransformation,
    max_steps: int,
    *batch,
    patience: int = 1,
):
    """One step: evaluate `objective(params, *batch) -> (loss, (metrics, holds))`.

    The stopping rule `holds` is checked on the current parameters before they are updated (as
    the reference does), each step on a fresh batch. Training converges once the rule holds on
    ≥ 90% of recent steps: a running average over about `patience` steps, so one lucky batch
    does not end training and one unlucky batch does not reset it (patience 1 stops on the first
    step that holds, as the reference does). A non-finite loss or gradient stops with the last
    finite parameters kept.
    """
    (loss, (metrics, holds)), grads = jax.value_and_grad(objective, has_aux=True)(
        state.params, *batch
    )
    pass_rate = state.pass_rate + (holds.astype(jnp.float32) - state.pass_rate) / patience
    converged = pass_rate >= PASS_RATE
    finite = jnp.isfinite(loss) & jnp.all(
        jnp.stack([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)])
    )
    updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, updates)
    take = finite & ~converged
    step = state.step + take.astype(jnp.int32)
    status = jnp.where(
        ~finite,
        NONFINITE,
        jnp.where(converged, CONVERGED, jnp.where(step >= max_steps, CAPPED, RUNNING)),
    )
    keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(take, a, b), new, old)  # noqa: E731
    new_state = state.replace(
        params=keep(params, state.params),
        opt_state=keep(opt_state, state.opt_state),
        step=step,
        status=status.astype(jnp.int32),
        pass_rate=pass_rate,
    )
    return new_state, {"loss": loss, **metrics}


def make_chunk(train_step: Callable, length: int, draw: Callable | None = None):
    """jit(state, args) → (state, metrics [length], valid [length]): `length` steps in a scan.

    `draw(key, args) -> batch` samples one step's data; a whole chunk's batches are drawn up
    front by one vmapped call (on CPU, per-step RNG launches cost more than the math), and
    `train_step(state, batch, args) -> (state, metrics)` consumes one of them.
    """

    # Jitted inside the loop so that its one trace serves both the metrics' shapes (the idle
    # branch's zeros) and the step itself: JAX keeps a jitted function's trace by its inputs'
    # types, and XLA inlines the call.
    step = jax.jit(train_step)

    def run(state: LoopState, args):
        key, chunk_key = jax.random.split(state.key)
        state = state.replace(key=key)
        if draw is None:
            batches = None
        else:
            batches = jax.vmap(lambda k: draw(k, args))(jax.random.split(chunk_key, length))

        def body(state, batch):
            def active(s):
                new, metrics = step(s, batch, args)
                return new, metrics, jnp.asarray(True)

            shapes = jax.eval_shape(step, state, batch, args)[1]
            zeros = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), shapes)

            def idle(s):
                return s, zeros, jnp.asarray(False)

            new, metrics, valid = jax.lax.cond(state.done, idle, active, state)
            return new, (metrics, valid)

        state, (metrics, valid) = jax.lax.scan(body, state, batches, length=length)
        return state, metrics, valid

    return jax.jit(run, compiler_options=LOOP_COMPILER_OPTIONS)


def run_until_done(chunk, state: LoopState, args, on_chunk: Callable | None = None,
                   on_state: Callable[[LoopState], None] | None = None,
                   until: Callable[[dict], bool] | None = None) -> LoopState:
    """Call a compiled chunk until the state reports done; `on_chunk(state, metrics, n)` per
    call, with host floats averaged over the chunk's n active steps; `on_state(state)` after
    every call (where a caller keeps the loop's state to resume from). `until(metrics)`, given
    the same averages, may end training early: the state is then returned CAPPED."""
    while True:
        state, metrics, valid = chunk(state, args)
        valid = jax.device_get(valid)
        means = None
        if (on_chunk is not None or until is not None) and valid.any():
            host = jax.device_get(metrics)
            means = {k: float(v[valid].mean()) for k, v in host.items()}
        if on_chunk is not None and means is not None:
            on_chunk(state, means, int(valid.sum()))
        if until is not None and means is not None and not bool(state.done) and until(means):
            state = state.replace(status=jnp.asarray(CAPPED, jnp.int32))
        if on_state is not None:
            on_state(state)
        if bool(state.done):
            return state
