"""Wall time of the Fig. 9 experiment (`jaml.experiments.fig9`) from a finished OUT directory.

Run it on the machine that ran the experiment: it reads the relation runs' summaries (fit
seconds) and every learning-loop run's `summary.json` (its wall seconds by phase, compilation
included) and records one row per method plus the total through the harness. A run that was
resumed counts only its last call, so record from runs that each finished in one call.
`--concurrent`: the methods ran as parallel processes on one GPU (one `--methods M` driver
each), so the total counts the slowest method's seeds instead of the sum over methods.

    python -m benchmarks.fig9_time --out runs/fig9 [--concurrent]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from benchmarks import harness
from jaml.experiments import _runs, fig9


def _finished(paths) -> list[dict]:
    summaries = [json.loads(p.read_text()) for p in sorted(paths)]
    return [s for s in summaries if s["status"] == "finished"]


def rows(out: Path, concurrent: bool = False) -> list[dict]:
    result, total = [], 0.0
    for name in fig9.RELATIONS:
        path = out / "relations" / name / "summary.json"
        if path.exists():
            seconds = sum(r["seconds"] for r in json.loads(path.read_text())["relations"])
            total += seconds
            result.append({"case": f"relations {name}", "wall_s": seconds})
    pilots = _finished(out.glob("pilot/*/seed_*/summary.json"))
    if pilots:
        seconds = sum(s["seconds_this_call"] for s in pilots)
        total += seconds
        result.append({"case": f"weight pilot x {len(pilots)} runs", "wall_s": seconds})
    per_method = []
    for method in fig9.METHODS:
        finished = _finished((out / method).glob("seed_*/summary.json"))
        if not finished:
            continue
        # A method's seeds are trained together (`run_many`, one call): every seed's summary
        # gives that call's wall time, so the method took the longest of them, not their sum.
        seconds = max(s["seconds_this_call"] for s in finished)
        phases = {k: sum(s["seconds_by_phase"][k] for s in finished)
                  for k in finished[0]["seconds_by_phase"]}
        per_method.append(seconds)
        result.append({"case": f"{method} x {len(finished)} seeds", "wall_s": seconds,
                       "epochs": finished[0]["epoch"],
                       **{f"{k}_s": v for k, v in phases.items()}})
    total += max(per_method, default=0.0) if concurrent else sum(per_method)
    how = "methods as parallel processes" if concurrent else "methods one after another"
    result.append({"case": f"Fig. 9 total (relations + pilot + runs, {how})", "wall_s": total})
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--concurrent", action="store_true")
    args = parser.parse_args(argv)
    measured = rows(args.out, args.concurrent)
    for row in measured:
        print(row)
    config = _runs.settings(json.loads(next(args.out.glob("*/seed_*/config.json")).read_text()))
    scale = json.dumps({k: config[k] for k in ("num_envs", "replay_slots", "epochs")})
    harness.record("fig9_experiment", measured,
                   notes=f"Wall seconds of `python -m jaml.experiments.fig9` (compilation "
                         f"included, one call per run) at {scale}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
