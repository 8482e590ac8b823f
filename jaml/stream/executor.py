"""How epochs execute: one run or R stacked runs, on the host, in device blocks, or as one
SPMD program over a mesh of devices, on one host or several.

The epoch itself is `Stream.epochs`, a pure function of the stacked states (`jaml.stream.loop`).
This module decides how a call of n epochs runs it: a host loop of jitted pieces (CPU,
`Stream.host_epoch`), blocks of up to 32 epochs inside one device loop (GPU/TPU), and that device
loop as one `shard_map` program when the runs are sharded along a mesh's "runs" axis. What it
compiles, the Stream keeps (`Stream.jit`, `Stream.learner_jit`).

Shapes: R runs.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from jaml.stream.loop import Stream, StreamState


def run_epochs(stream: Stream, s: StreamState, n: int):
    """n epochs of one run: (state, metrics stacked [n]). The state is donated (do not reuse
    the argument). `run_stacked_epochs` with R = 1."""
    states, metrics = run_stacked_epochs(stream, stack_runs([s]), n)
    return unstack_runs(states)[0], jax.tree.map(lambda x: x[:, 0], metrics)


def stack_runs(states: list[StreamState]) -> StreamState:
    """R runs' states → one state whose leaves carry a leading runs axis [R, ...].

    Weak types are dropped (e.g. Brax's normaliser initialises `std_eps` from a Python float):
    the epoch loop returns strong types, and a leaf whose type changed between calls would
    re-trace and re-compile the loop on the second call."""
    return _stack(list(states))


# The tree functions below are one program each: leaf by leaf, each new leaf shape would compile
# a program of its own (a state holds ~150 leaves; seconds of compiling on a CPU).
@jax.jit
def _stack(states: list[StreamState]) -> StreamState:
    return jax.tree.map(lambda *x: jax.lax.convert_element_type(jnp.stack(x), x[0].dtype),
                        *states)


def unstack_runs(states: StreamState) -> list[StreamState]:
    """The inverse of `stack_runs`: one state per run."""
    return _unstack(states)


@jax.jit
def _unstack(states: StreamState) -> list[StreamState]:
    count = states.epoch.shape[0]
    return [jax.tree.map(lambda x, i=i: x[i], states) for i in range(count)]


@jax.jit
def one_run_stacked(state: StreamState) -> StreamState:
    """One run's state as R = 1 stacked runs (leaves [1, ...]; weak types kept, unlike
    `stack_runs`)."""
    return jax.tree.map(lambda x: x[None], state)


@functools.partial(jax.jit, static_argnums=1)
def run_of(states: StreamState, i: int) -> StreamState:
    """Run i's state of stacked `states` (weak types kept)."""
    return jax.tree.map(lambda x: x[i], states)


@dataclasses.dataclass(eq=False)
class Stacked:
    """The stacked states of the runs last trained together (`members`, indices into
    `holders`), kept stacked from one block to the next while the group stays the same (the
    common case: all runs at one epoch); the other runs' states are held by their `holders`
    (each a run's `RunDir`), in its `state`."""

    holders: list
    members: tuple[int, ...] = ()
    states: StreamState | None = None

    def of(self, members: tuple[int, ...]) -> StreamState:
        """The stacked states of `members`, regrouped if they are not the last group."""
        if members != self.members:
            if self.states is not None:
                for i, state in zip(self.members, unstack_runs(self.states), strict=True):
                    self.holders[i].state = state
            self.states = stack_runs([self.holders[i].state for i in members])
            self.members = members
            for i in members:
                self.holders[i].state = None
        return self.states

    def state(self, i: int) -> StreamState:
        """Run i's state, from the stack or its holder."""
        if i not in self.members:
            return self.holders[i].state
        return run_of(self.states, self.members.index(i))


@functools.partial(jax.jit, static_argnums=(1, 2, 3))
def _take(tree, index: tuple[int, ...], axis: int = 0, rows: int | None = None):
    """`tree`'s leaves at `index` along `axis`, of their first `rows` along axis 0 where given."""
    at = (slice(None),) * axis + (np.asarray(index),)
    return jax.tree.map(lambda x: x[:rows][at], tree)


@jax.jit
def _concatenate(trees: list):
    return jax.tree.map(lambda *x: jnp.concatenate(x), *trees)


RUNS_AXIS = "runs"


def runs_mesh(num_runs: int, devices=None) -> Mesh:
    """A 1-D mesh ("runs") for R = `num_runs` runs. On one host: the first min(R, len(devices))
    devices (default: the local devices of the default backend). With `jax.distributed`
    initialised (several processes): every process's devices, `jax.devices()`, so each process
    holds a share of the runs (`held_runs`)."""
    if devices is None and jax.process_count() > 1:
        return Mesh(np.asarray(jax.devices()), (RUNS_AXIS,))
    devices = list(jax.local_devices() if devices is None else devices)
    return Mesh(np.asarray(devices[:max(1, min(num_runs, len(devices)))]), (RUNS_AXIS,))


def held_runs(num_runs: int, mesh: Mesh) -> range:
    """The runs (indices into R = `num_runs`) this process holds on `mesh`: ceil(R / devices)
    per device in mesh order, the last devices' shares short; every run when the mesh is this
    process's alone."""
    devices = list(mesh.devices.flat)
    mine = [i for i, d in enumerate(devices) if d.process_index == jax.process_index()]
    if not mine:
        raise ValueError(f"the mesh holds none of process {jax.process_index()}'s devices; "
                         "give every process devices in it (`runs_mesh`)")
    per = -(-num_runs // len(devices))
    held = range(min(mine[0] * per, num_runs), min((mine[-1] + 1) * per, num_runs))
    if not held:
        raise ValueError(f"{num_runs} runs leave process {jax.process_index()} none on a mesh "
                         f"of {len(devices)} devices; train at least one run per process")
    return held


def run_stacked_epochs(stream: Stream, states: StreamState, n: int, *, mesh: Mesh | None = None,
                       host_loop: bool | None = None, num_runs: int | None = None):
    """n epochs of R independent runs of one Stream, stacked along a leading axis.

    Returns (states, metrics [n, R] per name). The states are donated (do not reuse the
    argument). Every run computes the function it would alone, with the same keys, so one call
    trains R seeds with one compiled program. Its bits are reproducible for a given stacking,
    not across stackings: on a GPU the acting's batched kernels round differently for another
    R (docs/notes/stream.md).

    The device loop (default on GPU/TPU) runs up to 32 epochs per call inside `fori_loop`.
    With a mesh of several devices (default: `runs_mesh(R)`) the states are sharded along its
    "runs" axis and one SPMD program (`shard_map`) runs the one-device loop on each device's
    runs; nothing is communicated between them. Each device holds ceil(R / devices) runs, the
    last devices' shares padded with copies of a run they hold, dropped afterwards.
    Over several processes (`jax.distributed`, a mesh spanning them), `num_runs` is R, the runs
    of every process, and `states` this process's share of them (`held_runs`); the states and
    metrics returned are its share's.
    The host loop (default on CPU) is a Python loop over `Stream.host_epoch`, jitted pieces
    computing the same function with the same keys: XLA:CPU runs convolutions inside a while
    loop many times slower than outside one.
    """
    if host_loop is None:
        host_loop = jax.default_backend() == "cpu"
    count = int(states.epoch.shape[0])
    num_runs = count if num_runs is None else num_runs
    if not host_loop:
        return _device_loop(stream, states, n, runs_mesh(num_runs) if mesh is None else mesh,
                            num_runs)
    return _host_loop(stream, states, n)


def _device_loop(stream: Stream, states: StreamState, n: int, mesh: Mesh, num_runs: int):
    """n epochs in blocks of up to `BLOCK` per device call, this process's runs padded to its
    devices' shares and sharded along `mesh` (see `run_stacked_epochs`)."""
    count = int(states.epoch.shape[0])
    held = held_runs(num_runs, mesh)
    if count != len(held):
        raise ValueError(f"process {jax.process_index()} holds runs {held.start}-{held.stop - 1} "
                         f"of {num_runs} on this mesh but was given {count}; pass its share "
                         "(`held_runs`) and num_runs = the runs of every process")
    slots, real = _layout(count, mesh.local_mesh.size, -(-num_runs // mesh.size))
    if slots != real:
        states = _take(states, tuple(slots))
    if mesh.size > 1:  # this process's devices' shards, then the mesh's array of them
        states = jax.device_put(states, NamedSharding(mesh.local_mesh, P(RUNS_AXIS)))
        states = multihost_utils.host_local_array_to_global_array(states, mesh, P(RUNS_AXIS))
    blocks = []
    for start in range(0, n, BLOCK):
        k = min(BLOCK, n - start)
        states, metrics = _run_block(stream, mesh, states, k)
        if mesh.size > 1:
            metrics = _host_local(metrics, mesh, P(None, RUNS_AXIS))
        blocks.append(_take(metrics, tuple(real), 1, k))
    if mesh.size > 1:
        states = _host_local(states, mesh, P(RUNS_AXIS))
    if slots != real:
        states = _take(states, tuple(real))
    return states, _concatenate(blocks)


def _host_local(tree, mesh: Mesh, spec: P):
    """This process's shards of the mesh's arrays `tree`, as arrays over its own devices (no
    copy). An empty leaf (a domain without contacts, say) comes back from XLA whole on each
    device rather than split: it is made again at its local shape."""
    axis = tuple(spec).index(RUNS_AXIS)

    def one(x):
        if x.size:
            return multihost_utils.global_array_to_host_local_array(x, mesh, spec)
        shape = list(NamedSharding(mesh, spec).shard_shape(x.shape))
        shape[axis] *= mesh.local_mesh.size
        return jax.device_put(np.zeros(shape, x.dtype), NamedSharding(mesh.local_mesh, spec))

    return jax.tree.map(one, tree)


# Epochs per device call: the loop runs n ≤ BLOCK epochs with n a traced bound, so one
# compilation serves every block length a run asks for.
BLOCK = 32


def _layout(count: int, devices: int, per: int) -> tuple[list[int], list[int]]:
    """(slots, real): the run in each of the `devices` × `per` slots (`per` runs per device in
    order, the last devices' spare slots copies of their first run or, holding none, of run 0),
    and each run's slot."""
    slots, real = [], []
    for d in range(devices):
        mine = list(range(min(d * per, count), min((d + 1) * per, count)))
        real += [len(slots) + i for i in range(len(mine))]
        slots += mine + [mine[0] if mine else 0] * (per - len(mine))
    return slots, real


def _run_block(stream: Stream, mesh: Mesh, states: StreamState, n: int):
    """`_block` on the runs sharded along `mesh`: one device's program as is, several devices'
    as one `shard_map` program (each device its own runs; nothing crosses devices). The state
    is donated; one compilation per mesh and input types serves every block length and seed."""
    n = jnp.asarray(n, jnp.int32)
    if mesh.size == 1:
        return stream.learner_jit(_block)(states, n)
    return sharded_program(stream)(mesh, states, n)


def sharded_program(stream: Stream):
    """The Stream's jitted `_sharded_block(mesh, states, n)`, the mesh static, the states
    donated, with the learner's compiler options (`Stream.learner_jit`)."""
    return stream.learner_jit(_sharded_block, static_argnums=0, donate_argnums=1)


def _sharded_block(stream: Stream, mesh: Mesh, states: StreamState, n: jax.Array):
    """`_block` of each device's runs, the runs axis split along `mesh`'s "runs" axis.

    Empty leaves (an env's contact arrays where it has none, say) stay out of the `shard_map`:
    they hold nothing, and a `shard_map` that returns an empty input as it came segfaults XLA's
    GPU compiler under Shardy (docs/notes/stream.md); each side makes them anew at its shape.
    Unchecked (`check_vma=False`): MJX's solver branches on values that vary by device without
    saying so, and nothing here is replicated but the trip count n."""
    leaves, tree = jax.tree.flatten(states)

    def remade(kept, shape_of):
        kept = iter(kept)
        return tree.unflatten([next(kept) if x.size else jnp.zeros(shape_of(x), x.dtype)
                               for x in leaves])

    def per_device(kept, k):
        out, metrics = _block(stream, remade(kept, lambda x: (x.shape[0] // mesh.size,
                                                             *x.shape[1:])), k)
        return [x for x in jax.tree.leaves(out) if x.size], metrics

    kept, metrics = jax.shard_map(per_device, mesh=mesh, in_specs=(P(RUNS_AXIS), P()),
                                  out_specs=(P(RUNS_AXIS), P(None, RUNS_AXIS)),
                                  check_vma=False)([x for x in leaves if x.size], n)
    return remade(kept, lambda x: x.shape), metrics


def _block(stream: Stream, states: StreamState, n: jax.Array):
    """n (traced, ≤ BLOCK) epochs of stacked runs; metrics in [BLOCK, R] buffers, NaN past n."""
    epochs = stream.jit(Stream.epochs)  # the shape-only trace and the loop's share one trace
    shapes = jax.eval_shape(epochs, states)[1]
    buffers = jax.tree.map(lambda x: jnp.full((BLOCK, *x.shape), jnp.nan, x.dtype), shapes)

    def body(i, carry):
        states, buffers = carry
        states, metrics = epochs(states)
        return states, jax.tree.map(lambda b, v: b.at[i].set(v), buffers, metrics)

    return jax.lax.fori_loop(0, n, body, (states, buffers))


def _host_loop(stream: Stream, states: StreamState, n: int):
    """n epochs as a Python loop over `Stream.host_epoch` (see `run_stacked_epochs`)."""
    history = []
    for _ in range(n):
        states, metrics = stream.host_epoch(states)
        history.append(metrics)
    return states, jax.tree.map(lambda *v: jnp.stack(v), *history)
