"""The authors' own PyTorch AML (github MaksimIM/aml at 300a446, unchanged) run as a peer: one
fit in this process, its relations exported to .npz and evaluated in JAX on jaml's τ order.

Their training code runs as it is. Patched around it, and nothing else: the data RNG (their
`numpy.random.default_rng()` is unseeded; here it is seeded from the torch seed), the I/O
(`tensorboardX` replaced by a stand-in writing scalars to CSV, `sys.argv` for their argument
parser, stdout to a file), a wall-clock budget checked where a batch is drawn (their data
source) and before a relation is added, and observers (their `AML` subclassed only to keep a
handle on it, `learn_g` / `learn_syz` / `log_info` wrapped to time and label each phase). A run
cut by the budget keeps what was learned: the relations finished and the one in training,
flagged "cut".

    python benchmarks/peers/aml_reference.py --source Ellipse --seed 0 --max-relations 2 \\
        --budget-s 60 --out runs/aml_reference/ellipse-2-s0

`--source rows:FILE` trains on a .npy file of rows [N, D] (jaml's τ order, kept as it is)
behind their data-source interface (`rows_source`): each batch drawn from the rows with their
data RNG, its off-manifold rows made as their own sources make them.

The checkout: `--checkout`, else $JAML_AML_REFERENCE, else `.aml_reference` at the repository
root (git-ignored; see `MISSING`).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import importlib
import json
import math
import os
import sys
import tempfile
import time
import types
from collections.abc import Callable
from pathlib import Path

import numpy as np

COMMIT = "300a446"
CHECKOUT_ENV = "JAML_AML_REFERENCE"
DEFAULT_CHECKOUT = Path(__file__).resolve().parents[2] / ".aml_reference"
MISSING = (
    "the authors' AML code is not at {path}: fetch github:MaksimIM/aml and run `git --git-dir="
    "<its git dir> archive 300a446 | tar -x -C {path}` (or set $JAML_AML_REFERENCE to a "
    "folder holding it)"
)
SOURCES = ("Ellipse", "ConservativeBlock45Incline1D")  # theirs; or "rows:FILE" (`rows_source`)
ROWS = "rows:"
# τ order. Their block rows are state-major (s0, s1, v0, v1) (docs/reference/aml.md §6), jaml's are
# time-major (s0, v0, s1, v1): reference τ = jaml τ[..., JAML_TO_REFERENCE[source]].
JAML_TO_REFERENCE = {"Ellipse": (0, 1, 2), "ConservativeBlock45Incline1D": (0, 2, 1, 3)}
DATA_STREAM = 0x616D6C  # the data RNG's seed is (torch seed, this): not the torch stream


def find_checkout(path=None) -> Path:
    """The folder holding the authors' `aml/` package (argument, $JAML_AML_REFERENCE, default)."""
    path = Path(path or os.environ.get(CHECKOUT_ENV) or DEFAULT_CHECKOUT).resolve()
    if not (path / "aml" / "aml_main.py").is_file():
        raise FileNotFoundError(MISSING.format(path=path))
    return path


def data_seed(seed: int) -> np.random.SeedSequence:
    return np.random.SeedSequence([int(seed), DATA_STREAM])


class _ScalarWriter:
    """The stand-in for tensorboardX.SummaryWriter: scalars to `scalars.csv`, the rest dropped
    (aml_main only logs through add_scalar and add_text; figures only with visualization on)."""

    def __init__(self, logdir=None, *args, **kwargs):
        self._file = None
        if logdir is not None:
            self._file = open(Path(logdir) / "scalars.csv", "w", newline="")  # noqa: SIM115
            self._csv = csv.writer(self._file)
            self._csv.writerow(["step", "tag", "value"])

    def add_scalar(self, tag, value, step=None, *args, **kwargs):
        if self._file is not None:
            value = value.detach() if hasattr(value, "detach") else value
            self._csv.writerow([step, tag, float(value)])

    def __getattr__(self, name):  # add_text, add_figure, add_image, flush, ...
        if name.startswith("add_") or name == "flush":
            return lambda *args, **kwargs: None
        raise AttributeError(name)

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = None


def _tensorboard_stub() -> types.ModuleType:
    module = types.ModuleType("tensorboardX")
    module.SummaryWriter = _ScalarWriter
    module.__doc__ = "Stand-in for tensorboardX (benchmarks/peers/aml_reference.py)."
    return module


def load_reference(seed: int, checkout=None) -> types.ModuleType:
    """Import their `aml.aml_main` with the stand-in tensorboardX and their module-level data RNG
    (`aml.data_sources.rng = default_rng()`) seeded from `seed`. Importing again re-seeds it."""
    path = find_checkout(checkout)
    os.environ.setdefault("MPLBACKEND", "Agg")  # their aml_visualize imports pyplot
    loaded = sys.modules.get("aml")
    if loaded is not None and Path(loaded.__path__[0]).resolve() != path / "aml":
        raise RuntimeError(f"another `aml` package is imported already: {loaded.__path__[0]}")
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))
    real = np.random.default_rng
    seeded = data_seed(seed)

    def default_rng(seed=None):
        return real(seeded if seed is None else seed)

    np.random.default_rng = default_rng  # their `from numpy.random import default_rng` takes it
    # Ours even where the real tensorboardX exists; only while aml_main imports it by name.
    tensorboard = sys.modules.get("tensorboardX")
    sys.modules["tensorboardX"] = _tensorboard_stub()
    try:
        if "aml.data_sources" in sys.modules:
            importlib.reload(sys.modules["aml.data_sources"])
        else:
            importlib.import_module("aml.data_sources")
        return importlib.import_module("aml.aml_main")
    finally:
        np.random.default_rng = real
        if tensorboard is None:
            del sys.modules["tensorboardX"]
        else:
            sys.modules["tensorboardX"] = tensorboard


def reference_batch(source: str, seed: int, n: int, on_manifold=True, noise_scale=0.0,
                    checkout=None) -> np.ndarray:
    """[n, D] rows drawn by their data source (its order), the data RNG seeded from `seed`."""
    main = load_reference(seed, checkout)
    data = main.data_sources[source](n, "cpu")
    return data.get_batch(n, "cpu", on_manifold=on_manifold, noise_scale=noise_scale).numpy()


def rows_source(main: types.ModuleType, path) -> type:
    """A DataSource of their interface over the rows of a .npy file: `get_batch` draws rows with
    replacement by their data RNG and hands them to their `process_data`, which makes the
    off-manifold rows (uniform in the batch's own box, as for every source of theirs) and adds
    their noise. Their code subclasses nothing of it; `train` only calls `get_batch`."""
    data_sources = sys.modules[main.__name__.rpartition(".")[0] + ".data_sources"]
    rows = np.load(path).astype(np.float64)
    if rows.ndim != 2 or not np.isfinite(rows).all():
        raise ValueError(f"{path}: rows must be a finite [N, D] array, got shape {rows.shape}")

    class Rows(data_sources.DataSource):
        def _dim_names(self):
            return [f"x{i}" for i in range(rows.shape[1])]

        def get_batch(self, batch_size=None, device=None, on_manifold=True, noise_scale=0.0):
            picked = rows[data_sources.rng.integers(0, len(rows), batch_size or self.batch_size)]
            return data_sources.process_data(picked, on_manifold, noise_scale,
                                             device or self.device)

    return Rows


def _order(source: str) -> tuple[int, ...]:
    """Their τ order as indices of jaml's (identity for a file of rows)."""
    if source.startswith(ROWS):
        return tuple(range(np.load(source[len(ROWS):], mmap_mode="r").shape[1]))
    return JAML_TO_REFERENCE[source]


def to_jaml_order(rows: np.ndarray, source: str) -> np.ndarray:
    """Their rows [..., D] in jaml's coordinate order."""
    inverse = np.argsort(_order(source))
    return np.asarray(rows)[..., inverse]


class _OutOfTime(Exception):
    """The wall-clock budget is spent (raised where a batch is drawn or a relation is added)."""


@dataclasses.dataclass
class _Clock:
    budget_s: float | None

    def __post_init__(self):
        self.start = time.perf_counter()
        self.deadline = self.start + (math.inf if self.budget_s is None else self.budget_s)

    def check(self):
        if time.perf_counter() > self.deadline:
            raise _OutOfTime


def _adam_steps(optim) -> int:
    steps = [int(state["step"]) for state in optim.state.values() if "step" in state]
    return max(steps, default=0)


@contextlib.contextmanager
def _patched(target, name: str, value):
    old = getattr(target, name)
    setattr(target, name, value)
    try:
        yield
    finally:
        setattr(target, name, old)


def fit(source: str = "Ellipse", seed: int = 0, max_relations: int = 2, max_syzygies: int = 0,
        noise_scale: float = 0.0, budget_s: float | None = None, out=None, checkout=None,
        extra_args=(), quiet: bool = True) -> dict:
    """One reference fit (their `aml_main.train`, CPU, one thread) under a wall-clock budget.

    Writes into `out`: their run folder (log.txt, checkpoints, scalars.csv), `relations.npz`
    (`export`), `reference_stdout.txt` (their prints, when quiet). Returns a JSON-ready summary:
    per relation its steps, status ("done": their stopping rule; "capped": the step budget;
    "cut": the wall-clock budget ended it; "error": their code raised, `train_error` says what),
    their EMA on/off means, wall seconds and phases.
    """
    if source not in SOURCES and not source.startswith(ROWS):
        raise ValueError(f"source must be one of {SOURCES} or {ROWS}FILE, got {source!r}")
    os.environ["OMP_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)
    main = load_reference(seed, checkout)
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="aml-reference-"))
    out.mkdir(parents=True, exist_ok=True)
    # Their parser takes only their sources' names; for a file of rows the name only names
    # their run folder.
    named = "Ellipse" if source.startswith(ROWS) else source
    argv = ["--data_source", named, "--seed", str(seed), "--max_relations", str(max_relations),
            "--max_syzygies", str(max_syzygies), "--noise_scale", repr(float(noise_scale)),
            "--device", "cpu", "--save_path_prefix", str(out), *extra_args]
    with _patched(sys, "argv", ["aml_main", *argv]):
        args = main.get_all_args()

    clock = _Clock(budget_s)
    records: list[dict] = []
    handle: dict = {}

    def close_relation():
        if records and "seconds" not in records[-1]:
            records[-1]["seconds"] = time.perf_counter() - records[-1].pop("_started")

    class Observed(main.AML):
        """Their AML, unchanged: kept hold of, and no relation is added once time is up."""

        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            handle["aml"] = self

        def add_g(self, *a, **kw):
            clock.check()
            close_relation()
            result = super().add_g(*a, **kw)
            records.append({"index": len(records) + 1, "_started": time.perf_counter(),
                            "phases": [], "syzygy_rounds": []})
            return result

    original_learn_g, original_learn_syz, original_log = main.learn_g, main.learn_syz, main.log_info

    def learn_g(aml, data_source, args, epoch, tot_epoch, g_max_train_epochs, *rest):
        phase = {"kind": "g" if not records[-1]["phases"] else "push",
                 "max_steps": int(g_max_train_epochs), "ended": "running",
                 "_from": _adam_steps(aml.new_g_optim)}
        records[-1]["phases"].append(phase)
        result = original_learn_g(aml, data_source, args, epoch, tot_epoch, g_max_train_epochs,
                                  *rest)
        phase["ended"] = "done" if phase.pop("_done", False) else "capped"
        return result

    def learn_syz(syz_i, aml, *rest):
        round_ = {"ended": "running"}
        records[-1]["syzygy_rounds"].append(round_)
        holds, noise, _ = result = original_learn_syz(syz_i, aml, *rest)
        round_.update(ended="returned", holds=bool(holds), thickening=float(noise),
                      steps=_adam_steps(aml.syz_optim))
        return result

    def log_info(logfile, data):
        original_log(logfile, data)
        if isinstance(data, str) and data.startswith("learn_g done") and records:
            records[-1]["phases"][-1]["_done"] = True

    base = (rows_source(main, source[len(ROWS):]) if source.startswith(ROWS)
            else main.data_sources[source])

    def get_batch(self, *a, **kw):
        clock.check()
        return base.get_batch(self, *a, **kw)

    budgeted = type(base.__name__, (base,), {"get_batch": get_batch, "__module__": base.__module__})

    stdout = open(out / "reference_stdout.txt", "w") if quiet else None  # noqa: SIM115
    finished, error = False, None
    with contextlib.ExitStack() as stack:
        if stdout is not None:
            stack.enter_context(stdout)
            stack.enter_context(contextlib.redirect_stdout(stdout))
        for name, value in (("AML", Observed), ("learn_g", learn_g), ("learn_syz", learn_syz),
                            ("log_info", log_info)):
            stack.enter_context(_patched(main, name, value))
        main.torch_setup(args)  # torch.manual_seed(seed); device cpu
        writer, logfile = main.set_loggers(args)
        stack.callback(logfile.close)
        stack.callback(writer.close)
        try:
            main.train(budgeted, args, (writer, logfile))
            finished = True
        except _OutOfTime:
            main.log_info(logfile, f"wall-clock budget of {budget_s} s spent: stopped")
        except Exception as e:  # their code failing is an outcome: keep what it learned
            error = f"{type(e).__name__}: {e}"
            main.log_info(logfile, f"stopped by an error: {error}")
    close_relation()
    wall = time.perf_counter() - clock.start

    aml = handle.get("aml")
    nets, optims = [], []
    if aml is not None and aml.new_g_nn is not None:
        nets, optims = [*aml.gj_nns, aml.new_g_nn], [*aml.gj_optims, aml.new_g_optim]
    if error is not None:  # raised inside add_g: its network may have no record
        nets, optims = nets[:len(records)], optims[:len(records)]
    assert len(nets) == len(records), (len(nets), len(records))
    for rec, net, optim in zip(records, nets, optims, strict=True):
        rec["width"] = int(net.nn[0].out_features)
        rec["steps"] = _adam_steps(optim)
        starts = [phase.pop("_from") for phase in rec["phases"]]
        for phase, begin, end in zip(rec["phases"], starts, [*starts[1:], rec["steps"]],
                                     strict=True):
            phase["steps"] = end - begin
            phase.pop("_done", None)
        stopped = "error" if error else "cut"
        for part in rec["phases"] + rec["syzygy_rounds"]:
            part["ended"] = stopped if part["ended"] == "running" else part["ended"]
        cut = any(p["ended"] == stopped for p in rec["phases"] + rec["syzygy_rounds"])
        rec["status"] = stopped if cut else rec["phases"][-1]["ended"]
        rec["on_mean"], rec["off_mean"] = float(net.on_mean[0]), float(net.off_mean[0])
        rec["off_on"] = rec["off_mean"] / max(rec["on_mean"], 1e-30)
    export(nets, records, out / "relations.npz", source)

    return {
        "stack": "reference",
        "commit": COMMIT,
        "source": source,
        "seed": seed,
        "max_relations": max_relations,
        "max_syzygies": max_syzygies,
        "noise_scale": noise_scale,
        "budget_s": budget_s,
        "finished": finished,
        "cut": not finished and error is None,
        "train_error": error,
        "wall_s": wall,
        "steps": sum(r["steps"] for r in records),
        "relations": records,
        "npz": str(out / "relations.npz"),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
    }


def export(nets, records: list[dict], path, source: str) -> Path:
    """Their relation networks to .npz: g{k}_w{l} [out, in] (PyTorch's Linear layout) and
    g{k}_b{l} [out] for the Linear layers in order (tanh after each, the output's too), and
    per relation its EMA on/off means, width, steps and status."""
    import torch

    arrays = {}
    for k, net in enumerate(nets, 1):
        linears = [m for m in net.nn if isinstance(m, torch.nn.Linear)]
        for layer, lin in enumerate(linears):
            arrays[f"g{k}_w{layer}"] = lin.weight.detach().cpu().numpy().astype(np.float32)
            arrays[f"g{k}_b{layer}"] = lin.bias.detach().cpu().numpy().astype(np.float32)
    arrays["num_relations"] = np.asarray(len(nets))
    arrays["on_means"] = np.asarray([r["on_mean"] for r in records], np.float32)
    arrays["off_means"] = np.asarray([r["off_mean"] for r in records], np.float32)
    arrays["widths"] = np.asarray([r["width"] for r in records], np.int64)
    arrays["steps"] = np.asarray([r["steps"] for r in records], np.int64)
    arrays["status"] = np.asarray([r["status"] for r in records], str)
    arrays["jaml_to_reference"] = np.asarray(_order(source), np.int64)
    arrays["source"] = np.asarray(source)
    arrays["commit"] = np.asarray(COMMIT)
    np.savez(path, **arrays)
    return Path(path)


def _layers(data) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    out = []
    for k in range(1, int(data["num_relations"]) + 1):
        layers, layer = [], 0
        while f"g{k}_w{layer}" in data:
            layers.append((data[f"g{k}_w{layer}"], data[f"g{k}_b{layer}"]))
            layer += 1
        out.append(layers)
    return out


def load_relations(path, normalize: bool = False) -> Callable:
    """The exported relations as a JAX function τ [..., D] → [..., K], τ in jaml's coordinate
    order (for the block (s0, v0, s1, v1); permuted inside to their (s0, s1, v0, v1)). Each g_k
    is D → h → h → h → 1 with tanh after every layer, the output's included. `normalize`
    divides g_k by its EMA on-manifold mean (the units `relations.project` measures a
    RelationSet in)."""
    import jax.numpy as jnp

    with np.load(path) as data:
        layers = [[(jnp.asarray(w), jnp.asarray(b)) for w, b in rel] for rel in _layers(data)]
        perm = jnp.asarray(data["jaml_to_reference"])
        on = np.asarray(data["on_means"], np.float32)
    scale = jnp.asarray(1.0 / np.maximum(on, 1e-30) if normalize else np.ones_like(on))

    def relations(tau):
        h0 = jnp.asarray(tau)[..., perm]
        outs = []
        for rel in layers:
            h = h0
            for w, b in rel:
                h = jnp.tanh(h @ w.T + b)
            outs.append(h[..., 0])
        return jnp.stack(outs, axis=-1) * scale

    return relations


def relation_set(path, bounds=None, tolerance: float = 1.5):
    """The exported relations as a jaml `RelationSet` on jaml's τ order (the first layer's
    columns permuted), on/off means their EMA ones; `bounds` = (low, high): the data box, where
    the RelationSet records one (`project`'s trust region). Tolerance 1.5: their figures' filter
    (|g| < 1.5 × on-manifold mean)."""
    from jaml.relations.relation_set import RelationSet

    with np.load(path) as data:
        rels = _layers(data)
        perm = np.asarray(data["jaml_to_reference"])
        on, off = np.asarray(data["on_means"]), np.asarray(data["off_means"])
    dim, depth = len(perm), len(rels[0]) - 1 if rels else 3
    rs = RelationSet.empty(dim, depth, tolerance)
    if bounds is not None and "low" in {f.name for f in dataclasses.fields(RelationSet)}:
        low, high = (tuple(float(x) for x in np.asarray(b)) for b in bounds)
        rs = rs.replace(low=low, high=high)
    for k, rel in enumerate(rels):
        params = {}
        for layer, (w, b) in enumerate(rel):
            if layer == 0:
                w_jaml = np.empty_like(w)
                w_jaml[:, perm] = w  # W τ_ref = W[:, i] τ_jaml[perm[i]]
                w = w_jaml
            name = f"hidden{layer}" if layer < len(rel) - 1 else "out"
            params[f"{name}_kernel"], params[f"{name}_bias"] = w, b[:, None]
        rs = rs.append({"params": params}, float(on[k]), float(off[k]), int(rel[0][0].shape[0]))
    return rs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description="One fit of the authors' PyTorch AML (MaksimIM/aml 300a446).")
    parser.add_argument("--source", default="Ellipse",
                        help=f"one of {', '.join(SOURCES)}, or {ROWS}FILE (a .npy of rows)")
    parser.add_argument("--seed", type=int, default=0, help="torch seed (data RNG seeded from it)")
    parser.add_argument("--max-relations", type=int, default=2)
    parser.add_argument("--max-syzygies", type=int, default=0, help="0: transversality")
    parser.add_argument("--noise", type=float, default=0.0, help="their --noise_scale")
    parser.add_argument("--budget-s", type=float, default=None, help="wall-clock budget")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--checkout", type=Path, default=None)
    parser.add_argument("--verbose", action="store_true", help="their prints to stdout")
    args = parser.parse_args(argv)
    try:
        summary = fit(args.source, args.seed, args.max_relations, args.max_syzygies, args.noise,
                      args.budget_s, args.out, args.checkout, quiet=not args.verbose)
    except FileNotFoundError as e:
        print(e, file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
