"""AML's own figures (paper Fig. 5, Fig. 7, App. B.3.3): learn each row's relations, draw them.

Each row is a `jaml.relations.run` directory under OUT (resumable); figures are drawn from the
checkpoints, so `--draw-only` redraws without training.

    python -m jaml.experiments.aml_figures --out runs/aml_figures
    python -m jaml.experiments.aml_figures --out runs/aml_figures --rows fig5_top --draw-only
    python -m jaml.experiments.aml_figures --out runs/aml_figures --rows fig5_top --seeds 8
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np
from scipy.spatial import cKDTree

from jaml import sources
from jaml.relations import Config, codimension, load, project
from jaml.relations.quality import coverage
from jaml.relations.run import draw_figures, run

ROW_NAMES = ("fig5_top", "fig5_middle", "fig5_bottom", "fig5_bottom_syzygy_mode", "fig7_top",
             "fig7_middle", "fig7_bottom", "fig7_bottom_theta", "figB_syzygy")
# More than two relations, and syzygy rounds, are capped lower than the default 50 000 steps
# so that every row trains on a 2-core CPU in minutes; the paper states no budget.
_CAPPED = {"max_steps": 20_000}
# The paper's syzygy rows: restricted syzygies from g_2 on.
_SYZYGY = {"independence": "syzygy", "transversal_first": False, "syzygies_per_relation": 2,
           "syzygy_max_steps": 5_000, **_CAPPED}

# name -> (training source, Config overrides, source options of the drawn slice or None)
ROWS: dict[str, tuple[str, dict, dict | None]] = {
    "fig5_top": ("ellipse", {"max_relations": 2}, None),
    "fig5_middle": ("ellipse", {"max_relations": 4, **_CAPPED}, None),
    "fig5_bottom": ("ellipse", {"max_relations": 3, **_SYZYGY}, None),
    # The same ask at syzygy mode's defaults: transversality up to the data's codimension,
    # restricted syzygies beyond it (the paper's order leaves the relations tangent).
    "fig5_bottom_syzygy_mode": ("ellipse", {"max_relations": 3, "independence": "syzygy"}, None),
    "fig7_top": ("block45", {"max_relations": 3, **_CAPPED}, None),
    "fig7_middle": ("block35-friction", {"max_relations": 3, **_CAPPED}, None),
    # Trained over inclines in [π/20, π/2.5] (the angle is not in τ); drawn at 10°.
    "fig7_bottom": ("block-drag-range", {"max_relations": 2, **_CAPPED},
                    {"incline": math.radians(10.0)}),
    # The same with θ in τ (its last entry), drawn at θ = 10°.
    "fig7_bottom_theta": ("block-drag-range-theta", {"max_relations": 3, **_CAPPED},
                          {"incline": math.radians(10.0)}),
    "figB_syzygy": ("block45", {"max_relations": 3, **_SYZYGY}, None),
}


def train(name: str, out: Path, seed: int = 0, folder: str | None = None) -> dict:
    """Learn row `name`'s relations into out/name (or out/folder); returns its summary (with
    wall seconds)."""
    source, overrides, _ = ROWS[name]
    started = time.perf_counter()
    summary = run(source, Config(seed=seed, **overrides), out / (folder or name), progress=False,
                  figures=False)
    summary["wall_seconds"] = time.perf_counter() - started
    return summary


def _note(name: str, summary: dict, codim: dict) -> str:
    """The caption's last line: the row, how each relation ended, and the rank check."""
    source, overrides, slice_options = ROWS[name]
    ends = ", ".join(f"g{r['index']} {r['status']} ({r['steps']} steps, off/on {r['ratio']:.1f}×)"
                     for r in summary["relations"])
    drawn = ""
    if slice_options:
        drawn = f" Drawn at θ = {math.degrees(slice_options['incline']):.0f}°."
    return (f"Row {name}: source {source}, {overrides}.{drawn} Relations: {ends}. Rank of the "
            f"K×D Jacobian on {codim['points']} training rows: full (K = {codim['relations']}) at "
            f"{100 * codim['full_rank_fraction']:.0f}% of them (σ_K/σ_1 > {codim['rtol']:g}).")


def draw(name: str, out: Path) -> list[Path]:
    """Redraw row `name`'s figure from its checkpoint (`jaml.relations.run.draw_figures`) and
    write the rank check of its relations on fresh training rows to codimension.json."""
    source, _, slice_options = ROWS[name]
    rs = load(out / name / "checkpoint")
    rows = sources.make(source).sample(jax.random.key(1), 2048)
    codim = codimension(rs, rows)
    (out / name / "codimension.json").write_text(json.dumps(codim, indent=1))
    summary = json.loads((out / name / "summary.json").read_text())
    drawn = sources.make(source, **(slice_options or {}))
    return draw_figures(rs, drawn, out / name, note=_note(name, summary, codim))


def draw_seeds(name: str, out: Path, seeds: list[int]) -> Path:
    """One panel per seed of row `name` (trained into out/name_s{seed}): 1,024 uniform box points
    moved onto the learned manifold by `relations.project` at its defaults, coloured by their
    distance to the data, with the share that land within 0.05 of it and the share of the data
    they reach (`quality.coverage`; both also written per seed to out/name_seeds.json)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    source = sources.make(ROWS[name][0])
    dense = np.asarray(source.sample(jax.random.key(99), 200_000))
    low, high = dense.min(0), dense.max(0)
    tree = cKDTree(dense)
    cols = min(len(seeds), 4)
    rows = -(-len(seeds) // cols)
    fig = plt.figure(figsize=(3.2 * cols, 3.2 * rows))
    landed = []
    for i, seed in enumerate(seeds):
        rs = load(out / f"{name}_s{seed}" / "checkpoint")
        box = np.random.default_rng(seed).uniform(low, high, (1024, dense.shape[1]))
        points = np.asarray(project(rs, box.astype(np.float32)).points)
        distance = tree.query(points)[0]
        near = distance < 0.05
        reach = coverage(points[near], dense, 0.05, len(box))
        landed.append({"seed": seed, "relations": rs.num_relations, "landed": float(near.mean()),
                       **reach})
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        ax.scatter(*dense[::400].T, s=1, c="0.6")
        ax.scatter(*points[near].T, s=2, c="tab:green")
        ax.scatter(*points[~near].T, s=4, c="tab:red")
        ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(low[2], high[2]),
               xticks=[], yticks=[], zticks=[])
        ax.set_title(f"seed {seed}, {rs.num_relations} relations: {100 * near.mean():.0f}% "
                     f"within 0.05,\nreaching {100 * reach['coverage']:.0f}% of the data",
                     fontsize=9)
    fig.suptitle(f"{name}: box points projected onto the learned manifold (red: farther than "
                 "0.05 from the data)", fontsize=9)
    fig.tight_layout()
    path = out / f"{name}_seeds.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    (out / f"{name}_seeds.json").write_text(json.dumps(landed, indent=1))
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/aml_figures"))
    parser.add_argument("--rows", nargs="*", default=list(ROW_NAMES), choices=ROW_NAMES)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--draw-only", action="store_true")
    parser.add_argument("--seeds", type=int, default=0,
                        help="train seeds 0..N-1 of each row into OUT/ROW_sSEED and draw them "
                             "side by side (3-D rows)")
    args = parser.parse_args(argv)
    if args.seeds:
        for name in args.rows:
            for seed in range(args.seeds):
                if not args.draw_only:
                    train(name, args.out, seed, f"{name}_s{seed}")
            print(name, draw_seeds(name, args.out, list(range(args.seeds))), flush=True)
        return 0
    for name in args.rows:
        if not args.draw_only:
            summary = train(name, args.out, args.seed)
            print(name, json.dumps({k: summary[k] for k in ("status", "num_relations",
                                                            "wall_seconds")}), flush=True)
        print(name, [str(p) for p in draw(name, args.out)], flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
