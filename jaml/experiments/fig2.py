"""Paper Fig. 2 at a reduced scale: alignment of each learner's latents with the true state.

Runs `jaml.stream.run` for every (env, learner) into OUT/ENV/LEARNER (each run resumable), then
writes OUT/fig2.md (final per-dimension errors on π_rand and π_curr, with position and velocity
means) and OUT/ENV_alignment.png (all learners' curves). The paper's findings it checks:
  (a) VAE_rpl aligns better than VAE_v0 on π_rand (the replay keeps early, diverse frames);
  (b) PRED and the sequential learners (SVAE, DSA) align velocities better than the VAE, which
      sees one frame and cannot tell velocity.

    python -m jaml.experiments.fig2 --out runs/fig2                  # GPU-sized defaults
    python -m jaml.experiments.fig2 --out runs/fig2 --report-only    # tables from finished runs
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

LEARNERS = ("VAE_v0", "VAE_rpl", "PRED", "SVAE", "DSA")
ENVS = ("CartPole", "InvertedPendulum")
# Reduced scale: 1/5 of the reference replay, 200 learner epochs instead of tens of thousands,
# regressor sets of a few thousand sequences instead of 10 000.
SCALE = dict(num_envs=64, replay_slots=1024, epochs=216, eval_every=50, eval_train=4096,
             eval_rand=2048, eval_curr=1024, regressor_iterations=4000)


def _velocity(name: str) -> bool:
    return name.endswith("_dot") or "vel" in name


def final_errors(history: list[dict]) -> dict[str, dict[str, float]]:
    """test set → {dim: error} at the last analysed step."""
    last = max(r["step"] for r in history)
    return {r["test_set"]: r["errors"] for r in history if r["step"] == last}


def report(out: Path, envs, learners) -> str:
    lines = ["# Fig. 2 at reduced scale: alignment error (training-std units; lower is better)",
             ""]
    for env in envs:
        histories = {}
        for learner in learners:
            path = out / env / learner / "history.jsonl"
            if path.exists() and path.read_text().strip():
                histories[learner] = [json.loads(x) for x in path.read_text().splitlines()]
        if not histories:
            continue
        names = list(next(iter(histories.values()))[0]["errors"])
        config = json.loads((out / env / next(iter(histories)) / "config.json").read_text())
        settings = {k: config[k] for k in SCALE}
        lines += [f"## {env}", "", f"Settings: {json.dumps(settings)}", "",
                  "| learner | test set | " + " | ".join(names) + " | position mean | "
                  "velocity mean | epoch |",
                  "|---" * (len(names) + 5) + "|"]
        for learner, history in histories.items():
            last = max(r["step"] for r in history)
            for test_set, errs in final_errors(history).items():
                pos = np.mean([v for k, v in errs.items() if not _velocity(k)])
                vel = np.mean([v for k, v in errs.items() if _velocity(k)])
                lines.append(f"| {learner} | {test_set} | "
                             + " | ".join(f"{errs[n]:.3f}" for n in names)
                             + f" | {pos:.3f} | {vel:.3f} | {last} |")
        lines.append("")
        from jaml.evaluation import plots

        merged = [r for h in histories.values() for r in h]
        plots.plot_alignment(merged, out / f"{env}_alignment.png")
    text = "\n".join(lines) + "\n"
    (out / "fig2.md").write_text(text)
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--envs", nargs="+", default=list(ENVS))
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--report-only", action="store_true")
    for k, v in SCALE.items():
        parser.add_argument("--" + k.replace("_", "-"), type=int, default=v)
    args = parser.parse_args(argv)
    SCALE.update({k: getattr(args, k) for k in SCALE})
    if not args.report_only:
        from jaml.stream import for_env
        from jaml.stream.run import run

        for env in args.envs:
            for learner in args.learners:
                started = time.perf_counter()
                config = for_env(env, learner, seed=args.seed, **SCALE)
                summary = run(config, args.out / env / learner, progress=False)
                phases = ", ".join(f"{k} {v:.0f}s" for k, v in summary["seconds_by_phase"].items())
                print(f"{env} {learner}: {summary['status']} in "
                      f"{time.perf_counter() - started:.0f}s ({phases})", flush=True)
    print(report(args.out, args.envs, args.learners))
    return 0


if __name__ == "__main__":
    sys.exit(main())
