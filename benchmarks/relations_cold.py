"""Cold path of `relations.fit`: one fit of the ellipse's two relations (transversality,
defaults) in this fresh process, with the time JAX spent tracing, lowering and compiling.

    /usr/bin/time -f "%e s wall" python benchmarks/relations_cold.py   # once per fresh process
"""

from __future__ import annotations

import collections
import json
import sys
import time

import jax

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}


def main() -> None:
    spent = collections.Counter()

    def listener(event, seconds, **_):
        if event in EVENTS:
            spent[EVENTS[event]] += seconds

    jax.monitoring.register_event_duration_secs_listener(listener)
    started = time.perf_counter()
    from jaml import relations, sources

    imported = time.perf_counter()
    src = sources.make("ellipse")
    per_relation = []
    rs = relations.fit(src, relations.Config(max_relations=2),
                       on_relation=lambda rs, s: per_relation.append(
                           {"steps": s.steps, "seconds": round(s.seconds, 2),
                            "status": s.status, "ratio": round(s.ratio, 1)}))
    done = time.perf_counter()
    during_fit = dict(spent)
    print("-- fit done --", file=sys.stderr, flush=True)
    on = src.sample(jax.random.key(11), 20_000)
    off = jax.random.uniform(jax.random.key(12), on.shape, minval=on.min(0), maxval=on.max(0))
    ev = lambda t: jax.numpy.mean(jax.numpy.abs(relations.evaluate(rs, t)), 0)  # noqa: E731
    fresh = [round(float(x), 1) for x in ev(off) / ev(on)]
    g = [jax.vmap(jax.grad(rs.relation(k)))(on) for k in range(2)]
    cos = jax.numpy.sum(g[0] * g[1], -1) / (
        jax.numpy.linalg.norm(g[0], axis=-1) * jax.numpy.linalg.norm(g[1], axis=-1))
    print(json.dumps({
        "import_s": round(imported - started, 2),
        "fit_s": round(done - imported, 2),
        # JAX's own timers during the fit, summed over threads (g_2's loop compiles in the
        # background while g_1 trains).
        "trace_s": round(during_fit.get("trace", 0.0), 2),
        "lower_s": round(during_fit.get("lower", 0.0), 2),
        "compile_s": round(during_fit.get("compile", 0.0), 2),
        "relations": per_relation,
        "fresh_off_on": fresh,
        "mean_abs_sin": round(float(jax.numpy.mean(jax.numpy.sqrt(1 - cos**2))), 4),
    }))


if __name__ == "__main__":
    main()
