"""SPAIR: the spatial transformer against a plain bilinear loop, compositing, the presence KL in
closed form, the latent layout, and a short learning run on coloured squares.

Shapes are tiny (B = 2, 4×4 grid, 8×8 glimpses, narrow layers) but the frames are 64×64.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import learners
from jaml.learners import spair

B, K, Q = 2, 2, 2
TINY = {"backbone_filters": (8, 8, 8), "conv_features": 16, "cell_widths": (16,),
        "glimpse_size": 8, "what_dim": K, "bg_dim": Q, "object_filters": (8, 8),
        "object_hidden": 16, "bg_hidden": 16}


def numpy_bilinear(img, px, py):
    """img [H, W, C] sampled at pixel coordinates (px, py), zero outside: the textbook loop."""
    h, w, _ = img.shape
    x0, y0 = int(np.floor(px)), int(np.floor(py))
    fx, fy = px - x0, py - y0
    out = np.zeros(img.shape[-1])
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            y, x = y0 + dy, x0 + dx
            if 0 <= y < h and 0 <= x < w:
                out += wy * wx * img[y, x]
    return out


def numpy_glimpse(img, centre, scale, g):
    """[g, g, C]: glimpse pixel (u, v) reads the frame at centre + ((u, v) + ½)/g − ½)·scale."""
    h, w, _ = img.shape
    out = np.zeros((g, g, img.shape[-1]))
    for u in range(g):
        for v in range(g):
            fx = centre[0] + ((v + 0.5) / g - 0.5) * scale[0]
            fy = centre[1] + ((u + 0.5) / g - 0.5) * scale[1]
            out[u, v] = numpy_bilinear(img, fx * w - 0.5, fy * h - 0.5)
    return out


def _image(seed=0):
    return np.random.default_rng(seed).uniform(size=(64, 64, 3)).astype(np.float32)


def _glimpse(img, centre, scale, g):
    c, s = jnp.asarray([[centre]], jnp.float32), jnp.asarray([[scale]], jnp.float32)
    return np.asarray(spair.extract_glimpses(jnp.asarray(img)[None], c, s, g))[0, 0]


def test_identity_transform_returns_the_image():
    img = _image()
    np.testing.assert_allclose(_glimpse(img, (0.5, 0.5), (1.0, 1.0), 64), img, atol=1e-6)


def test_half_scale_centred_box_extracts_the_central_region():
    img = _image()
    # A 32-pixel glimpse of the central half lands exactly on pixels 16..47.
    np.testing.assert_allclose(_glimpse(img, (0.5, 0.5), (0.5, 0.5), 32), img[16:48, 16:48],
                               atol=1e-6)
    # A 16-pixel glimpse of it samples between pixels: compare with the plain loop.
    np.testing.assert_allclose(_glimpse(img, (0.5, 0.5), (0.5, 0.5), 16),
                               numpy_glimpse(img, (0.5, 0.5), (0.5, 0.5), 16), atol=1e-5)


@pytest.mark.parametrize("centre, scale", [((0.3, 0.7), (0.2, 0.35)), ((0.95, 0.05), (0.3, 0.3))])
def test_glimpse_matches_the_loop_off_centre_and_across_the_border(centre, scale):
    img = _image(1)
    np.testing.assert_allclose(_glimpse(img, centre, scale, 12),
                               numpy_glimpse(img, centre, scale, 12), atol=1e-5)


def test_placing_a_glimpse_is_the_inverse_of_extracting_it():
    glimpse = _image(2)[:32, :32]
    c, s = jnp.full((1, 1, 2), 0.5), jnp.full((1, 1, 2), 0.5)
    placed = np.asarray(spair.place_glimpses(jnp.asarray(glimpse)[None, None], c, s, (64, 64)))
    expected = np.zeros((64, 64, 3), np.float32)
    expected[16:48, 16:48] = glimpse
    np.testing.assert_allclose(placed[0, 0], expected, atol=1e-6)


def test_one_present_opaque_object_covers_the_background_exactly_where_its_alpha_is_one():
    rng = np.random.default_rng(3)
    n = 4
    rgb = rng.uniform(size=(1, n, 64, 64, 3)).astype(np.float32)
    alpha = rng.uniform(size=(1, n, 64, 64)).astype(np.float32)
    alpha[0, 0] = 0.0
    alpha[0, 0, 10:30, 20:40] = 1.0
    presence = np.array([[1.0, 0.0, 0.0, 0.0]], np.float32)  # the others are absent
    depth = rng.normal(size=(1, n)).astype(np.float32)
    bg = rng.uniform(size=(1, 64, 64, 3)).astype(np.float32)
    out = np.asarray(spair.composite(rgb, alpha, presence, depth, bg))[0]
    inside = np.zeros((64, 64), bool)
    inside[10:30, 20:40] = True
    np.testing.assert_allclose(out[inside], rgb[0, 0][inside], atol=1e-5)
    np.testing.assert_allclose(out[~inside], bg[0][~inside], atol=1e-6)


def test_the_deeper_of_two_opaque_objects_is_in_front():
    rgb = np.stack([np.full((8, 8, 3), 0.2), np.full((8, 8, 3), 0.9)])[None].astype(np.float32)
    alpha, presence = np.ones((1, 2, 8, 8), np.float32), np.ones((1, 2), np.float32)
    bg = np.zeros((1, 8, 8, 3), np.float32)
    front_second = spair.composite(rgb, alpha, presence, np.array([[0.0, 20.0]]), bg)
    front_first = spair.composite(rgb, alpha, presence, np.array([[20.0, 0.0]]), bg)
    np.testing.assert_allclose(front_second, 0.9, atol=1e-6)
    np.testing.assert_allclose(front_first, 0.2, atol=1e-6)


def test_presence_kl_is_the_bernoulli_closed_form():
    logits = np.array([-8.0, -2.0, 0.0, 0.5, 3.0, 9.0])
    for prior in (0.1, 0.5, 0.9):
        q = 1.0 / (1.0 + np.exp(-logits))
        closed = q * np.log(q / prior) + (1 - q) * np.log((1 - q) / (1 - prior))
        np.testing.assert_allclose(spair.bernoulli_kl(jnp.asarray(logits, jnp.float32), prior),
                                   closed, rtol=1e-4, atol=1e-6)
    # Zero when the posterior is the prior.
    assert abs(float(spair.bernoulli_kl(jnp.asarray(np.log(0.1 / 0.9)), 0.1))) < 1e-6


def test_boxes_stay_in_their_cells():
    where = jnp.asarray(np.random.default_rng(4).normal(size=(1, 16, 4)) * 5, jnp.float32)
    centre, scale = map(np.asarray, spair.boxes(where, 4, 0.5))
    col, row = np.arange(16) % 4, np.arange(16) // 4
    assert np.all((centre[0, :, 0] >= col / 4) & (centre[0, :, 0] <= (col + 1) / 4))
    assert np.all((centre[0, :, 1] >= row / 4) & (centre[0, :, 1] <= (row + 1) / 4))
    assert np.all((scale > 0) & (scale <= 0.5))


def squares(seed, b=B):
    """Frames [b, 1, 64, 64, 3] uint8: one or two coloured squares on a dark green background."""
    rng = np.random.default_rng(seed)
    img = np.empty((b, 1, 64, 64, 3))
    img[:] = (0.1, 0.3, 0.1)
    for i in range(b):
        for _ in range(rng.integers(1, 3)):
            y, x = rng.integers(0, 48, size=2)
            size = rng.integers(10, 17)
            img[i, 0, y:y + size, x:x + size] = rng.uniform(0.5, 1.0, size=3)
    return (img * 255).astype(np.uint8), np.zeros((b, 1, 2), np.float32)


@pytest.fixture(scope="module")
def run():
    learner = learners.make("SPAIR", ld_dim=2, learning_rate=1e-3, **TINY)
    opt = learners.default_optimizer(learner)
    data = squares(0)
    step = jax.jit(learners.make_train_step(learner, opt))

    def train(seed, steps):
        state = learners.init_train_state(learner, opt, jax.random.key(seed), data)
        history = []
        for i in range(steps):
            state, metrics = step(state, data, jax.random.fold_in(jax.random.key(seed), i))
            history.append(jax.device_get(metrics))
        return state, history

    state, history = train(0, 40)
    return dict(learner=learner, data=data, train=train, state=state, history=history)


def test_a_few_steps_on_coloured_squares_reduce_the_loss(run):
    losses = np.array([float(m["loss"]) for m in run["history"]])
    assert np.all(np.isfinite(losses)), losses
    # Mostly the background at first: ~815 → ~600 after 30 steps, ~480 after 40 (lr 1e-3).
    assert losses[-5:].mean() < 0.75 * losses[0], losses
    metrics = run["history"][-1]
    assert set(metrics) >= {"where", "what", "depth", "pres", "bg", "nll", "kl"}
    kl_sum = sum(float(metrics[k]) for k in ("where", "what", "depth", "pres", "bg"))
    np.testing.assert_allclose(metrics["kl"], kl_sum, rtol=1e-5)
    np.testing.assert_allclose(metrics["loss"], metrics["nll"] + metrics["kl"], rtol=1e-5)


def test_encode_is_the_per_cell_layout_and_reconstruct_a_frame(run):
    learner, (frames, actions) = run["learner"], run["data"]
    variables = run["state"].variables
    # One program for both: they share the backbone and the what encoder.
    z, recon = map(np.asarray, jax.jit(lambda v: (learner.encode(v, frames, actions),
                                                   learner.reconstruct(v, frames, actions)))(
        variables))
    assert z.shape == (B, 16 * (4 + 1 + 1 + K) + Q) == (B, learner.latent_size)
    assert learner.config.penalty_dim == learner.latent_size
    cells = z[:, :-Q].reshape(B, 16, 4 + 1 + 1 + K)
    assert np.all((cells[..., 4] > 0) & (cells[..., 4] < 1))  # presence probabilities
    assert recon.shape == (B, 1, 64, 64, 3)
    assert np.all(np.isfinite(recon)) and recon.min() >= 0.0 and recon.max() <= 1.0


def test_same_seed_same_result(run):
    state_a, hist_a = run["train"](1, 3)
    state_b, hist_b = run["train"](1, 3)
    assert [float(m["loss"]) for m in hist_a] == [float(m["loss"]) for m in hist_b]
    for a, b in zip(jax.tree.leaves(state_a.params), jax.tree.leaves(state_b.params), strict=True):
        np.testing.assert_array_equal(a, b)


def test_six_by_six_grid_shapes():
    learner = learners.make("SPAIR", ld_dim=2, grid_size=6, **TINY)
    frames, actions = squares(1)
    variables = jax.eval_shape(learner.init, jax.random.key(0), frames, actions)
    z = jax.eval_shape(lambda v: learner.encode(v, frames, actions), variables)
    assert z.shape == (B, 36 * (6 + K) + Q) == (B, learner.latent_size)
    out = jax.eval_shape(lambda v: learner.module.apply(
        v, *learner.check_batch(frames, actions), jax.random.key(0), train=True,
        mutable=["batch_stats"])[0], variables)
    assert out.recon.shape == (B, 1, 64, 64, 3) and out.z.shape == (B, 1, learner.latent_size)
    assert all(v.shape == (B,) for v in out.kl.values())


@pytest.mark.parametrize("field, value", [
    ("grid_size", 9), ("glimpse_size", 10), ("what_dim", 0), ("prior_presence", 1.0),
    ("temperature", 0.0), ("max_box_scale", 1.5), ("backbone_filters", (8, 8)),
])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=f"SPAIRConfig.{field} must be"):
        learners.make("SPAIR", ld_dim=2, **{field: value})
