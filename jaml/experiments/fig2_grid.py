"""Fig. 2's grid as its reports read it: the domains and seeds, each cell's histories, the
domains' LD-state groups and a record's mean error over a group (`fig2` and `fig2_claims`)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

import envs_mjx
from jaml.experiments import _runs

PENDULUMS = ("CartPole", "InvertedPendulum")
LOCOMOTION = ("HalfCheetah", "Ant")
ENVS = PENDULUMS + LOCOMOTION
SEEDS = tuple(range(6))


def ld_groups(env: str) -> dict[str, list[str]]:
    """group → LD-state names of `env`, from the domain's own metadata (`ld_state_groups`):
    the paper aggregates position, velocity and contacts (Fig. 2, locomotion)."""
    return {group: list(names) for group, names in _ld_groups(env)}


@functools.cache
def _ld_groups(env: str) -> tuple[tuple[str, tuple[str, ...]], ...]:
    # Building the domain parses its MJCF; a report reads the groups for every cell and check.
    domain = envs_mjx.make(env)
    groups: dict[str, list[str]] = {}
    for name, group in zip(domain.ld_state_names, domain.ld_state_groups, strict=True):
        if group != "other":
            groups.setdefault(group, []).append(name)
    return tuple((group, tuple(names)) for group, names in groups.items())


def grid_histories(out: Path, env: str, variants) -> dict[str, list[list[dict]]]:
    """variant → one history per seed run found under OUT/ENV/VARIANT."""
    runs = {}
    for variant in variants:
        histories = _runs.seed_histories(out / env / variant)
        if histories:
            runs[variant] = histories
    return runs


def group_value(record: dict, dims, relative: bool = False) -> float | None:
    """A record's mean error over `dims`, or (relative) that over the mean error of a constant
    prediction on the same test rows (the record's `baseline`), None where the record has none.

    Errors are in units of each run's regressor training targets, which come from its replay:
    VAE_v0's replay holds only current-policy frames, VAE_rpl's keeps early random-policy ones,
    and two runs' PPO streams differ, so the same error means different things across cells
    (on HalfCheetah a constant scored 1.57 on π_rand position in VAE_v0's units, 1.15 in
    VAE_rpl's). The fraction of the constant's error puts them on one scale."""
    error = float(np.mean([record["errors"][d] for d in dims]))
    if not relative:
        return error
    baseline = record.get("baseline")
    if not baseline:
        return None  # runs recorded before the analysis wrote baselines
    return error / float(np.mean([baseline[d] for d in dims]))
