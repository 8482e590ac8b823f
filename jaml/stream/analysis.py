"""The periodic analysis of a run (docs/reference/suite.md §5): alignment of its latents with
the true state.

What is encoded, fit and reported (π_rand, π_curr, rotation blocks): docs/stream.md,
"Analysis"; beside each error, a constant prediction's (the training targets' median,
`evaluation.constant_errors`), which the error is read against. Shapes: R runs, E envs,
L = learner.seq_len, N sequences, Z latent, D LD state, J rotation blocks.
"""

from __future__ import annotations

import dataclasses
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from envs_mjx.base import State
from jaml import evaluation
from jaml.evaluation import alignment, rotation
from jaml.evaluation import references as references_lib
from jaml.stream import collect
from jaml.stream import replay as replay_lib
from jaml.stream.executor import one_run_stacked
from jaml.stream.loop import Stream, StreamState


def encoded_replay(stream: Stream, states: StreamState, keys: jax.Array, num: int,
                   store: list | None = None):
    """(latents [R, N, Z], LD targets [R, N, D]) of N ≈ num sequences sampled from each of R
    stacked runs' replays (keys [R]), the regressor's training set: with
    `eval.validation_split` "slots" its leading rows (the regressor's held-out 30 %) come from
    other replay columns than the rest (`replay.sample_split`). `store`: a list that gets each
    chunk's sequences (host `Columns` [R, E, L]; `jaml.suite`)."""
    n = _chunks(num, stream.config.num_envs)
    chunks = jax.vmap(lambda k: jax.random.split(k, n))(keys)
    carry = None
    if stream.config.eval.validation_split == "slots":
        rows = np.arange(n * stream.config.num_envs).reshape(n, -1)
        held_out = rows < alignment.RegressorConfig().split(rows.size)
        carry = (jnp.asarray(held_out), jnp.zeros((), jnp.int32))
    return _map_chunks(stream.jit(_replay_chunk), stream, states, carry, chunks, store=store)


def encoded_rollouts(stream: Stream, states: StreamState, keys: jax.Array, num: int,
                     random: bool, fingerprints: bool = False,
                     kept: list[PiRandSet] | None = None, store: list | None = None):
    """(latents, LD targets) [R, N, ...] of sequences cut from fresh rollouts of R stacked runs
    (keys [R]): reset, `eval.transient` steps, then consecutive L-step rollouts per env
    (docs/reference/suite.md §5, start t = 0); with `fingerprints`, also each sequence's
    `input_fingerprints` [R, N, 2] (for the distortion). `kept` (π_rand only, one `PiRandSet`
    per run): the sequences are read from them when every one holds its run's key, else rolled
    out and stored in them. `store`: as `encoded_replay`'s (not with `kept`)."""
    _check_keepable(kept, random)
    if kept is not None and all(k.holds(stream, key, num)
                                for k, key in zip(kept, keys, strict=True)):
        chunks = [[k.chunks[c] for k in kept] for c in range(len(kept[0].chunks))]
        return _map_chunks(_kept_chunk, stream, states, chunks, np.arange(len(chunks))[None],
                           fingerprints)
    split = jax.vmap(jax.random.split)(keys)
    random = jnp.asarray(random)
    env_states = stream.jit(_rollout_start)(states, split[:, 0], random)
    n = _chunks(num, stream.config.num_envs)
    chunks = jax.vmap(lambda k: jax.random.split(k, n))(split[:, 1])
    store = store if kept is None else []
    out = _map_chunks(stream.jit(_rollout_chunk), stream, states, (env_states, random), chunks,
                      fingerprints, store)
    if kept is not None:
        for r, (k, key) in enumerate(zip(kept, keys, strict=True)):
            # Copies, not views of the stacked chunks: a finished run's set is then freed
            # alone while the others' stay.
            k.store(stream, key, num,
                    [jax.tree.map(lambda x, r=r: np.array(x[r]), seqs) for seqs in store])
    return out


def _check_keepable(kept, random: bool) -> None:
    if kept is not None and not random:
        raise ValueError("only the π_rand set (random=True) is the same at every analysis; "
                         "π_curr's follows the current policy and cannot be kept")


@dataclasses.dataclass(eq=False)
class PiRandSet:
    """One run's π_rand test sequences kept on the host (numpy `Columns` per chunk of
    `num_envs` sequences), so that its later analyses encode them again rather than roll them
    out again. The set is a function of the env, the run's π_rand key and its size alone (the
    policy is uniform: `Stream.test_policy` discards PPO's actions), so the reports do not
    change; only the time does (rolling out 10 048 sequences of 16 frames is 157 sequential
    16-step rollouts of 64 envs). Host memory: eval.rand × L × 12 KiB of 64×64 frames per run,
    ≈ 2 GB at the paper's eval.rand and L = 16."""

    tag: tuple | None = None  # what the chunks were rolled out for (`_tag`)
    chunks: list | None = None

    @staticmethod
    def _tag(stream: Stream, key: jax.Array, num: int) -> tuple:
        """The key's bits, the set's size and the stream settings that shape the rollouts."""
        if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
            key = jax.random.key_data(key)
        cfg = stream.config
        return (np.asarray(key).tobytes(), num, cfg.env, repr(cfg.env_config), cfg.num_envs,
                cfg.eval.transient, stream.seq_len)

    def holds(self, stream: Stream, key: jax.Array, num: int) -> bool:
        return self.chunks is not None and self.tag == self._tag(stream, key, num)

    def store(self, stream: Stream, key: jax.Array, num: int, chunks: list) -> None:
        """Keep `chunks` (host `Columns`, each owning its memory) for this key and size."""
        self.tag, self.chunks = self._tag(stream, key, num), chunks


def rotation_blocks(stream: Stream) -> tuple[tuple[int, ...], tuple[str, ...]]:
    """(starts, labels) of the LD state's rotation blocks, from the env's metadata
    (`rotation.ld_blocks`); ((), ()) for every domain but Rearrange."""
    return rotation.ld_blocks(stream.env.ld_state_names, stream.env.ld_state_groups)


def error_names(stream: Stream) -> list[str]:
    """Names of a report's error entries: the LD state's, then one per rotation block
    (objK_rotation, its mean principal-axis error)."""
    return [*stream.env.ld_state_names, *rotation_blocks(stream)[1]]


def _regressor_options(stream: Stream) -> dict:
    cfg = stream.config
    starts = rotation_blocks(stream)[0]  # with eval.regressor_normalize False (checked by `build`)
    return dict(seq_len=stream.seq_len, num_iterations=cfg.eval.regressor_iterations,
                normalize=cfg.eval.regressor_normalize, rotation_starts=starts)


def _part(seconds: dict | None, name: str, fn, *args, **kwargs):
    """fn(*args, **kwargs), its results ready, its wall time added to seconds[name] (when
    `seconds` is a dict): where an analysis spends its time, in a run's summary.json."""
    if seconds is None:
        return fn(*args, **kwargs)
    tic = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - tic
    return out


def evaluate(stream: Stream, s: StreamState, key: jax.Array, pi_rand_key: jax.Array, *,
             seconds: dict | None = None, pi_rand_set: PiRandSet | None = None,
             references: bool = False) -> dict:
    """`evaluate_runs` of one run (R = 1): its report."""
    return evaluate_runs(stream, one_run_stacked(s), key[None],
                         pi_rand_key[None], seconds=seconds,
                         pi_rand_sets=None if pi_rand_set is None else [pi_rand_set],
                         references=references)[0]


def set_names(stream: Stream) -> tuple[str, ...]:
    """The sets an analysis draws: the replay's ("train"), π_rand's and, under PPO with
    `eval.curr` > 0, π_curr's."""
    cfg = stream.config
    return ("train", "pi_rand") + (("pi_curr",) if cfg.policy == "ppo" and cfg.eval.curr > 0
                                   else ())


def evaluate_runs(stream: Stream, states: StreamState, keys: jax.Array,
                  pi_rand_keys: jax.Array, *, seconds: dict | None = None,
                  pi_rand_sets: list[PiRandSet] | None = None,
                  references: bool = False) -> list[dict]:
    """Per run of R stacked runs (keys [R] and pi_rand_keys [R] raw keys): alignment errors
    [D + J] (`error_names`) on π_rand (and π_curr under PPO), the held-out validation error,
    a latent-free constant's errors ("baseline", the same keys) and the distortion of the
    π_rand latents (exact, and trimmed of collapsed pairs), as host-side numbers, with the
    validation split used ("validation_split"). `seconds`: a dict that gets each part's wall
    time added (train_set, pi_rand, pi_curr, regressor, references), the R runs' together.
    `pi_rand_sets`: one per run, its kept π_rand sequences (read when every run's holds its
    key, else all rolled out and kept). `references`: also the reference rows on the same sets
    and regressor ("references", `reference_rows`): three more fits, so a run asks for them
    once, not at every analysis.

    On a GPU the analysis is latency bound, so one call for R runs costs about what one run
    costs: the replay samplers, the rollouts and the regressor fits are vmapped over the runs;
    the encoder is applied run by run inside one jitted call (`_encode`)."""
    cfg = stream.config
    split = jax.vmap(lambda k: jax.random.split(k, 3))(keys)
    k_train, k_curr, k_reg = split[:, 0], split[:, 1], split[:, 2]
    # With `references`, the sets' last input frames kept on the host for the pixel references.
    stored = {k: _LastInputFrames(stream.hist) for k in ("train", "pi_rand", "pi_curr")
              } if references else {}
    train = _part(seconds, "train_set", encoded_replay, stream, states, k_train, cfg.eval.train,
                  store=stored.get("train"))
    lat, st, inputs = _part(seconds, "pi_rand", encoded_rollouts, stream, states, pi_rand_keys,
                            cfg.eval.rand, random=True, fingerprints=True, kept=pi_rand_sets,
                            **({"store": stored["pi_rand"]} if references and not pi_rand_sets
                               else {}))
    tests = {"pi_rand": (lat, st)}
    if "pi_curr" in set_names(stream):
        tests["pi_curr"] = _part(seconds, "pi_curr", encoded_rollouts, stream, states, k_curr,
                                 cfg.eval.curr, random=False,
                                 **({"store": stored["pi_curr"]} if references else {}))
    seeds = np.asarray(jax.vmap(lambda k: jax.random.randint(k, (), 0, 2**31 - 1))(k_reg))
    train_states = np.asarray(train[1])
    test_states = {k: np.asarray(t) for k, (_, t) in tests.items()}
    columns = distortion_columns(stream)
    options = _regressor_options(stream)
    # What each error is read against: a latent-free constant's, in the regressor's units.
    baselines = [alignment.constant_errors(train_states[r],
                                           {k: t[r] for k, t in test_states.items()},
                                           validation=True, **options)
                 for r in range(len(seeds))]
    errors = _part(seconds, "regressor", alignment.alignment_errors_runs,
                   *train, tests, seeds=seeds.tolist(), **options)
    errors = {k: np.asarray(v) for k, v in errors.items()}
    reports = []
    for r in range(len(seeds)):
        exact, trimmed, left_out = evaluation.distortion_trimmed(lat[r], st[r][:, columns],
                                                                 inputs=inputs[r])
        reports.append({
            "errors": {k: v[r].tolist() for k, v in errors.items()},
            "baseline": {k: v.tolist() for k, v in baselines[r].items()},
            "distortion": exact,
            "distortion_trimmed": {"value": trimmed, "left_out": left_out},
            "irregularity": {"replay": irregularity(stream, train[0][r], train_states[r]),
                             "pi_rand": irregularity(stream, lat[r], st[r])},
            "validation_split": cfg.eval.validation_split,
        })
    if references:
        if pi_rand_sets:  # rolled out into the kept sets, or read from them
            for runs in zip(*(k.chunks for k in pi_rand_sets), strict=True):
                stored["pi_rand"].append(jax.tree.map(lambda *x: np.stack(x), *runs))
        rows = _part(seconds, "references", reference_rows, stream, stored["train"].pixels(),
                     train_states, {k: (stored[k].pixels(), test_states[k]) for k in tests},
                     seeds)
        for report, row in zip(reports, rows, strict=True):
            report["references"] = {"constant": report["baseline"], **row}
    return reports


@dataclasses.dataclass(frozen=True)
class RunAnalysis:
    """One run's analysis at an epoch, for its run directory (`RunDir.analysed`): its report
    (`evaluate_runs`) and the names of its errors (`error_names`), reconstructions
    (`reconstructions`), and its time: its share of the wall seconds, and by part."""

    report: dict
    names: list[str]
    frames: tuple[np.ndarray, np.ndarray]
    seconds: float
    parts: dict[str, float]


def analyse_runs(stream: Stream, states: StreamState, due: list[int], eval_keys: list,
                 pi_rand_keys: list, pi_rand_sets: list, references: list[bool]
                 ) -> list[RunAnalysis]:
    """The runs `due` (indices into the stacked `states`) analysed at their (common) epoch,
    each with its keys, its kept π_rand set (`PiRandSet`, or None) and whether it asks for the
    reference rows (`evaluate_runs`): one `RunAnalysis` per due run.

    The runs that one device holds are evaluated by one `evaluate_runs` call on that device (on
    a GPU about the cost of one run's `evaluate`: the analysis is latency bound), the time
    shared among them; with the runs split across devices that is one call per device, the
    devices taken in turn. Not one host thread per device: the analysis traces its programs as
    it goes, and a worker thread does not see the caller's JAX config contexts (e.g.
    `jax.threefry_partitionable`, which decides the random bits of the test sets and the
    regressor)."""
    shared = {}
    for device_states, members in due_by_device(states, [(i, n) for n, i in enumerate(due)]):
        tic = time.perf_counter()
        picks = [n for _, n in members]
        parts: dict[str, float] = {}
        kept = [pi_rand_sets[n] for n in picks]
        # The reference rows at a run's first analysis in this call only: three more fits.
        reports = evaluate_runs(stream, device_states, jnp.stack([eval_keys[n] for n in picks]),
                                jnp.stack([pi_rand_keys[n] for n in picks]), seconds=parts,
                                pi_rand_sets=None if None in kept else kept,
                                references=any(references[n] for n in picks))
        share = (time.perf_counter() - tic) / len(members)
        for n, report in zip(picks, reports, strict=True):
            shared[n] = report, share, {k: v / len(members) for k, v in parts.items()}
    names = error_names(stream)
    results = []
    for n, i in enumerate(due):
        report, share, parts = shared[n]
        tic = time.perf_counter()
        frames = reconstructions(stream, states, i, jax.random.fold_in(eval_keys[n], 7))
        parts["reconstructions"] = time.perf_counter() - tic
        results.append(RunAnalysis(report, names, frames, share + parts["reconstructions"],
                                   parts))
    return results


def due_by_device(states: StreamState, due: list) -> list[tuple[StreamState, list]]:
    """The runs `due` [(index into the stacked `states`, anything)] grouped by the device that
    holds them (the first, where the states are replicated): per device, its due runs' states
    stacked on it and their entries of `due`.

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


class _LastInputFrames(list):
    """A samplers' `store` that keeps of each chunk (`Columns` [R, E, L]) only its sequences'
    last input frames (`hist`), flattened: the pixel references' inputs, a 1/L of the chunk."""

    def __init__(self, hist: int):
        super().__init__()
        self.hist = hist

    def append(self, seqs) -> None:
        frames = np.asarray(seqs.frames[:, :, self.hist - 1])
        super().append(frames.reshape(*frames.shape[:2], -1))

    def pixels(self) -> np.ndarray:
        """uint8 [R, N, P]: the chunks' frames in order."""
        return np.concatenate(self, axis=1)


def reference_rows(stream: Stream, train_pixels, train_states, tests: dict, seeds) -> list[dict]:
    """Per run of R: {reference: {test set and "validation": [D + J] errors}} for
    `references.NAMES`, by the analysis's regressor with the run's seed on the run's rows:
    train_pixels uint8 [R, N, P], train_states [R, N, D], tests {name: (pixels [R, Nt, P],
    states [R, Nt, D])}, seeds [R]. The 3·R fits are one vmapped call."""
    names = references_lib.NAMES
    key = jax.random.key(0)  # the same projections for every run
    per_run = [references_lib.reference_latents(
        train_pixels[r], train_states[r], {k: (px[r], st[r]) for k, (px, st) in tests.items()},
        key) for r in range(len(seeds))]
    order = [(r, n) for r in range(len(seeds)) for n in names]
    errors = alignment.alignment_errors_runs(
        np.stack([per_run[r][n][0] for r, n in order]),
        np.stack([train_states[r] for r, _ in order]),
        {k: (np.stack([per_run[r][n][1][k] for r, n in order]),
             np.stack([tests[k][1][r] for r, _ in order])) for k in tests},
        seeds=[int(seeds[r]) for r, _ in order], **_regressor_options(stream))
    rows = [{} for _ in seeds]
    for i, (r, n) in enumerate(order):
        rows[r][n] = {k: np.asarray(v[i]).tolist() for k, v in errors.items()}
    return rows


def irregularity(stream: Stream, latents, states) -> float | None:
    """The reference code's distortion score (`evaluation.irregularity`) of one run's latents
    [N, Z] and LD states [N, D]; None where the latent is narrower than the LD state's
    continuous entries it would be read at."""
    names = stream.env.ld_state_names
    continuous = [i for i, n in enumerate(names) if not n.endswith("_id")]
    if not continuous or max(continuous) >= np.shape(latents)[-1]:
        return None
    value = evaluation.irregularity(np.asarray(latents), np.asarray(states), names)
    return None if np.isnan(value) else value


def distortion_columns(stream: Stream) -> np.ndarray:
    """Indices of the LD state's τ^true entries for the distortion (all by default)."""
    names = list(stream.env.ld_state_names)
    return np.asarray([names.index(n) for n in stream.config.eval.distortion_dims] or
                      range(len(names)))


def reconstructions(stream: Stream, states: StreamState, i: int, key: jax.Array, num: int = 8):
    """(true, decoded) last frames of `num` replay sequences of run i of the stacked `states`,
    uint8 [num, 64, 64, 3] each; a learner with boxes (SPAIR) has them drawn over the true
    frames. Only the run's replay and learner variables are taken from the stack."""
    replay, variables = jax.tree.map(lambda x: x[i], (states.replay, states.learner.variables))
    seqs = replay_lib.sample(replay, key, num, stream.seq_len)
    recon = stream.jit(_reconstruct)(variables, seqs.frames, seqs.actions)
    truth = np.asarray(seqs.frames[:, -1])
    if hasattr(stream.learner, "draw_boxes"):
        truth = stream.learner.draw_boxes(variables, truth)
    return truth, np.asarray(jnp.round(recon[:, -1] * 255)).astype(np.uint8)


def _chunks(num: int, num_envs: int) -> int:
    return max(1, math.ceil(num / num_envs))


def _map_chunks(producer, stream: Stream, states: StreamState, carry, keys,
                fingerprints: bool = False, store: list | None = None):
    """For each chunk c, `producer(states, carry, keys[:, c]) -> (carry, Columns [R, E, L])`,
    encoded; returns (latents [R, N, Z], LD targets [R, N, D]) with
    N = E · C, and with `fingerprints` the input fingerprints [R, N, 2]. `store`: a list that
    gets a host copy of each chunk.

    A host loop over one jitted producer and one jitted encoder on every backend: a scan over
    the chunks would compile the encoder once per data set (its length is static), and the
    per-chunk dispatch costs milliseconds against seconds of compilation (and XLA:CPU runs
    convolutions inside loops slowly, see `executor.run_stacked_epochs`)."""
    outs = []
    for c in range(keys.shape[1]):
        carry, seqs = producer(states, carry, keys[:, c])
        outs.append(stream.jit(_encode, static_argnums=2)(states.learner.variables, seqs,
                                                          fingerprints))
        if store is not None:
            store.append(jax.device_get(seqs))
    return tuple(jnp.concatenate(x, axis=1) for x in zip(*outs, strict=True))


def _kept_chunk(states, chunks: list, c):
    """A producer over kept chunks: carry the chunks ([chunk][run] host columns), key [1] the
    chunk's index; the runs' columns stacked [R, E, L] on the device."""
    runs = chunks[int(c[0])]
    return chunks, jax.device_put(jax.tree.map(lambda *x: np.stack(x), *runs))


# The programs below are jitted by the Stream (`Stream.jit`), which keeps them: a `jax.jit` made
# per call would recompile at every analysis.
def _reconstruct(stream: Stream, variables, frames, actions):
    return stream.learner.reconstruct(variables, frames, actions)


def input_fingerprints(hist: int, frames, actions, actions_seen: int | None = None) -> jax.Array:
    """uint32 [..., B, 2]: two hashes of what an encoder reads of each sequence (frames
    [..., B, T, H, W, C] uint8, actions [..., B, T, A]): its first `hist` frames and its first
    `actions_seen` actions (default hist − 1; `LearnerConfig.actions_seen`).

    Equal inputs give equal fingerprints; different ones collide with probability ≈ 2⁻⁶⁴ (two
    random linear hashes mod 2³²). The distortion skips pairs with equal fingerprints: states a
    fraction of a pixel apart render the same frame, which no encoder can tell apart."""
    seen_count = hist - 1 if actions_seen is None else actions_seen
    lead = frames.shape[:-4]
    words = [frames[..., :hist, :, :, :].reshape(*lead, -1).astype(jnp.uint32)]
    if seen_count > 0:
        seen = actions[..., :seen_count, :].astype(jnp.float32)
        words.append(jax.lax.bitcast_convert_type(seen, jnp.uint32).reshape(*lead, -1))
    words = jnp.concatenate(words, axis=-1)
    weights = jax.random.bits(jax.random.key(0), (2, words.shape[-1]), jnp.uint32) | 1
    return jnp.stack([jnp.sum(words * w, axis=-1, dtype=jnp.uint32) for w in weights], axis=-1)


def _encode(stream: Stream, variables, seqs: replay_lib.Columns, fingerprints: bool = False):
    """(latents [R, E, Z], LD targets [R, E, D]) of R stacked runs' sequences ([R, E, ...], per
    run variables), and with `fingerprints` [R, E, 2]: the encoder applied run by run in one
    program, one run per iteration of a `lax.map`.

    Not vmapped: vmapping a convolution over per-run weights turns it into one grouped
    convolution, which GPU libraries run far slower than R ordinary ones (see
    `Stream.learn_runs`), and it would change each run's float rounding. Not unrolled in
    Python either: R copies of the encoder compile several times slower, for the same latents
    (docs/notes/stream.md, "The analysis' encoder")."""
    z = jax.lax.map(lambda run: stream.learner.encode(*run),
                    (variables, seqs.frames, seqs.actions))
    out = (z, seqs.ld[:, :, stream.hist - 1])
    if fingerprints:
        out += (input_fingerprints(stream.hist, seqs.frames, seqs.actions,
                                   stream.learner.config.actions_seen),)
    return out


def _replay_chunk(stream: Stream, states: StreamState, carry, keys):
    """One replay sample of `num_envs` sequences per run (keys [R]). carry None (the leading
    split: every row from every column), or (held-out rows [C, E], chunk index c): row e of
    chunk c from the held-out columns where marked, else from the others; c advances."""
    if carry is None:
        def one(s, key):
            return replay_lib.sample(s.replay, key, stream.config.num_envs, stream.seq_len)

        return carry, jax.vmap(one)(states, keys)
    held_out, c = carry
    fraction = alignment.RegressorConfig().validation_fraction

    def split(s, key):
        return replay_lib.sample_split(s.replay, key, held_out[c], stream.seq_len, fraction)

    return (held_out, c + 1), jax.vmap(split)(states, keys)


def _rollout_chunk(stream: Stream, states: StreamState, carry, keys):
    """carry (env states [R, E], one traced π_rand flag) → L steps, one test sequence per env
    and run (keys [R])."""
    env_states, random = carry
    L = stream.seq_len

    def one(s, env_state, key):
        env_state, _, columns, _ = collect.rollout(stream.env, env_state,
                                                   stream.test_policy(s.ppo, random), key, L)
        return env_state, jax.vmap(replay_lib.window, (0, None, None))(columns, 0, L)

    env_states, seqs = jax.vmap(one)(states, env_states, keys)
    return (env_states, random), seqs


def _rollout_start(stream: Stream, states: StreamState, keys: jax.Array,
                   random: jax.Array) -> State:
    """The R runs' envs reset and past their `eval.transient` steps (keys [R])."""
    return jax.vmap(lambda s, k: _rollout_start_one(stream, s, k, random))(states, keys)


def _rollout_start_one(stream: Stream, s: StreamState, key: jax.Array, random) -> State:
    k_reset, k_transient = jax.random.split(key)
    env_state = collect.reset(stream.env, k_reset, stream.config.num_envs)
    if stream.config.eval.transient:
        # The transient's frames and transitions are unused (dropped from the program).
        env_state = collect.rollout(stream.env, env_state, stream.test_policy(s.ppo, random),
                                    k_transient, stream.config.eval.transient)[0]
    return env_state
