"""Save and load a `RelationSet` with Orbax (arrays) plus a JSON description (shapes, stats).

Orbax writes into a temporary directory and renames it on success, so a crash mid-save never
leaves a half-written checkpoint under the final name. Loading logs what App. B.3.1 prints:
the number of relations and syzygies and the recorded on/off means.
"""

from __future__ import annotations

import logging
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from jaml.relations.networks import Relation
from jaml.relations.relation_set import RelationSet, Report, require_relations

log = logging.getLogger("jaml.relations")
FORMAT = "jaml.relations/1"


def _arrays(rs: RelationSet) -> dict:
    return {"params": list(rs.params), "on_means": rs.on_means, "off_means": rs.off_means}


def _describe(rs: RelationSet) -> dict:
    return {
        "format": FORMAT,
        "dim": rs.dim,
        "depth": rs.depth,
        "widths": list(rs.widths),
        "tolerance": rs.tolerance,
        "distance_tolerance": (None if rs.distance_tolerance is None
                               else list(rs.distance_tolerance)),
        "syzygies": list(rs.syzygies),
        "dim_names": list(rs.dim_names),
        "on_means": np.asarray(rs.on_means).tolist(),
        "off_means": np.asarray(rs.off_means).tolist(),
        "low": list(rs.low),
        "high": list(rs.high),
        "quality": rs.quality.to_dict() if rs.quality is not None else None,
        # Only where the fit centred its rows (`relations.units`): other checkpoints unchanged.
        **({"centre": list(rs.centre)} if rs.centre else {}),
    }


def _here(tree):
    """Restore targets shaped as `tree` on this process's first device: a checkpoint records the
    devices it was saved from (a CPU's, another GPU's), which need not exist here."""
    here = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    return jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=here), tree)


def _read_meta(path: Path):
    with ocp.Checkpointer(ocp.CompositeCheckpointHandler()) as ckptr:
        return ckptr.restore(path, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]


def save(rs: RelationSet, path, *, overwrite: bool = True) -> Path:
    """Write `rs` to the directory `path` (atomically; replaces an existing one if overwrite)."""
    require_relations(rs, "save")
    path = Path(path).absolute()
    with ocp.Checkpointer(ocp.CompositeCheckpointHandler()) as ckptr:
        ckptr.save(
            path,
            args=ocp.args.Composite(
                arrays=ocp.args.StandardSave(_arrays(rs)), meta=ocp.args.JsonSave(_describe(rs))
            ),
            force=overwrite,
        )
    return path


def load(path) -> RelationSet:
    """Read a RelationSet written by `save`; raises FileNotFoundError / ValueError if unusable."""
    path = Path(path).absolute()
    if not path.is_dir():
        raise FileNotFoundError(f"no relations checkpoint at {path}")
    try:
        meta = _read_meta(path)
    except Exception as error:
        raise ValueError(f"corrupt or foreign relations checkpoint at {path}: {error}") from error
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{path} is not a jaml relations checkpoint (format {meta!r})")
    dim, depth, widths = meta["dim"], meta["depth"], meta["widths"]
    target = _here(
        {
            "params": [
                jax.eval_shape(Relation(w, depth).init, jax.random.key(0), jnp.zeros((1, dim)))
                for w in widths
            ],
            "on_means": jax.ShapeDtypeStruct((len(widths),), jnp.float32),
            "off_means": jax.ShapeDtypeStruct((len(widths),), jnp.float32),
        },
    )
    try:
        with ocp.Checkpointer(ocp.CompositeCheckpointHandler()) as ckptr:
            arrays = ckptr.restore(
                path, args=ocp.args.Composite(arrays=ocp.args.StandardRestore(target))
            )["arrays"]
    except Exception as error:
        raise ValueError(f"corrupt relations checkpoint at {path}: {error}") from error
    rs = RelationSet(
        params=tuple(arrays["params"]),
        on_means=arrays["on_means"],
        off_means=arrays["off_means"],
        widths=tuple(widths),
        depth=depth,
        dim=dim,
        tolerance=meta["tolerance"],
        syzygies=tuple(meta["syzygies"]),
        dim_names=tuple(meta["dim_names"]),
        # Checkpoints written before the trust region and the quality report lack these.
        low=tuple(meta.get("low") or ()),
        high=tuple(meta.get("high") or ()),
        quality=Report(meta["quality"]) if meta.get("quality") else None,
        # None: written before it; one number (for every relation): before per-relation ones.
        distance_tolerance=meta.get("distance_tolerance"),
        centre=tuple(meta.get("centre") or ()),
    )
    log.info("loaded %d relation%s (%d syzygies) from %s; mean |g| on / off the data: %s",
             rs.num_relations, "" if rs.num_relations == 1 else "s", sum(rs.syzygies), path,
             ", ".join(f"g{k + 1} {on:.4g} / {off:.4g}" for k, (on, off) in enumerate(
                 zip(np.asarray(rs.on_means).tolist(), np.asarray(rs.off_means).tolist(),
                     strict=True))))
    return rs


def save_loop_state(state, path, meta: dict) -> Path:
    """Write a training loop's state (`relations.loop.LoopState`) and a JSON `meta` to the
    directory `path`, atomically, replacing what is there."""
    path = Path(path).absolute()
    arrays = state.replace(key=jax.random.key_data(state.key))
    with ocp.Checkpointer(ocp.CompositeCheckpointHandler()) as ckptr:
        ckptr.save(path, args=ocp.args.Composite(arrays=ocp.args.StandardSave(arrays),
                                                 meta=ocp.args.JsonSave(meta)), force=True)
    return path


def loop_state_meta(path) -> dict | None:
    """The `meta` a `save_loop_state` directory holds, or None where there is none."""
    path = Path(path).absolute()
    return _read_meta(path) if path.is_dir() else None


def load_loop_state(path, template):
    """The loop state at `path`, shaped as `template`, on this process's first device."""
    path = Path(path).absolute()
    target = _here(template.replace(key=jax.random.key_data(template.key)))
    with ocp.Checkpointer(ocp.CompositeCheckpointHandler()) as ckptr:
        arrays = ckptr.restore(path, args=ocp.args.Composite(
            arrays=ocp.args.StandardRestore(target)))["arrays"]
    return arrays.replace(key=jax.random.wrap_key_data(
        arrays.key, impl=jax.random.key_impl(template.key)))
