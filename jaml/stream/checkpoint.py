"""Run checkpoints: the whole `StreamState` as named arrays in an Orbax `CheckpointManager`.

Each leaf is saved under its pytree path ("learner.params.conv0.kernel", "env.data.qpos", …),
so a checkpoint says what it holds and one written by a different `StreamState` is refused with
the names that differ, rather than failing on a shape at some leaf index. The manager's root
metadata records `FORMAT`. Zero-size leaves (mjx.Data has
some, e.g. `act` of a model without actuator state) are not saved (Orbax refuses them) and are
restored as zeros. Saving is atomic: Orbax writes a step to a temporary directory and renames it.

With several processes (`jax.distributed`) each process checkpoints the runs it holds, but
Orbax writes host arrays from process 0 alone and refuses a process's own device arrays, so
there a process hands its state to a short-lived single-process child that saves it
(`_save_apart`); restoring needs nothing of the kind.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from jaml import _interrupts

FORMAT = 2


class CheckpointMismatch(ValueError):
    """The checkpoint holds a different state than the one this code builds."""


def manager(out: Path, max_to_keep: int = 2) -> ocp.CheckpointManager:
    """The manager of OUT/checkpoints (created if missing), this process's alone: with several
    processes (`jax.distributed`) each writes the runs it holds, and Orbax would otherwise wait
    for the others at every save."""
    alone = ocp.options.MultiprocessingOptions(primary_host=jax.process_index(),
                                               active_processes={jax.process_index()})
    directory = (Path(out) / "checkpoints").absolute()
    directory.mkdir(parents=True, exist_ok=True)  # Orbax creates none for one process of many
    return ocp.CheckpointManager(
        directory,
        options=ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=False,
                                             multiprocessing_options=alone),
        # Named up front: a manager that has not saved in this process otherwise does not know
        # how to read an item's metadata (`item_metadata` gave None on resume, orbax on the
        # GPU image), so a restarted run could not resume. The handler takes the manager's
        # options: by default it would write its metadata from process 0 alone.
        item_handlers=ocp.StandardCheckpointHandler(multiprocessing_options=alone),
        metadata={"format": FORMAT, "content": "jaml.stream.StreamState"},
    )


def named(state) -> dict[str, jax.Array]:
    """{path name: leaf} of the state's non-empty leaves."""
    leaves = jax.tree_util.tree_flatten_with_path(state)[0]
    return {_name(path): x for path, x in leaves if np.prod(x.shape) > 0}


def save(mgr: ocp.CheckpointManager, step: int, state) -> None:
    """Write `state` as step `step` and wait until it is finalised. Ctrl-C or SIGTERM during
    the write takes effect once it is done (`_interrupts.held`): a checkpoint is whole or
    absent, and the interrupted run's summary names it."""
    with _interrupts.held():
        leaves = named(state)
        if jax.process_count() > 1:
            _save_apart(mgr, step, {k: np.asarray(x) for k, x in leaves.items()})
            return
        mgr.save(step, args=ocp.args.StandardSave(leaves))
        mgr.wait_until_finished()


def _save_apart(mgr: ocp.CheckpointManager, step: int, leaves: dict[str, np.ndarray]) -> None:
    """`save` from one process of several: the leaves go to a temporary file, a child process
    (CPU-only JAX, not distributed, so Orbax writes every array) saves them as step `step` with
    `manager`'s defaults, and `mgr` rereads the directory. The child runs in a session of its
    own, so a Ctrl-C at the terminal reaches only this process, which holds it until the step
    is written (`save`)."""
    directory = Path(mgr.directory)
    with tempfile.TemporaryDirectory(prefix="jaml-checkpoint-") as tmp:
        path = Path(tmp) / "leaves.pkl"
        path.write_bytes(pickle.dumps(leaves))  # keeps every dtype, bfloat16 included
        child = subprocess.run(
            [sys.executable, "-m", "jaml.stream.checkpoint", str(directory.parent), str(step),
             str(path)], env={**os.environ, "JAX_PLATFORMS": "cpu"}, capture_output=True,
            text=True, start_new_session=True)
        if child.returncode:
            raise RuntimeError(f"the process saving {directory / str(step)} failed: "
                               f"{(child.stderr.strip().splitlines() or ['no output'])[-1]}")
    mgr.reload()


def _save_from_file(out: str, step: str, path: str) -> None:
    """The child of `_save_apart`: OUT/checkpoints step `step` from the leaves pickled at
    `path` (this process's own temporary file)."""
    leaves = pickle.loads(Path(path).read_bytes())
    mgr = manager(Path(out))
    mgr.save(int(step), args=ocp.args.StandardSave(leaves))
    mgr.wait_until_finished()
    mgr.close()


class CheckpointUnreadable(ValueError):
    """A checkpoint step's files are incomplete or damaged (Orbax or TensorStore failed)."""


def restore(mgr: ocp.CheckpointManager, abstract, step: int | None = None):
    """The state saved at `step` (default: the latest), shaped like `abstract` (an
    `eval_shape` of the state). Raises CheckpointMismatch if the names differ, and
    CheckpointUnreadable, in one line, if Orbax cannot read the step's files."""
    step = mgr.latest_step() if step is None else step
    try:
        return _restore(mgr, abstract, step)
    except CheckpointMismatch:
        raise
    except Exception as error:  # Orbax / TensorStore: a spec dump and asyncio tracebacks
        first = (str(error).strip().splitlines() or [type(error).__name__])[0][:200]
        raise CheckpointUnreadable(
            f"{Path(mgr.directory) / str(step)} cannot be read ({type(error).__name__}: "
            f"{first}); move that folder away to resume from an earlier checkpoint, or start a "
            "new --out") from error


def _restore(mgr: ocp.CheckpointManager, abstract, step: int):
    saved = set(mgr.item_metadata(step).keys())
    paths_leaves, treedef = jax.tree_util.tree_flatten_with_path(abstract)
    names = [_name(p) if np.prod(a.shape) > 0 else None for p, a in paths_leaves]
    wanted = {n for n in names if n is not None}
    if saved != wanted:
        missing, unexpected = sorted(wanted - saved), sorted(saved - wanted)
        raise CheckpointMismatch(
            f"{mgr.directory} step {step} holds another state than this code builds: missing "
            f"{missing[:5]}{'…' if len(missing) > 5 else ''}, unexpected "
            f"{unexpected[:5]}{'…' if len(unexpected) > 5 else ''} (was it written by another "
            "jaml version or config? start a new --out)")
    target = {n: a for n, (_, a) in zip(names, paths_leaves, strict=True) if n is not None}
    if jax.process_count() > 1:  # on this process's device: Orbax's default is process 0's
        here = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        target = {n: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=here)
                  for n, a in target.items()}
    metadata = mgr.item_metadata(step)
    reshaped = sorted(n for n, a in target.items() if tuple(metadata[n].shape) != a.shape)
    if reshaped:
        raise CheckpointMismatch(
            f"{mgr.directory} step {step} holds other shapes for {reshaped[:5]}"
            f"{'…' if len(reshaped) > 5 else ''} (e.g. {reshaped[0]}: saved "
            f"{tuple(metadata[reshaped[0]].shape)}, built {target[reshaped[0]].shape}); was it "
            "written with another config? start a new --out")
    flat = mgr.restore(step, args=ocp.args.StandardRestore(target))
    return _build(treedef, paths_leaves, names, flat)


def _build(treedef, paths_leaves, names, flat):
    leaves = [flat[n] if n is not None else jnp.zeros(a.shape, a.dtype)
              for n, (_, a) in zip(names, paths_leaves, strict=True)]
    return jax.tree_util.tree_unflatten(treedef, leaves)


def _name(path) -> str:
    parts = []
    for k in path:
        for attr in ("name", "key", "idx"):
            if hasattr(k, attr):
                parts.append(str(getattr(k, attr)))
                break
        else:
            parts.append(str(k))
    return ".".join(parts)


if __name__ == "__main__":
    _save_from_file(*sys.argv[1:])
