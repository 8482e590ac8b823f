"""Paper Fig. 2 at a reduced scale: alignment of each learner's latents with the true state.

Runs `jaml.stream.run` for every (env, learner, seed) into OUT/ENV/LEARNER/seed_N (each run
resumable), then writes OUT/fig2.md (final per-dimension errors on π_rand and π_curr, with
means per LD group: position, velocity, contacts, from the domains' metadata; over several
seeds the mean and its 90 % confidence interval, as the paper's Fig. 2 shows over 6 runs)
and OUT/ENV_alignment.png (all learners' curves, bands over seeds; one panel per group for
locomotion). The paper's findings it checks:
  (a) VAE_rpl aligns better than VAE_v0 on π_rand (the replay keeps early, diverse frames);
  (b) PRED and the sequential learners (SVAE, DSA) align velocities better than the VAE, which
      sees one frame and cannot tell velocity.

    python -m jaml.experiments.fig2 --out runs/fig2 --seeds 0 1 2     # GPU-sized defaults
    python -m jaml.experiments.fig2 --out runs/fig2 --report-only     # tables from finished runs
    python -m jaml.experiments.fig2 --out runs/ref --learner-opt frame_nll=mean   # reference loss
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from jaml.evaluation import plots
from jaml.experiments._runs import add_scale_options, apply_scale, cell, read_history

LEARNERS = ("VAE_v0", "VAE_rpl", "PRED", "SVAE", "DSA")
ENVS = ("CartPole", "InvertedPendulum")
# Reduced scale: 1/5 of the reference replay, 200 learner epochs instead of tens of thousands,
# regressor sets of a few thousand sequences instead of 10 000.
SCALE = dict(num_envs=64, replay_slots=1024, epochs=216, eval_every=50, eval_train=4096,
             eval_rand=2048, eval_curr=1024, regressor_iterations=4000)


def ld_groups(env: str) -> dict[str, list[str]]:
    """group → LD-state names of `env`, from the domain's own metadata (`ld_state_groups`):
    the paper aggregates position, velocity and contacts (Fig. 2, locomotion)."""
    import envs_mjx

    domain = envs_mjx.make(env)
    groups: dict[str, list[str]] = {}
    for name, group in zip(domain.ld_state_names, domain.ld_state_groups, strict=True):
        if group != "other":
            groups.setdefault(group, []).append(name)
    return groups


def final_errors(history: list[dict]) -> dict[str, dict[str, float]]:
    """test set → {dim: error} at the last analysed step of one run."""
    last = max(r["step"] for r in history)
    return {r["test_set"]: r["errors"] for r in history if r["step"] == last}


def report(out: Path, envs, learners) -> str:
    """fig2.md from every finished seed_N run under OUT/ENV/LEARNER; returns its text."""
    lines = ["# Fig. 2 at reduced scale: alignment error (training-std units; lower is better)",
             "", "Several seeds: mean ± the half-width of its 90 % confidence interval.", ""]
    for env in envs:
        runs = {}  # learner → [history per seed]
        for learner in learners:
            seed_dirs = sorted((out / env / learner).glob("seed_*"))
            histories = [h for h in (read_history(d / "history.jsonl") for d in seed_dirs) if h]
            if histories:
                runs[learner] = histories
        if not runs:
            continue
        first = next(iter(runs.values()))[0]
        names = list(first[0]["errors"])
        config_path = next((out / env / next(iter(runs))).glob("seed_*/config.json"))
        config = json.loads(config_path.read_text())
        settings = {k: config[k] for k in SCALE}
        groups = ld_groups(env)
        lines += [f"## {env}", "", f"Settings: {json.dumps(settings)}", "",
                  "| learner | test set | " + " | ".join(names) + " | "
                  + " | ".join(f"{g} mean" for g in groups) + " | epoch | seeds |",
                  "|---" * (len(names) + len(groups) + 4) + "|"]
        for learner, histories in runs.items():
            finals = [final_errors(h) for h in histories]
            last = min(max(r["step"] for r in h) for h in histories)
            for test_set in finals[0]:
                per_seed = [f[test_set] for f in finals if test_set in f]
                dims = {n: [e[n] for e in per_seed] for n in names}
                means = [[np.mean([e[k] for k in dims_of]) for e in per_seed]
                         for dims_of in groups.values()]
                cells = [cell(v) for v in (*dims.values(), *means)]
                lines.append(f"| {learner} | {test_set} | " + " | ".join(cells)
                             + f" | {last} | {len(per_seed)} |")
        lines.append("")
        # Locomotion has tens of dimensions: one panel per group, as the paper shows them.
        panels = groups if len(names) > 8 else None
        plots.plot_alignment([r for hs in runs.values() for h in hs for r in h],
                             out / f"{env}_alignment.png", groups=panels)
    text = "\n".join(lines) + "\n"
    (out / "fig2.md").write_text(text)
    return text


def main(argv=None) -> int:
    from jaml.cli import key_value

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--learner-opt", type=key_value, action="append", metavar="KEY=VALUE",
                        default=[], help="a learner config field for every run, e.g. "
                                         "frame_nll=mean (the reference code's likelihood)")
    parser.add_argument("--report-only", action="store_true")
    add_scale_options(parser, SCALE)
    args = parser.parse_args(argv)
    apply_scale(args, SCALE)
    if not args.report_only:
        from jaml.stream import for_env
        from jaml.stream.run import run

        for env in args.envs:
            for learner in args.learners:
                for seed in args.seeds:
                    started = time.perf_counter()
                    config = for_env(env, learner, seed=seed, **SCALE,
                                     learner_overrides=dict(args.learner_opt))
                    summary = run(config, args.out / env / learner / f"seed_{seed}",
                                  progress=False)
                    phases = ", ".join(f"{k} {v:.0f}s"
                                       for k, v in summary["seconds_by_phase"].items())
                    print(f"{env} {learner} seed {seed}: {summary['status']} in "
                          f"{time.perf_counter() - started:.0f}s ({phases})", flush=True)
    print(report(args.out, args.envs, args.learners))
    return 0


if __name__ == "__main__":
    sys.exit(main())
