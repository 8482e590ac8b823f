"""Quiet output: a RelationSet's repr is one short line; relation progress bars count real steps."""

import inspect
import re

import jax
import jax.numpy as jnp

from jaml.configs.relations import Config
from jaml.relations import training
from jaml.relations.relation_set import RelationSet
from jaml.relations.run import _Recorder


def test_relation_set_repr_is_short_and_names_widths_and_means():
    weights = {"w": jnp.ones((3, 512)), "b": jnp.zeros(512)}
    rs = RelationSet(params=(weights, weights), on_means=jnp.array([0.0123, 0.02]),
                     off_means=jnp.array([0.5, 0.75]), widths=(64, 32), depth=2, dim=3,
                     dim_names=("x", "y", "z"))
    text = repr(rs)
    assert text == str(rs) and "\n" not in text and len(text) < 200
    assert "g1: width 64, on 0.0123 off 0.5" in text and "g2: width 32" in text
    assert "(x, y, z)" in text and "1.0" not in text  # no weights
    assert text.startswith("RelationSet(2 relations of")
    one = repr(RelationSet(params=(weights,), on_means=jnp.array([0.01]),
                           off_means=jnp.array([0.5]), widths=(64,), depth=2, dim=3))
    assert one.startswith("RelationSet(1 relation of") and one.endswith("off 0.5)")
    assert repr(RelationSet.empty(3, 2, 1.5)).endswith("tolerance 1.5)")


def test_a_relation_bar_has_no_budget_total_and_no_rate_from_before_it(tmp_path):
    """The first report (1000 steps run before the bar existed) is the bar's start, not a rate;
    a phase that stops at convergence leaves no bar short of a 50 000-step total."""
    rec = _Recorder(tmp_path, Config(max_relations=1), done=0, step_offset=0, progress=True)
    rec("relation", 0, {"step": 1000, "on_mean": 0.1, "off_mean": 1.0})
    bar = rec.bar
    assert bar.total is None and "50000" in bar.desc
    assert bar.n == 1000 and bar.format_dict["initial"] == 1000
    assert bar.format_dict["rate"] is None  # no rate yet: nothing counted since the start
    rec("relation", 0, {"step": 2000, "on_mean": 0.1, "off_mean": 1.0})
    assert bar.n == 2000
    rec.close()


def test_every_phase_the_fit_reports_has_a_bar_with_its_budget(tmp_path):
    """The phases named where `training` calls its callback are the ones `phase_budgets`
    lists, and the bar of each names its budget (a refinement round once had none, and its
    first report ended `jaml demo` with a KeyError)."""
    source = inspect.getsource(training)
    reported = set(re.findall(r'phase="(\w+)"', source)) | set(
        re.findall(r'callback\("(\w+)"', source))
    cfg = Config(max_relations=1)
    budgets = training.phase_budgets(cfg)
    assert reported and reported <= set(budgets), reported - set(budgets)
    assert budgets["refine"] == cfg.max_steps // training.REFINE_SHARE
    rec = _Recorder(tmp_path, cfg, done=0, step_offset=0, progress=True)
    for phase, budget in budgets.items():
        rec(phase, 0, {"step": 500, "on_mean": 0.1, "off_mean": 1.0})
        assert rec.bar.desc == f"g1 {phase} (≤ {budget} steps)"
    rec.close()


def test_a_budgeted_training_reports_the_steps_it_took_not_its_counters_start():
    """A refinement round runs the relation's loop with its counter started at max_steps −
    budget; its reports (the progress bar, metrics.jsonl) count from 0, as its result does."""
    from jaml import sources
    from jaml.relations.data import prepare
    from jaml.relations.networks import Relation

    cfg = Config(chunk_steps=5, stop_patience=1000, batch_size=32)
    batches = prepare(sources.make("ellipse"), 32, 0.0, jax.random.key(0), 2)
    params = Relation(4).init(jax.random.key(0), jnp.zeros((1, 3)))
    reported = []
    state = training._fit_relation(
        cfg, batches, RelationSet.empty(3, 3, 1.5), params, jax.random.key(1), 40,
        callback=lambda phase, k, m: reported.append((phase, m["step"])), phase="refine",
        budget=10)
    assert reported == [("refine", 5), ("refine", 10)] and int(state.step) == 10
