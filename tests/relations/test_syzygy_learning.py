"""Learning with syzygies: the syzygy network f, Algorithm 1 in syzygy mode and the joint
training of f beside g_k, on the ellipse.

Apart from tests/relations/test_learning.py, at the suite's cheap XLA setting
(tests/conftest.py): their loops run a few thousand steps, so compiling at the full level costs
more than it saves (and the two modules balance across the workers).
"""

import math

import jax
import pytest

from jaml import relations, sources
from jaml.relations.data import prepare
from jaml.relations.training import fit_syzygy
from tests.relations.test_learning import _fresh_ratio


@pytest.mark.loop_level
def test_syzygy_network_expresses_a_dependent_relation_but_not_an_independent_one():
    cfg = relations.Config(syzygy_max_steps=6000, separation_ratio=20.0)
    batches = prepare(sources.make("ellipse"), cfg.batch_size, 0.0, jax.random.key(0), 4)
    plane = lambda t: 0.2 * (t[..., 1] - 2 * t[..., 2] - 1)  # noqa: E731
    multiple = lambda t: (1.0 + 0.5 * t[..., 0] ** 2) * plane(t)  # noqa: E731  h·g1
    hyperboloid = lambda t: 0.1 * (t[..., 0] ** 2 + t[..., 1] ** 2 - 2 * t[..., 2] ** 2 - 1)  # noqa: E731
    _, found, dep = fit_syzygy(cfg, batches, [plane], multiple, jax.random.key(1), 0.5)
    assert found and dep["residual"] < 0.05 * dep["g_scale"], dep
    _, found, ind = fit_syzygy(cfg, batches, [plane], hyperboloid, jax.random.key(1), 0.5)
    assert not found and ind["residual"] > 0.2 * ind["g_scale"], ind


@pytest.mark.loop_level
def test_algorithm_1_with_syzygies_learns_separating_relations():
    """The paper's Algorithm 1 with restricted syzygies, as written: jaml's further starts
    (`premine_attempts`, which here train the whole fit twice) are tested in test_quality."""
    src = sources.make("ellipse")
    cfg = relations.Config(
        max_relations=2,
        independence="syzygy",
        transversal_first=False,  # syzygies from g_2 on, the paper's way
        premine_attempts=1,
        syzygies_per_relation=1,
        max_steps=30_000,
        syzygy_max_steps=4000,
        syzygy_push_steps=8000,
    )
    rs = relations.fit(src, cfg)
    assert rs.num_relations == 2
    assert (_fresh_ratio(rs, src, jax.random.key(31)) >= 5).all()
    assert math.isfinite(float(rs.on_means.sum()))


def test_syzygy_mode_trains_up_to_the_codimension_with_transversality_and_judges_beyond(
        monkeypatch):
    """With `transversal_first` (the default), g_2 of the ellipse (codimension 2) trains with
    eq. 2 (its loop reports the angle, no syzygy network) and only g_3 trains against syzygies,
    here jointly with its f ("push"), then judged once, as kept, by the fit's fresh syzygy
    (`unexplained_share`, stubbed here: new) whose share the report carries."""
    from jaml.relations import training

    judged, phases, summaries = [], set(), []

    def new(cfg, batches, rs, g_k, key, callback):
        judged.append(rs.num_relations)
        return 0.9

    monkeypatch.setattr(training, "unexplained_share", new)
    cfg = relations.Config(max_relations=3, independence="syzygy", syzygy_training="joint",
                           codimension=2, max_steps=400, chunk_steps=100, batch_size=128,
                           stop_patience=10, eval_batches=2, syzygy_max_steps=200,
                           mined_weight=0.0, stop_when_complete=False, pretrain_steps=0)
    rs = relations.fit(sources.make("ellipse"), cfg,
                       callback=lambda phase, k, m: phases.add((phase, k, "angle" in m)),
                       on_relation=lambda _, summary: summaries.append(summary))
    assert judged == [2] and rs.num_relations == 3
    assert ("relation", 1, True) in phases
    assert not any(phase in ("syzygy", "push") and k < 2 for phase, k, _ in phases)
    assert ("push", 2, False) in phases
    assert ("syzygy", 2, False) not in phases  # no syzygy fitted but the stubbed judge's
    assert summaries[2].syzygy_rounds == []
    assert summaries[2].unexplained == 0.9 and summaries[1].unexplained is None
    assert [r.get("unexplained") for r in rs.quality.to_dict()["relations"]] == [None, None, 0.9]


def test_a_relation_beyond_the_codimension_must_be_new_land_more_and_not_cut_the_data():
    from jaml.relations.training import _beyond_codimension_unneeded

    cfg = relations.Config(independence="syzygy")
    before = {"landed": 0.90, "extends": 0.0, "coverage": 0.96}
    assert "not new" in _beyond_codimension_unneeded(
        cfg, 0.1, {"landed": 0.99, "coverage": 0.96}, before)
    assert "no more projected box points" in _beyond_codimension_unneeded(
        cfg, 0.5, {"landed": 0.85, "extends": 0.05, "coverage": 0.96}, before)
    assert _beyond_codimension_unneeded(
        cfg, 0.5, {"landed": 0.95, "coverage": 0.96}, before) == ""
    # Landing more, but its zero set cuts the data to a few points (reach 7 % against 96 %):
    assert "cuts the data: the landed points reach 7% of the data's rows with it against " \
        "96% without it" in _beyond_codimension_unneeded(
            cfg, 0.5, {"landed": 0.99, "coverage": 0.07}, before)
    assert _beyond_codimension_unneeded(
        cfg, 0.5, {"landed": 0.99, "coverage": 0.90}, before) == ""  # within COVER_KEPT
    assert _beyond_codimension_unneeded(cfg, 0.5, None, before) == ""
    paper = cfg.replace(transversal_first=False)
    assert _beyond_codimension_unneeded(paper, 0.1, {"landed": 0.5}, before) == ""
