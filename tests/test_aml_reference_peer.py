"""The authors' PyTorch AML as a peer (benchmarks/peers/aml_reference.py): their relation
networks evaluated in JAX equal their torch outputs, the seeded data RNG repeats its draws, and
a fit cut by its budget still yields its relation.

Marked slow (torch is no dependency of the default suite, and the authors' code is a git-ignored
checkout: `make test-slow`); each test skips with the reason when either is absent.
"""

import sys

import numpy as np
import pytest

from benchmarks.peers import aml_reference as ar

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def torch():
    torch = pytest.importorskip("torch", reason="torch is not installed (the bench extra)")
    try:
        ar.find_checkout()
    except FileNotFoundError as e:
        pytest.skip(str(e))
    return torch


def _their_nets(torch, source, widths, seed=0):
    """Their GNNs (aml_nets.GNN, as AML.add_g builds them), random weights and on/off means."""
    main = ar.load_reference(seed)
    from aml.aml_nets import GNN

    torch.manual_seed(seed)
    dim = len(ar.JAML_TO_REFERENCE[source])
    nets, records = [], []
    for k, width in enumerate(widths):
        net = GNN(dim, 1, [width] * 3, torch.nn.Tanh(), torch.nn.Tanh(), "cpu")
        net.on_mean[0], net.off_mean[0] = 0.01 * (k + 1), 0.1 * (k + 1)
        nets.append(net)
        records.append({"width": width, "steps": 0, "status": "cut", "on_mean": 0.01 * (k + 1),
                        "off_mean": 0.1 * (k + 1)})
    assert main.AML is not None
    return nets, records


@pytest.mark.parametrize("source", ar.SOURCES)
def test_jax_relations_equal_their_torch_networks(torch, source, tmp_path):
    """On random τ in jaml's order: the callable and the RelationSet equal their networks fed
    the same rows in their order (the block's (s0, s1, v0, v1))."""
    from jaml import relations

    nets, records = _their_nets(torch, source, widths=(4, 8, 16))
    path = ar.export(nets, records, tmp_path / "relations.npz", source)
    dim = len(ar.JAML_TO_REFERENCE[source])
    tau = np.random.default_rng(1).normal(scale=2.0, size=(257, dim)).astype(np.float32)
    theirs = np.asarray(tau)[:, ar.JAML_TO_REFERENCE[source]]
    with torch.no_grad():
        want = np.concatenate([net(torch.from_numpy(theirs)).numpy() for net in nets], -1)
    np.testing.assert_allclose(np.asarray(ar.load_relations(path)(tau)), want, atol=1e-5)
    np.testing.assert_allclose(np.asarray(ar.load_relations(path)(tau[0])), want[0], atol=1e-5)
    scaled = ar.load_relations(path, normalize=True)(tau)
    np.testing.assert_allclose(np.asarray(scaled) * [0.01, 0.02, 0.03], want, atol=1e-5)
    rs = ar.relation_set(path)
    np.testing.assert_allclose(np.asarray(relations.evaluate(rs, tau)), want, atol=1e-5)
    np.testing.assert_allclose(np.asarray(rs.on_means), [0.01, 0.02, 0.03], rtol=1e-6)
    assert rs.widths == (4, 8, 16) and rs.depth == 3


def test_seeded_data_rng_repeats_its_draws_and_block_order_converts(torch):
    a = ar.reference_batch("Ellipse", seed=3, n=64)
    b = ar.reference_batch("Ellipse", seed=3, n=64)
    c = ar.reference_batch("Ellipse", seed=4, n=64)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    off = ar.reference_batch("Ellipse", seed=3, n=64, on_manifold=False)
    np.testing.assert_array_equal(off, ar.reference_batch("Ellipse", 3, 64, on_manifold=False))
    # Their block rows (s0, s1, v0, v1) in jaml's order (s0, v0, s1, v1) obey jaml's relations.
    rows = ar.to_jaml_order(ar.reference_batch("ConservativeBlock45Incline1D", 0, 64),
                            "ConservativeBlock45Incline1D")
    c45 = 9.8 * np.sin(np.pi / 4)
    np.testing.assert_allclose(rows[:, 3] - rows[:, 1], c45, atol=1e-5)
    np.testing.assert_allclose(rows[:, 2] - rows[:, 0] - rows[:, 1], c45 / 2, atol=1e-5)


def test_a_budget_cut_fit_keeps_its_relation_flagged(torch, tmp_path):
    """Three seconds of their Ellipse fit: no relation finishes, the one in training is kept
    (status "cut", its steps and EMA means), exported, and loads as the run left it."""
    summary = ar.fit("Ellipse", seed=0, max_relations=2, budget_s=3.0, out=tmp_path)
    assert summary["cut"] and not summary["finished"]
    (g1,) = summary["relations"]
    assert g1["status"] == "cut" and g1["steps"] > 0 and g1["width"] == 4
    assert g1["phases"] == [{"kind": "g", "max_steps": 50_000, "ended": "cut",
                             "steps": g1["steps"]}]
    assert 0 < g1["on_mean"] < 1 and summary["torch_threads"] == 1
    out = ar.load_relations(summary["npz"])(np.zeros((5, 3), np.float32))
    assert out.shape == (5, 1) and np.all(np.abs(np.asarray(out)) < 1)
    assert (tmp_path / "reference_stdout.txt").stat().st_size > 0
    # Their TensorBoard scalars went to the stand-in's CSV; the process's tensorboardX is left
    # as it was.
    (scalars,) = tmp_path.glob("AML_Ellipse_*/scalars.csv")
    assert "g_loss" in scalars.read_text()
    assert getattr(sys.modules.get("tensorboardX"), "SummaryWriter", None) is not ar._ScalarWriter


def test_a_file_of_rows_trains_behind_their_data_source_interface(torch, tmp_path):
    """`rows:FILE`: their batches are rows of the file (drawn by their seeded data RNG, the same
    draws for the same seed), their off-manifold rows uniform inside each batch's box as their
    `process_data` makes them, and a short fit on the rows exports relations of its width."""
    rows = np.random.default_rng(0).normal(size=(500, 4))
    path = tmp_path / "rows.npy"
    np.save(path, rows)
    main = ar.load_reference(seed=5)
    source = ar.rows_source(main, path)(64, "cpu")
    on = source.get_batch(64, "cpu").numpy()
    assert on.shape == (64, 4) and source.dim_names == ["x0", "x1", "x2", "x3"]
    assert all(np.isclose(rows, row, atol=1e-6).all(1).any() for row in on)
    np.testing.assert_array_equal(
        on, ar.rows_source(ar.load_reference(seed=5), path)(64, "cpu").get_batch(64).numpy())
    off = source.get_batch(4096, "cpu", on_manifold=False).numpy()
    assert not any(np.isclose(rows, row, atol=1e-6).all(1).any() for row in off[:64])
    assert (off.min(0) >= rows.min(0) - 1e-6).all() and (off.max(0) <= rows.max(0) + 1e-6).all()
    summary = ar.fit(f"{ar.ROWS}{path}", seed=0, max_relations=1, budget_s=2.0, out=tmp_path)
    (g1,) = summary["relations"]
    assert g1["steps"] > 0 and g1["width"] == 4
    assert ar.load_relations(summary["npz"])(rows[:3].astype(np.float32)).shape == (3, 1)
