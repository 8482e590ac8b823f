"""How epochs execute: one run or R stacked runs, on the host, in device blocks, or split
across devices.

The epoch itself is `Stream.epochs`, a pure function of the stacked states (`jaml.stream.loop`).
This module decides how a call of n epochs runs it: a host loop of jitted pieces (CPU), blocks of
up to 32 epochs inside one device loop (GPU/TPU), and one such program per device when the runs
are sharded across a mesh. What it compiles, the Stream keeps (`Stream.jit`).

Shapes: R runs.
"""

from __future__ import annotations

import concurrent.futures

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from jaml import learners
from jaml.stream import loop
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
    return jax.tree.map(lambda *x: jax.lax.convert_element_type(jnp.stack(x), x[0].dtype),
                        *states)


def unstack_runs(states: StreamState) -> list[StreamState]:
    """The inverse of `stack_runs`: one state per run."""
    count = states.epoch.shape[0]
    return [jax.tree.map(lambda x, i=i: x[i], states) for i in range(count)]


def runs_mesh(num_runs: int, devices=None) -> Mesh:
    """A 1-D mesh ("runs") over the first min(num_runs, len(devices)) devices (default: all
    local devices of the default backend). With `jax.distributed` initialised, pass
    `jax.devices()` to span every host's devices."""
    devices = list(jax.local_devices() if devices is None else devices)
    return Mesh(np.asarray(devices[:max(1, min(num_runs, len(devices)))]), (RUNS_AXIS,))


RUNS_AXIS = "runs"


def run_stacked_epochs(stream: Stream, states: StreamState, n: int, *, mesh: Mesh | None = None,
                       host_loop: bool | None = None):
    """n epochs of R independent runs of one Stream, stacked along a leading axis.

    Returns (states, metrics [n, R] per name). The states are donated (do not reuse the
    argument). Every run computes the function it would alone, with the same keys, so one call
    trains R seeds with one compiled program. Its bits are reproducible for a given stacking,
    not across stackings: on a GPU the acting's batched kernels round differently for another
    R (docs/notes/stream.md).

    The device loop (default on GPU/TPU) runs up to 32 epochs per call inside `fori_loop`.
    With a mesh of several devices (default: `runs_mesh(R)`) the states are sharded along its
    "runs" axis and each device runs the same one-device program on its own runs, launched
    from one host thread per device so the devices work at once; nothing is communicated
    between them. R is padded to a multiple of the mesh size with copies of the first run,
    dropped afterwards.
    One program per device rather than one `shard_map` program: XLA's GPU compiler crashed
    compiling the `shard_map` form of this loop.
    The host loop (default on CPU) is a Python loop over jitted, vmapped `act` and `learn_step`
    calls computing the same function with the same keys: XLA:CPU runs convolutions inside a
    while loop many times slower than outside one.
    """
    if host_loop is None:
        host_loop = jax.default_backend() == "cpu"
    if not host_loop:
        return _device_loop(stream, states, n, runs_mesh(states.epoch.shape[0])
                            if mesh is None else mesh)
    return _host_loop(stream, states, n)


def _device_loop(stream: Stream, states: StreamState, n: int, mesh: Mesh):
    """n epochs in blocks of up to `BLOCK` per device call, the runs padded to and sharded
    along `mesh` (see `run_stacked_epochs`)."""
    count = int(states.epoch.shape[0])
    padded = -count % mesh.size
    if padded:
        states = jax.tree.map(
            lambda x: jnp.concatenate([x, jnp.repeat(x[:1], padded, axis=0)]), states)
    if mesh.size > 1:
        states = jax.device_put(states, NamedSharding(mesh, P(RUNS_AXIS)))
    blocks = []
    for start in range(0, n, BLOCK):
        k = min(BLOCK, n - start)
        states, metrics = _blocks_per_device(stream, mesh, states, k)
        blocks.append(jax.tree.map(lambda x, k=k: x[:k, :count], metrics))
    if padded:
        states = jax.tree.map(lambda x: x[:count], states)
    return states, jax.tree.map(lambda *x: jnp.concatenate(x), *blocks)


# Epochs per device call: the loop runs n ≤ BLOCK epochs with n a traced bound, so one
# compilation serves every block length a run asks for.
BLOCK = 32


def _blocks_per_device(stream: Stream, mesh: Mesh, states: StreamState, n: int):
    """`_block` on each device's runs; the states stay sharded as they came."""
    if mesh.size == 1:
        return _learner_jit(stream, _block)(states, jnp.asarray(n, jnp.int32))
    leaves, treedef = jax.tree.flatten(states)
    devices = list(mesh.devices.flat)
    args = {d: (treedef.unflatten([next(s.data for s in x.addressable_shards if s.device == d)
                                   for x in leaves]),
                jax.device_put(jnp.asarray(n, jnp.int32), d)) for d in devices}
    # Each device gets its own executable (its inputs live there). Tracing runs here, in the
    # caller's thread, one device after another: Flax and JAX tracing state is not safe to share
    # between threads, and JAX's config contexts (e.g. `jax.threefry_partitionable`, which
    # decides the random bits) are thread-local, so the caller's are the ones that count. What
    # is thread safe, XLA compiling and running the executables, happens in one host thread per
    # device: a GPU while loop's trip test syncs with the thread that launched it, so a single
    # thread would run the devices one after another.
    # A device's shard of sharded states is views of the sharded arrays: not donated.
    avals = tuple(jax.typeof(x) for x in leaves)
    lowered = {d: stream.jit(_block).lower(*args[d]) for d in devices
               if (_block, d, avals) not in stream.programs}

    def on(device):
        executable = stream.program(
            (_block, device, avals),
            lambda: lowered[device].compile(compiler_options=learners.compiler_options()))
        return jax.block_until_ready(executable(*args[device]))

    with concurrent.futures.ThreadPoolExecutor(mesh.size) as pool:
        outs = list(pool.map(on, devices))
    sharding = NamedSharding(mesh, P(RUNS_AXIS))

    def gather(*parts):
        shape = (sum(p.shape[0] for p in parts), *parts[0].shape[1:])
        return jax.make_array_from_single_device_arrays(shape, sharding, list(parts))

    new = jax.tree.map(gather, *(o[0] for o in outs))
    metrics = jax.tree.map(lambda *m: np.concatenate([np.asarray(x) for x in m], axis=1),
                           *(o[1] for o in outs))
    return new, metrics


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
    """n epochs as a Python loop over jitted `act` and learner-step calls (see
    `run_stacked_epochs`)."""
    history = []
    for _ in range(n):
        states, k_learn, metrics = stream.jit(_act_runs, donate_argnums=0)(states)
        if bool(loop.replays_full(states)):
            keys = jax.vmap(stream.learn_keys)(k_learn)  # [R, learner_steps, 2]
            learner_state, steps = states.learner, []
            for i in range(stream.config.learner_steps):
                learner_state, m = _learner_jit(stream, _learn_step_runs)(
                    learner_state, states.replay, keys[:, i])
                steps.append(m)
            states = states.replace(learner=learner_state)
            learner_metrics = jax.tree.map(lambda *v: jnp.mean(jnp.stack(v), axis=0), *steps)
        else:
            learner_metrics = loop.skipped(stream, states, k_learn)
        metrics.update({f"learner/{k}": v for k, v in learner_metrics.items()})
        history.append(metrics)
    return states, jax.tree.map(lambda *v: jnp.stack(v), *history)


def _act_runs(stream: Stream, states: StreamState):
    return jax.vmap(stream.act)(states)


def _learn_step_runs(stream: Stream, learner_state, replay, keys):
    return jax.vmap(stream.learn_step)(learner_state, replay, keys)


def _learner_jit(stream: Stream, fn):
    """`fn(stream, states, ...)` jitted by the Stream (the states donated) with the learner's
    compiler options (`learners.compiler_options()`: on the CPU convolutions take XLA's Eigen
    path, not YNNPACK's, which ran the VAE's train step slower; XLA's defaults elsewhere). Read
    at each call: the options depend on the backend."""
    return stream.jit(fn, donate_argnums=0, compiler_options=learners.compiler_options())


def due_by_device(states: StreamState, due: list) -> list[tuple[StreamState, list]]:
    """The runs `due` grouped by the device that holds them (the first, where the states are
    replicated): per device, its due runs' states stacked on it and their entries of `due`.

    Taken from each device's own shard, so nothing crosses devices; a device's whole shard is
    used as is (no copy of its replays) when every run in it is due."""
    owner = {}
    for shard in states.epoch.addressable_shards:
        start, stop, _ = shard.index[0].indices(states.epoch.shape[0])
        for i in range(start, stop):
            owner.setdefault(i, shard.device)
    groups: dict = {}
    for i, r in due:
        groups.setdefault(owner[i], []).append((i, r))

    def local(x, device, index):
        shard = next(s for s in x.addressable_shards if s.device == device)
        start, stop, _ = shard.index[0].indices(x.shape[0])
        if index == list(range(start, stop)):
            return shard.data
        return shard.data[np.asarray(index) - start]

    return [(jax.tree.map(lambda x, d=device, m=members: local(x, d, [i for i, _ in m]), states),
             members) for device, members in groups.items()]
