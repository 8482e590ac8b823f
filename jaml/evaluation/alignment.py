"""Latent–state alignment (paper §2.1, Fig. 2): test error of an MLP regressor latents → LD state.

A fresh regressor per analysis, as in the reference suite (`docs/reference/suite.md` §5);
its architecture, training, units, rotation blocks and deviations are tabled in
docs/evaluation.md. Shapes: N rows, Z latent width, D LD-state width, J rotation blocks.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaml.evaluation import _checks, rotation


@dataclasses.dataclass(frozen=True)
class RegressorConfig:
    """Knobs of the alignment regressor; defaults are the reference suite's (§5).

    Attributes:
      hidden: hidden layer widths (`analyze_hsz` 256, 256).
      dropout: dropout rate after each hidden ReLU (train mode only).
      learning_rate: Adam step size.
      num_iterations: optimizer steps, one random minibatch each.
      seq_len: L of the learner whose latents are evaluated; sets the default minibatch size.
      batch_size: rows per step; None ⇒ 4·(1024 // seq_len). Capped at the number of fit rows.
      validation_fraction: leading fraction of the training rows split off and not fit on
        (the reference disables early stopping, so they only give a held-out error).
      normalize: z-score targets with the fit rows' mean/std (benchmark envs); False for domains
        already in a fixed range (Rearrange [−1, 1], Incline [0, 1]), errors then in raw units.
      std_eps: added to the std before dividing.
      rotation_starts: start indices of 9-entry rotation blocks in the targets (e.g.
        `rotation.rearrange_rotation_starts()`); the fit then minimises the reference's loss,
        L1 on the other dims plus each block's mean principal-axis error. Needs
        normalize=False (z-scored entries are no longer a rotation).
    """

    hidden: tuple[int, ...] = (256, 256)
    dropout: float = 0.2
    learning_rate: float = 1e-4
    num_iterations: int = 10_000
    seq_len: int = 1
    batch_size: int | None = None
    validation_fraction: float = 0.3
    normalize: bool = True
    std_eps: float = 1e-6
    rotation_starts: tuple[int, ...] = ()

    def __post_init__(self):
        problems = []
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            problems.append(f"hidden must be non-empty positive widths, got {self.hidden}")
        if not 0.0 <= self.dropout < 1.0:
            problems.append(f"dropout must be in [0, 1), got {self.dropout}")
        if self.learning_rate <= 0:
            problems.append(f"learning_rate must be > 0, got {self.learning_rate}")
        if self.num_iterations < 1:
            problems.append(f"num_iterations must be ≥ 1, got {self.num_iterations}")
        if self.seq_len < 1:
            problems.append(f"seq_len must be ≥ 1, got {self.seq_len}")
        if self.batch_size is not None and self.batch_size < 1:
            problems.append(f"batch_size must be ≥ 1, got {self.batch_size}")
        if not 0.0 <= self.validation_fraction < 1.0:
            problems.append(
                f"validation_fraction must be in [0, 1), got {self.validation_fraction}"
            )
        if self.rotation_starts and self.normalize:
            problems.append("rotation_starts needs normalize=False (Rearrange targets are used "
                            "as is)")
        if problems:
            raise ValueError("; ".join(problems))

    def batch_for(self, num_rows: int) -> int:
        """Minibatch size for `num_rows` fit rows: min(4·(1024 // L), N) unless set."""
        if self.batch_size is not None:
            return min(self.batch_size, num_rows)
        return min(4 * max(1024 // self.seq_len, 1), num_rows)

    def split(self, num_rows: int) -> int:
        """Number of leading rows held out as validation."""
        return math.floor(self.validation_fraction * num_rows)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Regressor:
    """A fitted alignment regressor: MLP parameters and the target normalisation.

    Attributes:
      params: list of {"w": [in, out], "b": [out]} per layer, last one linear.
      mean, std: [D] target statistics (0 and 1 when not normalising).
      validation_error: [D] error on the held-out leading rows (NaN when none were held out).
    """

    params: list
    mean: jax.Array
    std: jax.Array
    validation_error: jax.Array


def _init_mlp(key: jax.Array, sizes: tuple[int, ...]) -> list:
    """PyTorch `nn.Linear` default init: W, b ~ U(±1/√fan_in). sizes = (Z, *hidden, D)."""
    params = []
    keys = jax.random.split(key, len(sizes) - 1)
    for k, fan_in, fan_out in zip(keys, sizes[:-1], sizes[1:], strict=True):
        kw, kb = jax.random.split(k)
        bound = 1.0 / math.sqrt(fan_in)
        params.append(
            {
                "w": jax.random.uniform(kw, (fan_in, fan_out), jnp.float32, -bound, bound),
                "b": jax.random.uniform(kb, (fan_out,), jnp.float32, -bound, bound),
            }
        )
    return params


def _apply_mlp(params: list, x: jax.Array, dropout: float, key: jax.Array | None) -> jax.Array:
    """[B, Z] → [B, D]. ReLU + (inverted) dropout after each hidden layer; key None ⇒ eval mode."""
    for i, layer in enumerate(params[:-1]):
        x = jax.nn.relu(x @ layer["w"] + layer["b"])
        if key is not None and dropout > 0.0:
            keep = jax.random.bernoulli(jax.random.fold_in(key, i), 1.0 - dropout, x.shape)
            x = jnp.where(keep, x / (1.0 - dropout), 0.0)
    return x @ params[-1]["w"] + params[-1]["b"]


def _per_dim_l1(params: list, x: jax.Array, y: jax.Array) -> jax.Array:
    """Eval-mode mean |f(x) − y| per target dimension: [N, Z], [N, D] → [D]."""
    return jnp.mean(jnp.abs(_apply_mlp(params, x, 0.0, None) - y), axis=0)


def _scores(params: list, x: jax.Array, y: jax.Array, starts: tuple[int, ...]) -> jax.Array:
    """`_per_dim_l1` [D], then, for rotation blocks at `starts`, each block's mean
    principal-axis error [J]: [D + J]. y unnormalised when there are blocks."""
    if not starts:
        return _per_dim_l1(params, x, y)
    pred = _apply_mlp(params, x, 0.0, None)
    return jnp.concatenate([jnp.mean(jnp.abs(pred - y), axis=0),
                            jnp.mean(rotation.block_errors(pred, y, starts), axis=0)])


@functools.partial(jax.jit, static_argnames=("config", "batch"))
def _train(key: jax.Array, x: jax.Array, y: jax.Array, config: RegressorConfig, batch: int):
    """The whole fit as one compiled scan. x [N, Z], y [N, D] (already normalised) → params."""
    init_key, loop_key = jax.random.split(key)
    params = _init_mlp(init_key, (x.shape[1], *config.hidden, y.shape[1]))
    optimizer = optax.adam(config.learning_rate)
    opt_state = optimizer.init(params)
    n = x.shape[0]

    def loss_fn(p, xb, yb, dropout_key):
        pred = _apply_mlp(p, xb, config.dropout, dropout_key)
        if config.rotation_starts:
            return rotation.alignment_loss(pred, yb, config.rotation_starts)
        return jnp.mean(jnp.abs(pred - yb))

    def step(carry, step_key):
        p, s = carry
        batch_key, dropout_key = jax.random.split(step_key)
        if batch == n:  # the whole fit set every step
            xb, yb = x, y
        else:
            idx = jax.random.randint(batch_key, (batch,), 0, n)
            xb, yb = x[idx], y[idx]
        loss, grads = jax.value_and_grad(loss_fn)(p, xb, yb, dropout_key)
        updates, s = optimizer.update(grads, s, p)
        return (optax.apply_updates(p, updates), s), loss

    (params, _), losses = jax.lax.scan(
        step, (params, opt_state), jax.random.split(loop_key, config.num_iterations)
    )
    return params, losses


def fit_regressor(latents, states, seed: int = 0, config: RegressorConfig | None = None,
                  **overrides) -> Regressor:
    """Trains a fresh regressor latents [N, Z] → states [N, D]; deterministic for a given seed."""
    config = _resolve(config, overrides)
    x, y = _checks.paired(("latents_train", "states_train"), latents, states)
    n_val = config.split(x.shape[0])
    if x.shape[0] - n_val < 2:
        raise ValueError(
            f"latents_train/states_train: too few samples, {x.shape[0]} rows leave "
            f"{x.shape[0] - n_val} to fit after the {config.validation_fraction:.0%} validation "
            "split; need at least 2"
        )
    rotation.check_starts(config.rotation_starts, y.shape[1])
    x_fit, y_fit = x[n_val:].astype(np.float32), y[n_val:].astype(np.float32)
    if config.normalize:
        mean = y_fit.mean(axis=0)
        std = y_fit.std(axis=0) + config.std_eps
    else:
        mean = np.zeros(y.shape[1], np.float32)
        std = np.ones(y.shape[1], np.float32)
    params, _ = _train(
        jax.random.key(seed),
        jnp.asarray(x_fit),
        jnp.asarray((y_fit - mean) / std),
        config,
        config.batch_for(x_fit.shape[0]),
    )
    if n_val > 0:
        val = _per_dim_l1(params, jnp.asarray(x[:n_val], jnp.float32),
                          jnp.asarray((y[:n_val] - mean) / std, jnp.float32))
    else:
        val = jnp.full((y.shape[1],), jnp.nan, jnp.float32)
    return Regressor(params, jnp.asarray(mean), jnp.asarray(std), val)


def regressor_error(regressor: Regressor, latents, states, name: str = "test") -> jax.Array:
    """Per-dimension test error [D] of a fitted regressor, in training-std units when normalised."""
    x, y = _checks.paired((f"latents_{name}", f"states_{name}"), latents, states)
    z_in = regressor.params[0]["w"].shape[0]
    d_out = regressor.mean.shape[0]
    if x.shape[1] != z_in:
        raise ValueError(f"latents_{name}: width {x.shape[1]} does not match training width {z_in}")
    if y.shape[1] != d_out:
        raise ValueError(f"states_{name}: width {y.shape[1]} does not match training width {d_out}")
    y_norm = (jnp.asarray(y, jnp.float32) - regressor.mean) / regressor.std
    return _jit_per_dim_l1(regressor.params, jnp.asarray(x, jnp.float32), y_norm)


_jit_per_dim_l1 = jax.jit(_per_dim_l1)


def rotation_errors(regressor: Regressor, latents, states, starts, name: str = "test"
                    ) -> jax.Array:
    """[J]: the mean principal-axis error of each rotation block (`rotation.block_errors`) of a
    regressor fitted without normalisation, on a test set latents [N, Z] → states [N, D]."""
    x, y = _checks.paired((f"latents_{name}", f"states_{name}"), latents, states)
    if not (np.all(np.asarray(regressor.mean) == 0) and np.all(np.asarray(regressor.std) == 1)):
        raise ValueError("rotation_errors needs a regressor fitted with normalize=False")
    starts = rotation.check_starts(starts, regressor.mean.shape[0])
    if y.shape[1] != regressor.mean.shape[0]:
        raise ValueError(f"states_{name}: width {y.shape[1]} does not match training width "
                         f"{regressor.mean.shape[0]}")
    return _jit_rotation_errors(regressor.params, jnp.asarray(x, jnp.float32),
                                jnp.asarray(y, jnp.float32), starts)


@functools.partial(jax.jit, static_argnames="starts")
def _jit_rotation_errors(params, x, y, starts):
    pred = _apply_mlp(params, x, 0.0, None)
    return jnp.mean(rotation.block_errors(pred, y, starts), axis=0)


def alignment_errors(latents_train, states_train, test_sets: Mapping[str, tuple], seed: int = 0,
                     config: RegressorConfig | None = None, **overrides) -> dict[str, jax.Array]:
    """Fits once, then errors [D] on each named test set, e.g. {"pi_curr": (lat, st), "pi_rand": …}.

    The result also carries "validation": the error on the held-out leading training rows.
    With `rotation_starts` (J blocks) each is [D + J]: the per-entry errors, then each block's
    mean principal-axis error (`rotation_errors`). `alignment_errors_runs` with one run.
    """
    if not isinstance(test_sets, Mapping) or not test_sets:
        raise ValueError("test_sets must be a non-empty mapping name → (latents, states)")
    if "validation" in test_sets:
        raise ValueError('test_sets: the name "validation" is reserved for the held-out rows')
    for name, pair in test_sets.items():
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise ValueError(f"test_sets[{name!r}] must be a pair (latents, states)")
    x, y = _checks.paired(("latents_train", "states_train"), latents_train, states_train)
    tests = {}
    for name, (lat, st) in test_sets.items():  # fail before the (long) fit, not after it
        xt, yt = _checks.paired((f"latents_{name}", f"states_{name}"), lat, st)
        if xt.shape[1] != x.shape[1] or yt.shape[1] != y.shape[1]:
            raise ValueError(
                f"test set {name!r}: widths (Z={xt.shape[1]}, D={yt.shape[1]}) differ from the "
                f"training set's (Z={x.shape[1]}, D={y.shape[1]})"
            )
        tests[name] = (xt[None], yt[None])
    errors = alignment_errors_runs(x[None], y[None], tests, [seed], config, **overrides)
    return {name: e[0] for name, e in errors.items()}


def alignment_error(latents_train, states_train, latents_test, states_test, seed: int = 0,
                    config: RegressorConfig | None = None, **overrides) -> jax.Array:
    """Per-dimension test error [D]: latents [N, Z] → states [N, D], in training-std units
    ([D + J] with `rotation_starts`, see `alignment_errors`)."""
    return alignment_errors(
        latents_train, states_train, {"test": (latents_test, states_test)}, seed, config,
        **overrides,
    )["test"]


def alignment_errors_runs(latents_train, states_train, test_sets: Mapping[str, tuple], seeds,
                          config: RegressorConfig | None = None, **overrides
                          ) -> dict[str, jax.Array]:
    """`alignment_errors` of R independent data sets at once, one fit per run, vmapped.

    latents_train [R, N, Z], states_train [R, N, D], test_sets {name: ([R, Nt, Z], [R, Nt, D])},
    seeds [R] ints: errors [R, D] per name (and "validation"), where row r is what
    `alignment_errors` gives for run r's arrays and seeds[r] ([D + J] with `rotation_starts`).
    One compiled program fits every run: one scan of Adam steps, each step every run's.
    """
    if not isinstance(test_sets, Mapping) or not test_sets:
        raise ValueError("test_sets must be a non-empty mapping name → (latents, states)")
    if "validation" in test_sets:
        raise ValueError('test_sets: the name "validation" is reserved for the held-out rows')
    config = _resolve(config, overrides)
    x = jnp.asarray(latents_train, jnp.float32)
    y = jnp.asarray(states_train, jnp.float32)
    seeds = np.asarray(seeds)
    if x.ndim != 3 or y.ndim != 3 or x.shape[:2] != y.shape[:2] or seeds.shape != x.shape[:1]:
        raise ValueError(f"expected latents [R, N, Z], states [R, N, D] and seeds [R]; got "
                         f"{x.shape}, {y.shape} and {seeds.shape}")
    tests = {}
    for name, pair in test_sets.items():
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise ValueError(f"test_sets[{name!r}] must be a pair (latents, states)")
        xt, yt = (jnp.asarray(a, jnp.float32) for a in pair)
        if (xt.ndim != 3 or yt.ndim != 3 or xt.shape[:2] != yt.shape[:2]
                or xt.shape[0] != x.shape[0] or xt.shape[2] != x.shape[2]
                or yt.shape[2] != y.shape[2]):
            raise ValueError(f"test set {name!r}: shapes {xt.shape}, {yt.shape} do not match the "
                             f"training sets' {x.shape}, {y.shape} (same R, Z and D)")
        tests[name] = (xt, yt)
    n_val = config.split(x.shape[1])
    if x.shape[1] - n_val < 2:
        raise ValueError(f"latents_train/states_train: too few samples, {x.shape[1]} rows leave "
                         f"{x.shape[1] - n_val} to fit; need at least 2")
    rotation.check_starts(config.rotation_starts, y.shape[2])
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds, jnp.uint32))
    errors = _fit_and_score_runs(keys, x, y, tests, config, n_val,
                                 config.batch_for(x.shape[1] - n_val))
    # In `alignment_errors`'s order (test sets as given, then "validation"): a jitted function
    # returns its dicts with sorted keys, and the run directory writes records in this order.
    return {name: errors[name] for name in [*test_sets, "validation"]}


def constant_errors(states_train, test_states: Mapping[str, object],
                    config: RegressorConfig | None = None, *, validation: bool = False,
                    **overrides) -> dict[str, np.ndarray]:
    """The errors of a prediction that ignores the latents: the level an alignment error is read
    against (what a latent that encodes nothing of the state scores).

    Every test row is predicted as the per-entry median of the training rows the regressor would
    be fit on (after its validation split): the constant that minimises their L1 error. Scored
    in the regressor's units (training-std units when `normalize`) and, with `rotation_starts`,
    followed by each block's mean principal-axis error of that constant block (not the block
    loss's own optimum: the median of rotation entries is the reference's regressor fed
    uninformative latents, to first order). states_train [N, D], test_states {name: [Nt, D]}
    → {name: [D] or [D + J]} numpy arrays; with `validation`, then "validation" on the held-out
    training rows (NaN where the split holds none), the level of `alignment_errors`' own.
    """
    config = _resolve(config, overrides)
    y = np.asarray(states_train, np.float64)
    if y.ndim != 2 or y.shape[0] < 1:
        raise ValueError(f"states_train must be [N, D] with N ≥ 1, got shape {y.shape}")
    if validation and "validation" in test_states:
        raise ValueError('test_states: the name "validation" is reserved for the held-out rows')
    starts = rotation.check_starts(config.rotation_starts, y.shape[1])
    n_val = config.split(y.shape[0])
    y_fit = y[n_val:]  # the split holds out under 100 %: never empty
    scale = y_fit.std(axis=0) + config.std_eps if config.normalize else np.ones(y.shape[1])
    constant = np.median(y_fit, axis=0)
    errors = {}
    for name, states in test_states.items():
        yt = np.asarray(states, np.float64)
        if yt.ndim != 2 or yt.shape[1] != y.shape[1]:
            raise ValueError(f"test_states[{name!r}] must be [Nt, {y.shape[1]}], got shape "
                             f"{yt.shape}")
        errors[name] = _constant_error(constant, scale, yt, starts)
    if validation:
        errors["validation"] = (_constant_error(constant, scale, y[:n_val], starts) if n_val
                                else np.full(y.shape[1] + len(starts), np.nan, np.float32))
    return errors


def _constant_error(constant, scale, states, starts) -> np.ndarray:
    """float32 [D + J]: `constant` [D] scored on `states` [Nt, D] (`constant_errors`)."""
    per_entry = np.mean(np.abs(states - constant) / scale, axis=0)
    if starts:
        pred = np.broadcast_to(constant, states.shape).astype(np.float32)
        blocks = np.asarray(rotation.block_errors(jnp.asarray(pred),
                                                  jnp.asarray(states, jnp.float32), starts))
        per_entry = np.concatenate([per_entry, blocks.mean(axis=0)])
    return per_entry.astype(np.float32)


def _resolve(config: RegressorConfig | None, overrides: dict) -> RegressorConfig:
    known = {f.name for f in dataclasses.fields(RegressorConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"unknown regressor override(s) {unknown}; known: {sorted(known)}")
    return dataclasses.replace(config or RegressorConfig(), **overrides)


@functools.partial(jax.jit, static_argnames=("config", "n_val", "batch"))
def _fit_and_score_runs(keys, x, y, tests, config: RegressorConfig, n_val: int, batch: int):
    """Per run (vmapped): `fit_regressor` then `regressor_error` on each test set."""

    def one(key, x, y, tests):
        x_fit, y_fit = x[n_val:], y[n_val:]
        if config.normalize:
            mean = y_fit.mean(axis=0)
            std = y_fit.std(axis=0) + config.std_eps
        else:
            mean, std = jnp.zeros(y.shape[1], jnp.float32), jnp.ones(y.shape[1], jnp.float32)
        params, _ = _train(key, x_fit, (y_fit - mean) / std, config, batch)
        starts = config.rotation_starts
        errors = {name: _scores(params, xt, (yt - mean) / std, starts)
                  for name, (xt, yt) in tests.items()}
        errors["validation"] = (
            _scores(params, x[:n_val], (y[:n_val] - mean) / std, starts) if n_val > 0
            else jnp.full((y.shape[1] + len(starts),), jnp.nan, jnp.float32))
        return errors

    return jax.vmap(one)(keys, x, y, tests)
