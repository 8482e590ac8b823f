"""MeshOnIncline: the contract under jit(vmap), a textured object in the rendered frame, loading
a user's YCB-layout folder, and frictionless sliding against s0 + g sin(theta) t^2 / 2."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import envs_mjx
from envs_mjx import render
from envs_mjx.domains import mesh_incline
from envs_mjx.domains.mesh_object import load_object, read_obj

B, T = 2, 50
FAST_COMPILE = {"xla_backend_optimization_level": 0}


def _rollout(env, state, actions):
    def body(s, a):
        s = env.step(s, a)
        return s, (s.ld_state, s.pipeline_state.qpos, s.reward, s.done)

    return jax.lax.scan(body, state, actions)


@pytest.fixture(scope="module")
def env():
    return envs_mjx.make("MeshOnIncline", image_size=48)


@pytest.fixture(scope="module")
def states(env):
    reset = jax.jit(jax.vmap(env.reset), compiler_options=FAST_COMPILE)
    state0 = reset(jax.random.split(jax.random.key(0), B))
    actions = jax.random.uniform(jax.random.key(1), (B, T, 1), minval=-1.0, maxval=1.0)
    run = jax.jit(jax.vmap(lambda s, a: _rollout(env, s, a)), compiler_options=FAST_COMPILE)
    final, traj = run(state0, actions)
    return state0, final, traj


def test_contract_under_jit_vmap(env, states):
    state0, final, (ld, qpos, reward, done) = states
    assert env.ld_state_names == ("texture_id", "object_id", "theta", "position", "velocity")
    assert env.action_size == 1 and env.observation_size == 5
    for s in (state0, final):
        assert s.ld_state.shape == (B, 5) and s.ld_state.dtype == jnp.float32
        assert s.pixels.shape == (B, 48, 48, 3) and s.pixels.dtype == jnp.uint8
    assert ld.shape == (B, T, 5) and qpos.shape == (B, T, 7)
    assert set(np.unique(np.asarray(done))) <= {0.0, 1.0}
    for x in (ld, qpos, reward, final.pixels):
        assert np.all(np.isfinite(np.asarray(x, np.float32)))
    # The duck is MESH_OBJECTS[0]: normalized object id 0; the LD state moves during the rollout.
    np.testing.assert_allclose(ld[..., 1], 0.0)
    assert np.ptp(np.asarray(ld[..., 3])) > 0.01


def test_frame_shows_the_textured_object(env, states):
    state0 = jax.tree.map(lambda x: x[0], states[0])
    ctx = render.make_context(env.mj_model, "pixels", 48, 48)
    out = jax.jit(render.render)(
        ctx.replace(geom_rgb=state0.info["geom_rgba"][:, :3]), state0.pipeline_state
    )
    visual = envs_mjx.base.geom_ids(env.mj_model, ["object_visual"])[0]
    hull = envs_mjx.base.geom_ids(env.mj_model, ["object"])[0]
    seg, rgb = np.asarray(out.segmentation), np.asarray(out.rgb)
    mask = seg == visual
    # The object is in view (~28 pixels at 48 x 48 since the camera was pulled back to keep it
    # whole over the plank's extent; test_domains checks that).
    assert mask.sum() > 15, mask.sum()
    assert not np.any(seg == hull)  # the collision hull is not drawn
    np.testing.assert_array_equal(rgb, np.asarray(state0.pixels))  # what the env returns
    # Texture: the object's pixels take many colours, and its hue varies beyond what shading alone
    # (a scalar factor on one material colour) could do: the duck has a yellow body, an orange
    # beak and dark eyes.
    pix = rgb[mask].astype(np.float32)
    assert len({tuple(p) for p in pix}) > 10
    chroma = pix / np.maximum(pix.sum(1, keepdims=True), 1.0)
    assert np.ptp(chroma[:, 1]) > 0.05 or np.ptp(chroma[:, 2]) > 0.05
    Image.fromarray(rgb).resize((192, 192), Image.NEAREST).save("/tmp/mesh_incline.png")


def _write_user_object(folder):
    """A unit cube with a two-coloured texture, in the YCB google_16k layout (quads + vt)."""
    folder.mkdir()
    corners = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    quads = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    lines = [f"v {x} {y} {z}" for x, y, z in corners]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1"]
    lines += ["f " + " ".join(f"{v}/{k + 1}" for k, v in enumerate(q)) for q in quads]
    (folder / "textured.obj").write_text("\n".join(lines) + "\n")
    tex = np.zeros((256, 256, 3), np.uint8)
    tex[:128] = (200, 30, 30)
    tex[128:] = (30, 30, 200)
    Image.fromarray(tex).save(folder / "texture_map.png")


def test_user_folder_loads_and_missing_ones_raise(tmp_path):
    folder = tmp_path / "my_object"
    _write_user_object(folder)
    verts, faces, uv = read_obj(folder / "textured.obj")
    assert verts.shape == (8, 3) and faces.shape == (12, 3) and uv.shape == (12, 3, 2)
    mesh = load_object(folder, size=0.2)
    assert mesh.texture.shape == (128, 128, 3)  # shrunk from 256
    np.testing.assert_allclose(mesh.verts.max(0) - mesh.verts.min(0), 0.2)
    env = mesh_incline.MeshOnIncline(
        dataclasses.replace(mesh_incline.default_config(), pixels="off", object_size=0.2),
        object_dir=str(folder),
    )
    m = env.mj_model
    visual = envs_mjx.base.geom_ids(m, ["object_visual"])[0]
    assert m.mesh_facenum[m.geom_dataid[visual]] == 12
    assert env._half_height == pytest.approx(0.1)
    _, _, info = env._sample_reset(jax.random.key(0))
    qpos = jnp.asarray(env.mj_model.qpos0)
    ld = env._ld_state(env._data0.replace(qpos=qpos), info)
    assert float(ld[1]) == pytest.approx(len(mesh_incline.MESH_OBJECTS) / 6.0)

    with pytest.raises(FileNotFoundError, match="object folder not found"):
        mesh_incline.MeshOnIncline(object_dir=str(tmp_path / "nope"))
    (folder / "texture_map.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"texture_map\.png missing"):
        mesh_incline.MeshOnIncline(object_dir=str(folder))
    with pytest.raises(ValueError, match="object must be one of"):
        envs_mjx.make("MeshOnIncline", object="teapot", pixels="off")


def test_slides_down_a_frictionless_plank():
    env = envs_mjx.make("MeshOnIncline", object="domino", friction_range=(0.0, 0.0), pixels="off")
    reset = jax.jit(jax.vmap(env.reset), compiler_options=FAST_COMPILE)
    state0 = reset(jax.random.split(jax.random.key(3), B))
    steps = 10
    run = jax.jit(jax.vmap(lambda s, a: _rollout(env, s, a)), compiler_options=FAST_COMPILE)
    _, (_, qpos, _, _) = run(state0, jnp.zeros((B, steps, 1)))
    theta = np.asarray(state0.info["theta"])
    s0, _ = jax.vmap(env.along_plank)(
        state0.pipeline_state.qpos, state0.pipeline_state.qvel, state0.info["theta"]
    )
    s, _ = jax.vmap(env.along_plank)(qpos[:, -1], jnp.zeros((B, 6)), state0.info["theta"])
    t = steps * env.dt
    expected = np.asarray(s0) + 0.5 * 9.81 * np.sin(theta) * t**2
    assert np.all(np.asarray(s) > np.asarray(s0) + 0.05)  # it moved downhill
    np.testing.assert_allclose(np.asarray(s), expected, rtol=0.02)
