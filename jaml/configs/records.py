"""Run records written by older code, read as the runs they were (`read`), and a record as the
reports show it, flat (`settings`).

Older records: config.json files from before the config tree (flat fields such as
"eval_every", `learner_overrides` / `env_overrides`, the learner's and env's configs under
"resolved"); learner and eval fields added since, at the values those runs used; and the
`penalty.json` that `jaml fig9` wrote beside a config.json before the run config held its
`penalty`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from jaml.configs.stream import StreamConfig, changed_fields

# The key under which records written before the typed tree held the learner's and env's
# configs.
RESOLVED = "resolved"
# Learner fields added after runs were first recorded, at the values a record that lacks them
# ran with (then the only behaviour), not at today's defaults: the conv stacks in float32, the
# encoder blind to the action into the first predicted frame.
LEGACY_LEARNER_FIELDS = {"compute_dtype": "float32", "activation_dtype": "float32",
                         "current_action": "hidden"}
# Eval fields added after runs were first recorded, at the values those runs used: the
# regressor's held-out rows the leading rows of one replay draw.
LEGACY_EVAL_FIELDS = {"validation_split": "leading"}
# The flat fields of records written before the tree → their paths in it.
FLAT_FIELDS = {
    "replay_slots": "replay.slots", "replay_keep_fraction": "replay.keep_fraction",
    "eval_every": "eval.every", "eval_train": "eval.train", "eval_rand": "eval.rand",
    "eval_curr": "eval.curr", "eval_transient": "eval.transient",
    "regressor_iterations": "eval.regressor_iterations",
    "regressor_normalize": "eval.regressor_normalize",
    "distortion_dims": "eval.distortion_dims",
}
# Where the ready-made learner configs' classes lived, and live (an own learner's "type").
OLD_LEARNER_CONFIGS, NEW_LEARNER_CONFIGS = "jaml.learners.config.", "jaml.configs.learners."
# The penalty record `jaml fig9` wrote into a run directory before config.json held it.
PENALTY_SIDECAR = "penalty.json"
# Where those runs placed the relations' coordinates on PRED's latent (fig9's layout then):
# θ on the last static entry, s and v on the dynamic entries.
PENALTY_SIDECAR_LAYOUT = {"static": ["theta"], "dynamic": ["s", "v"]}


def read(record: dict[str, Any], directory: Path | None = None) -> StreamConfig:
    """The config a run's config.json `record` describes, written by this code or an older one.
    Fields a record lacks (new in the code) take their defaults, the learner's
    `LEGACY_LEARNER_FIELDS` and the eval's `LEGACY_EVAL_FIELDS` the values it ran with. Where
    the record has no "penalty", `directory` (the run's) may hold it as a `PENALTY_SIDECAR`. An
    older record may leave values to the run (the learner's ld_dim): `config.resolve` fills
    them as for a new run."""
    d = _migrated(record)
    if "penalty" not in d and directory is not None:
        d["penalty"] = _sidecar_penalty(Path(directory))
    return StreamConfig.from_dict(d)


def own_learner(record: dict[str, Any]) -> dict | None:
    """A record's learner_config as written for a learner of your own (its fields and "type"),
    the type named where its class lives now: the ready-made configs (`SingleFrameConfig`,
    `RecurrentConfig`) were in jaml.learners.config before jaml.configs.learners."""
    own = record.get("learner_config")
    if isinstance(own, dict) and str(own.get("type")).startswith(OLD_LEARNER_CONFIGS):
        return own | {"type": NEW_LEARNER_CONFIGS + own["type"].rsplit(".", 1)[1]}
    return own


def _migrated(d: dict[str, Any]) -> dict[str, Any]:
    """A record in the tree's form: one written before the tree has its flat fields moved to
    their paths, and its learner's and env's configs taken from "resolved" where it has them,
    else from its overrides on the defaults (which is what they were)."""
    d = dict(d)
    resolved = d.pop(RESOLVED, {})
    learner_overrides = d.pop("learner_overrides", None)
    env_overrides = d.pop("env_overrides", None)
    for flat, path in FLAT_FIELDS.items():
        if flat in d:
            part, name = path.split(".")
            d.setdefault(part, {})[name] = d.pop(flat)
    if learner_overrides is not None or "learner" in resolved:
        d["learner_config"] = resolved.get("learner", {"ld_dim": None, **learner_overrides})
    if env_overrides is not None or "env" in resolved:
        d["env_config"] = resolved.get("env", env_overrides)
    if d.get("learner_config") is not None:
        d["learner_config"] = LEGACY_LEARNER_FIELDS | d["learner_config"]
    d["eval"] = LEGACY_EVAL_FIELDS | d.get("eval", {})
    return d


def _sidecar_penalty(directory: Path) -> dict | None:
    """The `penalty` field of the run in `directory` from its `PENALTY_SIDECAR` (None: none, or
    a method that imposed no relations). The sidecar named its relation set, kept under
    OUT/relations/<set>/checkpoint above the run; fields added to it later read as they ran
    (no ok rows)."""
    path = directory / PENALTY_SIDECAR
    sidecar = json.loads(path.read_text()) if path.exists() else {}
    name = sidecar.get("relations")
    if name is None:
        return None
    homes = [p for p in directory.parents if (p / "relations" / name).is_dir()]
    home = homes[0] if homes else directory.parent.parent
    return {"relations": str(home / "relations" / name / "checkpoint"),
            "used": [i - 1 for i in sidecar["relations_used"]], **PENALTY_SIDECAR_LAYOUT,
            "weight": sidecar["weight"], "form": sidecar["form"],
            "ok_weight": sidecar.get("ok_weight", 0.0),
            "ok_rows": sidecar.get("ok_rows", "relations"),
            "ok_fraction": sidecar.get("ok_fraction")}


def settings(record: dict) -> dict:
    """A run's config.json as the reports show it, flat: the run's fields, its sizes by the
    names of records written before the config tree (`FLAT_FIELDS`), and its learner's and
    env's fields that differ from their defaults (float32 dtypes) as "learner_overrides" and
    "env_overrides" (the learner's ld_dim, the env's, left out). Such an older record is shown
    as written (less its "resolved" configs)."""
    if "replay" not in record:  # written before the tree
        return {k: v for k, v in record.items() if k != RESOLVED}
    config = read(record)
    flat = {k: v for k, v in record.items()
            if k not in ("replay", "eval", "learner_config", "env_config")}
    for name, path in FLAT_FIELDS.items():
        part, field = path.split(".")
        flat[name] = record[part][field]
    # Against the defaults with float32 conv stacks, the reference's: a bfloat16 run says so,
    # whichever machine writes the report.
    default = StreamConfig(env=config.env, learner=config.learner)
    if default.learner_config is not None:
        default = default.replace(learner_config=default.learner_config.for_backend("cpu"))
    for part in ("learner", "env"):
        mine, theirs = getattr(config, f"{part}_config"), getattr(default, f"{part}_config")
        changed = {} if mine is None else changed_fields(mine, theirs, skip=("ld_dim",))
        flat[f"{part}_overrides"] = json.loads(json.dumps(changed))
    return flat
