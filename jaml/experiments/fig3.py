"""Paper Fig. 3: VAE_rpl and SPAIR (4×4 and 6×6 cells) on RearrangeGeom with the reacher arm
(`--env RearrangeYCB`: the same on the realistic objects, which the paper reports as too hard).

Each variant trains its seeds together (`_runs.train_seeds` → `jaml.stream.run.run_many`: one
compiled program, the seeds stacked) on the PPO frame stream into OUT/VARIANT/seed_N, each run
resumable on its own. Then OUT/fig3.md and the images are written from whatever runs exist:

  OUT/fig3.png             alignment error over training, π_curr top row and π_rand bottom, one
                           panel per LD group (arm joint angles, the main joint, object
                           positions, the largest object's position, object orientation), mean
                           and 90 % band over seeds per variant
  OUT/fig3_recon_V.png     variant V's last analysis (first seed): true frames on top, with
                           SPAIR's boxes (presence > 0.5) drawn over them, reconstructions below
  OUT/fig3.md              settings, final errors per group and per object (mean over seeds ±
                           the half-width of its 90 % confidence interval), and the numbers that
                           bear on the paper's claims next to them

The LD groups come from the env's metadata (`ld_state_groups`) and state names (sin_qJ / cos_qJ
arm joints, objK_* object K); the "largest object" has the largest bounding box in every
version used. Positions and joints score by mean |prediction − truth|, orientation by the
reference's principal-axis error (`jaml.evaluation.rotation`, docs/evaluation.md).

What the paper reports (Fig. 3's caption, and §2 "Benchmarking latent state alignment"):
"VAE_rpl encoded angle of the main robot joint, location & partly orientation (major axis) of
the largest objects. SPAIR encoded (rough) locations quickly, but did not improve with longer
training (bounding boxes not tight)."

    python -m jaml.experiments.fig3 --out runs/fig3                     # 3 variants × 3 seeds
    python -m jaml.experiments.fig3 --out runs/fig3 --variants SPAIR_4x4 --stop-after 100
    python -m jaml.experiments.fig3 --out runs/fig3 --report-only       # report from the runs

Settings are the reference's for Rearrange (docs/reference/suite.md §3–5; `REARRANGE`,
`_runs.Sizes`, `FRAMES_PER_BATCH` below, listed in docs/results/fig3.md). The paper does not give
Fig. 3's training length; the default is 300 epochs (222 of them training), analysed every 50.

The variants share nothing, so on one GPU they can run as parallel processes (more throughput
than one process; docs/notes/experiments.md), then one call writes the report:

    for v in VAE_rpl SPAIR_4x4 SPAIR_6x6; do
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.3 python -m jaml.experiments.fig3 --out runs/fig3 \
        --variants $v & done; wait
    python -m jaml.experiments.fig3 --out runs/fig3 --report-only

A run cannot move between machines (its replay is too large to carry), so on a machine held for
a limited time end each call with `--stop-after` (a run stopped between analyses checkpoints
where it stopped; set JAX_COMPILATION_CACHE_DIR outside the checkout to keep the compiled
programs), or start the processes detached (`setsid`) and poll. GPU time per phase, and how
the committed run was made: docs/notes/experiments.md.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import re
import shutil
import sys
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

import envs_mjx
from jaml._options import KeyValues, key_values
from jaml._rundir import write_text
from jaml.configs.stream import for_env, scaled
from jaml.experiments import _runs
from jaml.experiments._runs import cell

# jaml.evaluation (JAX, SciPy, Matplotlib) is imported by the functions that report: the
# command's --help imports none of them (tests/test_launch.py).

# The paper's Fig. 3 domain, and the realistic-object one it reports as too hard for these
# learners (§2); both with the reacher arm by default.
ENVS = ("RearrangeGeom", "RearrangeYCB")
ENV = ENVS[0]
# label → (learner, learner config overrides). The VAE takes the reference's PARAMS_VAE_REARR:
# no ELU/sigmoid on μ, log-variances within ±20, and a latent as wide as the LD state (D, not
# the default 2·D: `config_for` sets it from the env).
VARIANTS = {
    "VAE_rpl": ("VAE_rpl", {"mu_nl": False, "logvar_limit": 20.0}),
    "SPAIR_4x4": ("SPAIR", {"grid_size": 4}),
    "SPAIR_6x6": ("SPAIR", {"grid_size": 6}),
}
SEEDS = (0, 1, 2)
# The paper's batches: 1024 frames for the VAEs, 64 for SPAIR ("its decoding is significantly
# more expensive").
FRAMES_PER_BATCH = {"VAE_rpl": 1024, "SPAIR": 64}
# The reference's Rearrange settings that `stream.for_env` does not set for this domain: the
# rollout it forces to 10 steps, and LD targets used as is ([−1, 1]); 50 learner steps per epoch
# and PPO's MLP 256 with 50 × 4 minibatches are for_env's defaults for it.
REARRANGE = {"rollout_len": 10, "learner_steps": 50, "eval.regressor_normalize": False}
SCHEDULE = (300, 50)  # epochs, eval_every

ARM, MAIN_JOINT, POSITIONS, LARGEST, ORIENTATION = (
    "arm joint angles", "main joint", "object positions", "largest object position",
    "object orientation")
_JOINT = re.compile(r"(?:sin|cos)_(q\d+)")
_OBJECT_POSITION = re.compile(r"(obj\d+)_[xyz]")
_OBJECT_ROTATION = re.compile(r"(obj\d+)_r\d\d")


# ---------------------------------------------------------------------------------------------
# The LD state's layout.


@dataclasses.dataclass(frozen=True)
class Layout:
    """The reacher's LD-state names by part.

    joints: joint → its (sin, cos) names, base joint first (the "main" joint: the shoulder).
    positions / rotations: object slot → its position / rotation-entry names.
    orientations: object slot → the record name of its rotation block's principal-axis error
      (objK_rotation, `jaml.stream.analysis.error_names`).
    shapes: object slot → its shape, or shapes joined by "/" when versions differ.
    largest: the slot whose shape has the largest bounding box in every version used (alone),
      or None.
    """

    joints: dict[str, list[str]]
    positions: dict[str, list[str]]
    rotations: dict[str, list[str]]
    orientations: dict[str, str]
    shapes: dict[str, str]
    largest: str | None

    def groups(self) -> dict[str, list[str]]:
        """The LD entries of Fig. 3's three groups: arm joint angles, object positions, object
        orientation (its rotation entries; the figure scores them by `orientations`)."""
        return {ARM: _flat(self.joints), POSITIONS: _flat(self.positions),
                ORIENTATION: _flat(self.rotations)}

    def panels(self) -> dict[str, list[str]]:
        """The figure's and the table's columns: the groups, the main joint after the arm's and
        the largest object's position after the objects'."""
        main = next(iter(self.joints))
        panels = {ARM: _flat(self.joints), f"{MAIN_JOINT} ({main})": self.joints[main],
                  POSITIONS: _flat(self.positions)}
        if self.largest is not None:
            label = f"{LARGEST} ({self.largest}: {self.shapes[self.largest]})"
            panels[label] = self.positions[self.largest]
        panels[ORIENTATION] = list(self.orientations.values())
        return panels


def _flat(parts: dict[str, list[str]]) -> list[str]:
    return [n for names in parts.values() for n in names]


def layout(env: str = ENV, env_opt: dict | None = None) -> Layout:
    """The layout of `env` (with config overrides `env_opt`) from its own metadata: the
    domain's LD group of each entry (position / orientation / other) and its name (sin_qJ,
    cos_qJ: arm joint J; objK_x/y/z: object K's position; objK_rIJ: its rotation); an entry
    that fits none of these is an error, not silently dropped."""
    return _layout(env, _items(env_opt))


def _items(options: dict | None) -> tuple:
    """Config overrides as a hashable key (JSON lists, as config.json holds them, as tuples)."""
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v)
                        for k, v in (options or {}).items()))


@functools.cache
def _domain(env: str, env_opt: tuple):
    return envs_mjx.make(env, **dict(env_opt))


@functools.cache
def _layout(env: str, env_opt: tuple) -> Layout:
    from jaml.evaluation import rotation

    domain = _domain(env, env_opt)
    joints: dict[str, list[str]] = {}
    positions: dict[str, list[str]] = {}
    rotations: dict[str, list[str]] = {}
    patterns = {"position": ((_JOINT, joints), (_OBJECT_POSITION, positions)),
                "orientation": ((_OBJECT_ROTATION, rotations),)}
    for name, group in zip(domain.ld_state_names, domain.ld_state_groups, strict=True):
        if group == "other":  # the version id: a scene parameter, not state
            continue
        for pattern, parts in patterns.get(group, ()):
            match = pattern.fullmatch(name)
            if match:
                parts.setdefault(match.group(1), []).append(name)
                break
        else:
            raise ValueError(f"{env}: LD entry {name!r} (group {group!r}) is not an arm joint's "
                             "sin/cos nor an object's position or rotation entry")
    if not joints or not positions or set(positions) != set(rotations):
        raise ValueError(f"{env}: expected arm joints and objects with a position and a "
                         f"rotation each, got joints {list(joints)}, positions {list(positions)}, "
                         f"rotations {list(rotations)}")
    starts, labels = rotation.ld_blocks(domain.ld_state_names, domain.ld_state_groups)
    names = list(domain.ld_state_names)
    orientations = {_OBJECT_ROTATION.fullmatch(names[s]).group(1): label
                    for s, label in zip(starts, labels, strict=True)}
    if list(orientations) != list(rotations):
        raise ValueError(f"{env}: rotation blocks {list(orientations)} do not match the objects' "
                         f"rotation entries {list(rotations)}")
    shapes, largest = _object_shapes(domain, list(positions))
    return Layout(joints, positions, rotations, orientations, shapes, largest)


def _object_shapes(domain, slots: list[str]) -> tuple[dict[str, str], str | None]:
    """Per slot its shapes over the env's versions, and the slot of the largest object (by
    bounding-box volume) when one slot holds it, the same in every version."""
    from envs_mjx.domains import rearrange

    geom = domain.objects_kind == "geom"
    sets = rearrange.GEOM_SETS if geom else rearrange.YCB_SETS
    kinds = rearrange.GEOM_KINDS if geom else rearrange.YCB_KINDS
    by_slot: dict[str, list[str]] = {s: [] for s in slots}
    largest: set[str | None] = set()
    for version in domain.versions:
        names = sets[version % len(sets)]
        if len(names) != len(slots):
            raise ValueError(f"version {version} has {len(names)} objects, the LD state "
                             f"{len(slots)}")
        for slot, name in zip(slots, names, strict=True):
            if name not in by_slot[slot]:
                by_slot[slot].append(name)
        volumes = [float(np.prod(kinds[n].extent)) for n in names]
        biggest = [s for s, v in zip(slots, volumes, strict=True) if v == max(volumes)]
        largest.add(biggest[0] if len(biggest) == 1 else None)  # a tie names no slot
    shapes = {s: "/".join(names) for s, names in by_slot.items()}
    return shapes, (largest.pop() if len(largest) == 1 else None)


# ---------------------------------------------------------------------------------------------
# Training.


def config_for(variant: str, seed: int, scale: dict, schedule: tuple[int, int],
               learner_opt: dict | None = None, env_opt: dict | None = None, env: str = ENV,
               preset: str = "paper"):
    """The StreamConfig of one run on `env` (one of ENVS). `scale` holds StreamConfig overrides
    (`_runs.Sizes.overrides()`, or any others: the tests shrink everything); `learner_opt` learner
    config fields for this variant; `preset` "smoke" replaces sizes and schedule
    (`jaml.suite.SCALES`)."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; valid: {', '.join(VARIANTS)}")
    if env not in ENVS:
        raise ValueError(f"unknown env {env!r} for Fig. 3; valid: {', '.join(ENVS)}")
    learner, overrides = VARIANTS[variant]
    if learner == "VAE_rpl":
        overrides = {"latent_dim": len(_domain(env, _items(env_opt)).ld_state_names),
                     **overrides}
    epochs, eval_every = schedule
    settings = {**REARRANGE, "frames_per_batch": FRAMES_PER_BATCH[learner], **scale}
    return scaled(for_env(env, learner, {
        "seed": seed, "epochs": epochs, "eval.every": eval_every, **settings,
        **_runs.options("learner_config", {**overrides, **(learner_opt or {})}),
        **_runs.options("env_config", env_opt or {})}), preset)


def learner_options(items, variants) -> dict[str, dict]:
    """variant → learner config overrides from KEY=VALUE texts: KEY=VALUE for every variant,
    NAME.KEY=VALUE for the variants NAME labels (a variant, e.g. SPAIR_6x6, or a learner, e.g.
    SPAIR for both grids)."""
    names = set(VARIANTS) | {learner for learner, _ in VARIANTS.values()}
    options: dict[str, dict] = {v: {} for v in variants}
    for key, value in key_values(items).items():
        target, _, field = key.rpartition(".")
        if target and target not in names:
            raise ValueError(f"--learner-opt {key}: {target!r} is no variant or learner; "
                             f"valid: {', '.join(sorted(names))}")
        for v in variants:
            if not target or target in (v, VARIANTS[v][0]):
                options[v][field] = value
    return options


def run_cell(out: Path, variant: str, seeds, scale: dict, schedule: tuple[int, int],
             learner_opt: dict | None = None, env_opt: dict | None = None, env: str = ENV,
             preset: str = "paper", **call_options) -> list[dict]:
    """Every seed of one variant, trained together into OUT/VARIANT/seed_N; their summaries.
    `call_options`: `_runs.CallOptions.run_options()` (stop_after, deadline, …)."""
    configs = [config_for(variant, s, scale, schedule, learner_opt, env_opt, env, preset)
               for s in seeds]
    dirs = [out / variant / f"seed_{s}" for s in seeds]
    return _runs.train_seeds(variant, configs, dirs, **call_options)


# ---------------------------------------------------------------------------------------------
# The report.


def collect(out: Path, variants) -> dict[str, list[list[dict]]]:
    """variant → one history per seed run under OUT/VARIANT (records relabelled with the
    variant, since both SPAIR grids record the learner "SPAIR")."""
    runs = {}
    for variant in variants:
        histories = [[r | {"learner": variant} for r in h]
                     for h in _runs.seed_histories(out / variant)]
        if histories:
            runs[variant] = histories
    return runs


def values_at(histories: list[list[dict]], step: int, test_set: str,
              names: list[str], field: str = "errors") -> list[float]:
    """Per seed, the mean error over `names` at `step` on `test_set` (seeds without that
    record, or whose record lacks one of the names, are left out: histories written before the
    stream recorded objK_rotation have no orientation). field="baseline": the latent-free
    constant's errors on the same rows (recorded since the analysis computes them)."""
    values = []
    for h in histories:
        record = next((r for r in h if r["step"] == step and r["test_set"] == test_set), None)
        if record is not None and all(n in record.get(field, {}) for n in names):
            values.append(float(np.mean([record[field][n] for n in names])))
    return values


def _test_sets(histories) -> list[str]:
    """π_curr first (the paper's top row), then π_rand, then anything else."""
    order = {"pi_curr": 0, "pi_rand": 1}
    found = dict.fromkeys(r["test_set"] for h in histories for r in h)
    return sorted(found, key=lambda t: order.get(t, 2))


def _config(out: Path, variant: str) -> dict:
    path = next((out / variant).glob("seed_*/config.json"))
    return _runs.settings(json.loads(path.read_text()))


def _common_steps(histories) -> list[int]:
    """The analysis steps every seed reached, in order."""
    return sorted(set.intersection(*({r["step"] for r in h} for h in histories)))


def _training_steps(histories, config: dict) -> list[int]:
    """The analysis steps every seed reached after its learner started (the replay full)."""
    fill = config["replay_slots"] // config["num_envs"]
    return [s for s in _common_steps(histories) if s > fill]


def _paired(a: list[float], b: list[float]) -> str:
    """Mean of the per-seed differences a − b ± its 90 % half-width."""
    if not a or len(a) != len(b):
        return "–"
    return _signed(cell([x - y for x, y in zip(a, b, strict=True)]))


def _signed(text: str) -> str:
    return text if text.startswith("-") else "+" + text


def _welch(a: list[float], b: list[float]) -> str:
    if not a or not b:
        return "–"
    from jaml.evaluation import intervals

    diff, low, high = intervals.welch_interval(a, b)
    if np.isnan(low):
        return f"{diff:+.3f}"
    return f"{diff:+.3f} [{low:+.3f}, {high:+.3f}]"


def _claims(runs, shape: Layout, configs) -> list[str]:
    """Rows of the claims table: the paper's statement, the measure, and per test set the
    number (paired differences within a variant: mean ± 90 % half-width over seeds; between
    variants: the difference of means and its Welch 90 % interval)."""
    lines = ["| paper | measure (negative: the first is lower) | variant | π_curr | π_rand |",
             "|---|---|---|---|---|"]
    tests = ["pi_curr", "pi_rand"]
    main, *others = list(shape.joints)

    def row(claim, measure, variant, per_test):
        lines.append(f"| {claim} | {measure} | {variant} | "
                     + " | ".join(per_test(t) for t in tests) + " |")

    if "VAE_rpl" in runs:
        h = runs["VAE_rpl"]
        last = _runs.last_common_step(h)
        if others:
            row("VAE_rpl encoded the main joint's angle", f"{main} − {others[0]} error, epoch "
                f"{last}", "VAE_rpl",
                lambda t: _paired(values_at(h, last, t, shape.joints[main]),
                                  values_at(h, last, t, shape.joints[others[0]])))
        if shape.largest is not None:
            rest = [n for k, names in shape.positions.items() if k != shape.largest
                    for n in names]
            row("… and the location of the largest objects",
                f"{shape.largest} − other objects' position error, epoch {last}", "VAE_rpl",
                lambda t: _paired(values_at(h, last, t, shape.positions[shape.largest]),
                                  values_at(h, last, t, rest)))
    positions = _flat(shape.positions)
    for variant, h in runs.items():
        # From the first analysis (the replay just full, no learner step yet): what training
        # changed at all, for every variant.
        common = _common_steps(h)
        if len(common) >= 2:
            first, last = common[0], common[-1]
            row("(what training changed)", f"object position error, epoch {last} − epoch "
                f"{first} (no learner step yet)", variant,
                lambda t, h=h, first=first, last=last: _paired(
                    values_at(h, last, t, positions), values_at(h, first, t, positions)))
            if variant == "VAE_rpl" and shape.largest is not None:
                largest = shape.positions[shape.largest]
                row("(what training changed)", f"{shape.largest} position error, epoch {last} "
                    f"− epoch {first}", variant,
                    lambda t, h=h, first=first, last=last, largest=largest: _paired(
                        values_at(h, last, t, largest), values_at(h, first, t, largest)))
        if VARIANTS[variant][0] != "SPAIR":
            continue
        steps = _training_steps(h, configs[variant])
        if len(steps) >= 2:
            row("SPAIR encoded rough locations quickly but did not improve with longer training",
                f"object position error, epoch {steps[-1]} − epoch {steps[0]}", variant,
                lambda t, h=h, steps=steps: _paired(values_at(h, steps[-1], t, positions),
                                                    values_at(h, steps[0], t, positions)))
        if "VAE_rpl" in runs:
            last = min(_runs.last_common_step(h), _runs.last_common_step(runs["VAE_rpl"]))
            row("(SPAIR against VAE_rpl)", f"object position error − VAE_rpl's, epoch {last}",
                variant, lambda t, h=h, last=last: _welch(
                    values_at(h, last, t, positions),
                    values_at(runs["VAE_rpl"], last, t, positions)))
    return lines if len(lines) > 2 else []


def _recon_image(out: Path, variant: str, stopped=()) -> tuple[Path, str] | None:
    """The newest reconstruction image of the variant's first seed that has one and is not
    `stopped` (seed directory names), copied to OUT/fig3_recon_VARIANT.png; (its path, a
    caption)."""
    for seed_dir in sorted((out / variant).glob("seed_*")):
        if seed_dir.name in stopped:
            continue
        images = sorted((seed_dir / "recon").glob("epoch_*.png"))
        if images:
            target = out / f"fig3_recon_{variant}.png"
            shutil.copyfile(images[-1], target)
            epoch = int(images[-1].stem.split("_")[1])
            return target, f"{variant}, {seed_dir.name}, epoch {epoch}"
    return None


def plot(runs: dict[str, list[list[dict]]], panels: dict[str, list[str]], path: Path) -> None:
    """fig3.png: mean and 90 % band over seeds per variant, π_curr top row, π_rand bottom."""
    from jaml.evaluation import plots

    records = sorted((r for hs in runs.values() for h in hs for r in h),
                     key=lambda r: r["test_set"] != "pi_curr")
    fig = plots.plot_alignment(records, path, groups=panels)
    # Rearrange targets are not z-scored (docs/reference/suite.md §5): the errors are in the LD
    # state's units, orientation's the principal-axis error.
    for ax in fig.axes:
        ax.set_xlabel("epoch")
        if ax.get_ylabel():
            ax.set_ylabel("mean |error| (LD units)")
        if ax.get_title().startswith(ORIENTATION):
            ax.set_title(ax.get_title().replace(ORIENTATION, f"{ORIENTATION} (principal axis)"),
                         fontsize=9)
    plots.save_figure(fig, path)


def report(out: Path, variants=tuple(VARIANTS)) -> str:
    """OUT/fig3.md, fig3.png and the reconstruction images from every run under OUT; returns
    the markdown."""
    out = Path(out)
    if not out.is_dir():
        raise FileNotFoundError(f"{out}: no such directory (train first, or check --out)")
    runs = collect(out, variants)
    # The env the runs used (their versions decide the objects' shapes).
    configs = {v: _config(out, v) for v in runs}
    envs = {c.get("env", ENV) for c in configs.values()} or {ENV}
    if len(envs) > 1:
        raise ValueError(f"{out} holds runs of several envs ({', '.join(sorted(envs))}); give "
                         "each env its own --out")
    env = envs.pop()
    shape = layout(env, next(iter(configs.values()), {}).get("env_overrides"))
    panels = shape.panels()
    lines = [f"# Fig. 3: {env} (reacher), alignment of VAE_rpl and SPAIR with the true "
             "state", "",
             "Errors are mean |prediction − truth| per LD entry in the state's own units "
             "(positions normalised to [−1, 1], sin/cos of the joints; lower is better), at the "
             "last epoch every seed of a variant reached: mean over seeds ± the half-width of "
             "its 90 % confidence interval. Orientation is the reference's principal-axis error "
             "of each object's rotation block (M = R_trueᵀR̂: the mean over i of "
             "min(|M[i,2] − e_z[i]|, |M[i,2] + e_z[i]|), neither degrees nor radians: 0 when "
             "the major axes agree up to sign, 2/3 for perpendicular axes, 1/3 for a zero "
             "prediction), averaged over the objects; "
             "– where the runs did not record it. A \"constant prediction\" row (runs analysed "
             "since the analysis records it) is what a latent with no information scores on the "
             "same rows: every row predicted as the median of the regressor's training targets "
             "(the ceiling); a \"true state\" row (runs since 2026-11-29) what the regressor "
             "scores with the true state itself as the latent, at the first analysis of each "
             "run's last call (the floor).",
             "", "The paper: \"VAE_rpl encoded angle of the main robot joint, location & partly "
             "orientation (major axis) of the largest objects. SPAIR encoded (rough) locations "
             "quickly, but did not improve with longer training (bounding boxes not tight).\"",
             ""]
    if not runs:
        lines += [f"No analysed runs under {out} yet.", ""]
        text = "\n".join(lines)
        write_text(out / "fig3.md", text)
        return text
    lines += ["## Settings", ""]
    keys = (*_runs.SIZES, "epochs", "eval_every", "rollout_len", "learner_steps",
            "frames_per_batch", "learner_overrides", "env_overrides")
    for variant, config in configs.items():
        lines.append(f"- {variant}: `{json.dumps({k: config.get(k) for k in keys})}`")
    columns = list(panels)
    lines += ["", "## Alignment by group", "",
              "| variant | test set | " + " | ".join(columns) + " | epoch | seeds |",
              "|---" * (len(columns) + 4) + "|"]
    for variant, histories in runs.items():
        last = _runs.last_common_step(histories)
        floors = _runs.true_state_errors(out / variant, list(histories[0][0]["errors"]))
        for test_set in _test_sets(histories):
            for label, field in ((variant, "errors"),
                                 (f"{variant}: constant prediction", "baseline")):
                per_panel = [values_at(histories, last, test_set, panels[c], field)
                             for c in columns]
                if field == "errors" or any(per_panel):  # constants: runs that recorded them
                    lines.append(f"| {label} | {test_set} | "
                                 + " | ".join(cell(v) if v else "–" for v in per_panel)
                                 + f" | {last} | {len(per_panel[0])} |")
            if floors.get(test_set):  # the floor, where the runs recorded it
                per_panel = [[float(np.mean([r[n] for n in panels[c]])) for r in floors[test_set]]
                             for c in columns]
                lines.append(f"| {variant}: true state | {test_set} | "
                             + " | ".join(cell(v) for v in per_panel)
                             + f" | — | {len(floors[test_set])} |")
    stopped = {v: _runs.stopped_runs(out / v) for v in variants}
    notes = [f"- {variant} {seed}: stopped, {error.split(';')[0]}; left out of every table "
             "and figure." for variant, errors in stopped.items()
             for seed, error in errors.items()]
    if notes:
        lines += ["", *notes]
    plot(runs, panels, out / "fig3.png")
    lines += ["", "![Fig. 3](fig3.png)", "", "## Per object", ""]
    if any("sphere" in s for s in shape.shapes.values()):
        lines += ["Spheres are one colour: their rotation does not show in a frame.", ""]
    lines += ["| variant | test set | "
              + " | ".join(f"{k} ({shape.shapes[k]}) {part}" for k in shape.positions
                           for part in ("position", "orientation")) + " |",
              "|---" * (2 * len(shape.positions) + 2) + "|"]
    for variant, histories in runs.items():
        last = _runs.last_common_step(histories)
        for test_set in _test_sets(histories):
            cells = [values_at(histories, last, test_set, names)
                     for k in shape.positions
                     for names in (shape.positions[k], [shape.orientations[k]])]
            lines.append(f"| {variant} | {test_set} | "
                         + " | ".join(cell(v) if v else "–" for v in cells) + " |")
    claims = _claims(runs, shape, configs)
    if claims:
        lines += ["", "## The paper's claims, side by side", "", *claims]
    images = [x for x in (_recon_image(out, v, stopped[v]) for v in runs) if x is not None]
    if images:
        lines += ["", "## Reconstructions at the last analysis", "",
                  "Top row: true frames (SPAIR: its boxes with presence > 0.5 drawn over them); "
                  "bottom row: the learner's reconstructions.", ""]
        for path, caption in images:
            lines += [f"{caption}:", "", f"![{caption}]({path.name})", ""]
    text = "\n".join(lines) + "\n"
    write_text(out / "fig3.md", text)
    return text


# ---------------------------------------------------------------------------------------------
# The command.


@dataclasses.dataclass(frozen=True)
class Args(_runs.Driver):
    """Paper Fig. 3: VAE_rpl and SPAIR (4×4, 6×6) on RearrangeGeom (or RearrangeYCB) with the
    reacher, PPO stream; each variant trains its seeds together into OUT/VARIANT/seed_N (each
    resumable), then OUT/fig3.md, fig3.png and the reconstruction images are written from the
    runs."""

    out: Path
    """the experiment's directory (one env per directory)"""
    env: Literal[ENVS] = ENV
    """the domain: RearrangeGeom (the paper's Fig. 3) or RearrangeYCB (textured stand-ins for
    the YCB objects; the paper found it too hard for these learners)"""
    variants: tuple[Literal[tuple(VARIANTS)], ...] = tuple(VARIANTS)
    """learner variants (SPAIR with 4×4 or 6×6 cells)"""
    seeds: tuple[int, ...] = SEEDS
    """seeds of each variant, trained together"""
    learner_opt: KeyValues = ()
    """a learner config field: KEY=VALUE for every variant, VARIANT.KEY=VALUE or
    LEARNER.KEY=VALUE for some, e.g. SPAIR.beta=0.2"""
    env_opt: KeyValues = ()
    """an env config field for every run, e.g. versions=[0,1]"""
    sizes: Annotated[_runs.Sizes, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_runs.Sizes)
    epochs: int = SCHEDULE[0]
    """epochs of every run (the first replay_slots / num_envs fill the replay)"""
    eval_every: int = SCHEDULE[1]
    """epochs between analyses"""
    call: Annotated[_runs.CallOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_runs.CallOptions)
    scale: Literal["paper", "smoke"] = "paper"
    """"smoke": every run at `jaml.suite.SCALES["smoke"]` (4 epochs, small sets), replacing
    the size and schedule flags"""
    report_only: bool = False
    """no training: fig3.md and the images from the runs under OUT"""

    def train(self) -> None:
        options = learner_options(self.learner_opt, self.variants)
        env_opt = key_values(self.env_opt)
        for variant in self.variants:
            run_cell(self.out, variant, self.seeds, self.sizes.under(self.scale),
                     (self.epochs, self.eval_every), options[variant], env_opt, self.env,
                     self.scale, **self.call.run_options())

    def report(self) -> str:
        return report(self.out, self.variants)


def main(argv=None) -> int:
    """`python -m jaml.experiments.fig3 ARGS` is `jaml fig3 ARGS`."""
    # This module's importable copy (run as a script, this one is __main__, whose classes
    # the command line's help rule does not read as jaml's): as `jaml fig3` has it.
    from jaml.experiments import fig3

    return _runs.main("fig3", fig3.Args, argv)


if __name__ == "__main__":
    sys.exit(main())
