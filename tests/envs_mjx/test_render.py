"""The ray caster against mujoco.Renderer (segmentation, depth) plus its jit/vmap contract."""

import os

# MuJoCo picks its GL backend at import; EGL is the headless one that works on this machine.
os.environ.setdefault("MUJOCO_GL", "egl")

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from envs_mjx import render
from envs_mjx.render import intersect

H = W = 64


class Poses(NamedTuple):
    """The four arrays the renderer reads, as plain arrays (a pytree jit accepts)."""

    geom_xpos: np.ndarray
    geom_xmat: np.ndarray
    cam_xpos: np.ndarray
    cam_xmat: np.ndarray


def poses(d: mujoco.MjData) -> Poses:
    return Poses(*(np.array(getattr(d, f), np.float32) for f in Poses._fields))


def torus(big=0.25, small=0.1, nu=16, nv=8):
    """A non-convex triangle mesh ([V, 3], [F, 3]) with 2*nu*nv faces and per-vertex uv."""
    a, b = np.meshgrid(2 * np.pi * np.arange(nu) / nu, 2 * np.pi * np.arange(nv) / nv,
                       indexing="ij")
    verts = np.stack([(big + small * np.cos(b)) * np.cos(a), (big + small * np.cos(b)) * np.sin(a),
                      small * np.sin(b)], -1).reshape(-1, 3)
    uv = np.stack([a / (2 * np.pi), b / (2 * np.pi)], -1).reshape(-1, 2)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    idx = lambda ii, jj: (ii % nu) * nv + (jj % nv)  # noqa: E731
    quads = [idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)]
    faces = np.concatenate([np.stack([quads[0], quads[1], quads[2]], -1).reshape(-1, 3),
                            np.stack([quads[0], quads[2], quads[3]], -1).reshape(-1, 3)])
    return verts, faces, uv


def _fmt(x):
    return " ".join(f"{v:.6g}" for v in np.ravel(x))


def all_geoms_xml(nu=16, nv=8):
    """Every drawable geom type on free bodies, a textured floor, a fixed and a tracking camera."""
    v, f, uv = torus(nu=nu, nv=nv)
    return f"""<mujoco><asset>
  <mesh name="torus" vertex="{_fmt(v)}" face="{_fmt(f)}" texcoord="{_fmt(uv)}"/>
  <texture name="grid" type="2d" builtin="checker" width="64" height="64" rgb1=".1 .2 .3"
           rgb2=".8 .8 .8"/>
  <material name="grid" texture="grid" texrepeat="2 2" texuniform="true"/>
  <material name="tmesh" texture="grid" rgba="1 .8 .8 1"/></asset>
<worldbody><light pos="0 0 3" dir="0 0 -1"/>
  <geom name="floor" type="plane" size="0 0 1" material="grid"/>
  <geom name="tile" type="plane" size=".3 .2 1" pos="-1 1 .3" euler="30 0 0" rgba="0 1 0 1"/>
  <body name="box" pos="0 0 .5"><freejoint/><geom type="box" size=".2 .1 .15" rgba="1 0 0 1"/>
  </body>
  <body name="ball" pos=".6 0 .5"><freejoint/><geom type="sphere" size=".15" rgba="0 0 1 1"/></body>
  <body name="pill" pos="-.6 0 .5"><freejoint/><geom type="capsule" size=".08 .2"/></body>
  <body name="can" pos="0 .6 .5"><freejoint/><geom type="cylinder" size=".12 .15"/></body>
  <body name="egg" pos="0 -.6 .5"><freejoint/><geom type="ellipsoid" size=".2 .1 .12"/></body>
  <body name="ring" pos=".6 .6 .5"><freejoint/><geom type="mesh" mesh="torus" material="tmesh"/>
    <camera name="track" mode="trackcom" pos="0 -2 1.5" xyaxes="1 0 0 0 .6 .8"/></body>
  <camera name="fixed" pos=".2 -2.2 1.8" xyaxes="1 0 0 0 .6 .8"/>
</worldbody></mujoco>"""


CARTPOLE_XML = """<mujoco><worldbody><light pos="0 0 4" dir="0 0 -1"/>
  <geom name="floor" type="plane" size="3 3 .1" rgba=".9 .9 .9 1"/>
  <geom name="rail" type="box" size="2 .02 .02" pos="0 0 1" rgba=".3 .3 .3 1" contype="0"
        conaffinity="0"/>
  <body name="cart" pos="0 0 1"><joint name="slide" type="slide" axis="1 0 0"/>
    <geom name="cart" type="box" size=".2 .1 .08" rgba=".8 .3 .2 1" contype="0" conaffinity="0"/>
    <body name="pole"><joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom name="pole" type="box" size=".03 .03 .4" pos="0 0 .4" rgba=".2 .5 .8 1" contype="0"
            conaffinity="0"/></body></body>
  <camera name="side" pos="0 -4 1.2" xyaxes="1 0 0 0 0 1"/>
</worldbody></mujoco>"""


def random_poses(m, d, rng, n):
    """n random configurations: free bodies jittered and spun, hinge/slide joints drawn."""
    out = []
    for _ in range(n):
        mujoco.mj_resetData(m, d)
        for j in range(m.njnt):
            a = m.jnt_qposadr[j]
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                d.qpos[a:a + 3] += rng.uniform(-0.25, 0.25, 3)
                q = rng.normal(size=4)
                d.qpos[a + 3:a + 7] = q / np.linalg.norm(q)
            else:
                d.qpos[a] = rng.uniform(-1.0, 1.0)
        mujoco.mj_forward(m, d)
        out.append(poses(d))
    return out


@pytest.fixture(scope="module")
def jit_render():
    return jax.jit(render.render)


def mujoco_segmentation(m, d, camera):
    with mujoco.Renderer(m, H, W) as r:
        r.enable_segmentation_rendering()
        r.update_scene(d, camera)
        s = r.render()
    return np.where(s[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, s[..., 0], -1)


def agreement_per_pose(xml, cameras, n_poses, jit_render, seed=0, **ctx_kwargs):
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    scores = []
    for camera in cameras:
        ctx = render.make_context(m, camera, H, W, **ctx_kwargs)
        for p in random_poses(m, d, rng, n_poses):
            # random_poses leaves d at the last pose; re-derive d for this one from its arrays.
            d.geom_xpos[:], d.geom_xmat[:] = p.geom_xpos, p.geom_xmat.reshape(-1, 9)
            d.cam_xpos[:], d.cam_xmat[:] = p.cam_xpos, p.cam_xmat.reshape(-1, 9)
            ref = mujoco_segmentation(m, d, camera)
            seg = np.asarray(jit_render(ctx, p).segmentation)
            assert len(np.unique(ref)) > 2, "scene should show several geoms"
            scores.append(((seg == ref).mean(), camera))
    return scores


def test_segmentation_matches_mujoco_all_geom_types(jit_render):
    scores = agreement_per_pose(all_geoms_xml(), ["fixed", "track"], 3, jit_render)
    worst = min(scores)
    assert worst[0] >= 0.99, scores


def test_segmentation_matches_mujoco_cartpole(jit_render):
    scores = agreement_per_pose(CARTPOLE_XML, ["side"], 3, jit_render)
    assert min(scores)[0] >= 0.99, scores


def test_decimated_mesh_still_matches(jit_render):
    # 1024 faces squeezed to at most 300: silhouettes may move by about one grid cell.
    scores = agreement_per_pose(all_geoms_xml(nu=32, nv=16), ["fixed"], 2, jit_render,
                                max_mesh_faces=300)
    assert min(scores)[0] >= 0.99, scores


def test_depth_matches_mujoco(jit_render):
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    d = mujoco.MjData(m)
    d.qpos[:] = [0.3, 0.5]
    mujoco.mj_forward(m, d)
    with mujoco.Renderer(m, H, W) as r:
        r.enable_depth_rendering()
        r.update_scene(d, "side")
        ref = r.render()
    out = jit_render(render.make_context(m, "side"), poses(d))
    seg = np.asarray(out.segmentation)
    mask = seg >= 0
    rel = np.abs(np.asarray(out.depth)[mask] - ref[mask]) / ref[mask]
    assert np.median(rel) < 1e-3 and np.quantile(rel, 0.95) < 1e-2, (np.median(rel), rel.max())


def test_dtypes_shapes_jit_vmap_and_no_recompile():
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    ctx = render.make_context(m, "side", 48, 32)
    dx = mjx.put_data(m, mujoco.MjData(m))
    mx = mjx.put_model(m)
    qpos = jnp.stack([jnp.array([x, 0.4 * x]) for x in np.linspace(-1, 1, 5)])
    # camlight is where MJX fills cam_xpos / cam_xmat, after kinematics has placed the bodies.
    place = jax.jit(jax.vmap(lambda q: mjx.camlight(mx, mjx.kinematics(mx, dx.replace(qpos=q)))))
    batch = place(qpos)
    f = jax.jit(jax.vmap(render.render, in_axes=(None, 0)))
    out = f(ctx, batch)
    assert out.rgb.shape == (5, 48, 32, 3) and out.rgb.dtype == jnp.uint8
    assert out.depth.shape == (5, 48, 32) and out.depth.dtype == jnp.float32
    assert out.segmentation.shape == (5, 48, 32) and out.segmentation.dtype == jnp.int32
    # The cart moves, so the frames must differ; each equals its unbatched render.
    assert not np.array_equal(out.segmentation[0], out.segmentation[-1])
    single = jax.jit(render.render)(ctx, jax.tree.map(lambda x: x[2], batch))
    np.testing.assert_array_equal(out.segmentation[2], single.segmentation)
    np.testing.assert_array_equal(out.rgb[2], single.rgb)
    # New data values (and another camera of the same model) reuse the compiled program.
    f(ctx, place(qpos[::-1] * 0.5))
    f(ctx.replace(cam_id=jnp.asarray(0, jnp.int32)), batch)
    assert f._cache_size() == 1


def test_large_batches_render_in_chunks_like_single_frames():
    # 37 frames: on the CPU the vmap rule renders chunks of 32 plus a remainder of 5. Colours
    # are batched too (as the envs' per-episode schemes are), and a second vmap on top must
    # agree with the first.
    chunk = render.raycast.CPU_BATCH_CHUNK
    assert chunk < 37 and 37 % chunk
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    ctx = render.make_context(m, "side", 24, 16)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    frames, rgbs = [], rng.uniform(0, 1, (37, m.ngeom, 3)).astype(np.float32)
    for _ in range(37):
        d.qpos[:] = rng.uniform(-1, 1, m.nq)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
        frames.append(poses(d))
    batch = Poses(*(np.stack(col) for col in zip(*frames, strict=True)))

    def draw(rgb, p):
        return render.render(ctx.replace(geom_rgb=rgb), p)

    out = jax.jit(jax.vmap(draw))(rgbs, batch)
    twice = jax.jit(jax.vmap(jax.vmap(draw)))(
        rgbs[None].repeat(2, 0), jax.tree.map(lambda x: np.stack([x, x]), batch))
    one = jax.jit(draw)
    for i in (0, 31, 32, 36):
        single = one(rgbs[i], jax.tree.map(lambda x, i=i: x[i], batch))
        for field in ("rgb", "depth", "segmentation"):
            np.testing.assert_array_equal(getattr(out, field)[i], getattr(single, field))
            np.testing.assert_array_equal(getattr(twice, field)[1, i], getattr(single, field))


def test_nearest_hits_stay_materialised_when_the_context_is_a_constant():
    # The envs close over their context, so XLA sees it as constants; the loop that keeps the
    # first pass's result in a buffer must survive that (if XLA could fold its trip count it
    # would delete it, and every consumer would re-run the pass: 2.6x slower on Ant).
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    ctx = render.make_context(m, "side", 8, 8)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    hlo = jax.jit(lambda p: render.render(ctx, p)).lower(poses(d)).compile().as_text()
    assert " while(" in hlo


def test_frame_stays_materialised_for_a_consumer_of_its_bytes():
    # env.step selects the new or the previous frame byte by byte; without a buffer between the
    # packed frame and its bytes XLA:CPU fused all of the shading into that select's loop, once
    # per channel (CartPole's step 2.6x slower). A second one-trip loop holds the packed frame.
    if jax.default_backend() != "cpu":
        pytest.skip("the renderer materialises the packed frame on the CPU only")
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    ctx = render.make_context(m, "side", 8, 8)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    prev = jnp.zeros((8, 8, 3), jnp.uint8)

    def step(p, keep):
        return jnp.where(keep, prev, render.render(ctx, p).rgb)

    alone = jax.jit(lambda p: render.render(ctx, p)).lower(poses(d)).compile()
    selected = jax.jit(step).lower(poses(d), jnp.bool_(False)).compile()
    assert alone.as_text().count(" while(") == 2 and selected.as_text().count(" while(") == 2
    out = selected(poses(d), jnp.bool_(False))
    # The renderer's own program (op by op, its hundreds of small programs took seconds).
    np.testing.assert_array_equal(out, alone(poses(d)).rgb)


def test_background_and_colours(jit_render):
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    out = jit_render(render.make_context(m, "side", background=(0.0, 1.0, 0.0)), poses(d))
    seg, rgb = np.asarray(out.segmentation), np.asarray(out.rgb)
    assert (seg == -1).any() and (rgb[seg == -1] == [0, 255, 0]).all()
    cart = rgb[seg == 2].astype(float)  # geom 2 is the reddish cart
    assert (cart[:, 0] > cart[:, 2]).all()


def test_unknown_camera_lists_valid_ones():
    m = mujoco.MjModel.from_xml_string(CARTPOLE_XML)
    with pytest.raises(ValueError, match=r"unknown camera 'nope'.*0: 'side'"):
        render.make_context(m, "nope")
    with pytest.raises(ValueError, match="unknown camera 7"):
        render.make_context(m, 7)


def test_undrawable_geom_type_is_rejected():
    xml = """<mujoco><asset><hfield name="h" nrow="3" ncol="3" size="1 1 .1 .1"/></asset>
      <worldbody><geom name="terrain" type="hfield" hfield="h"/>
      <camera name="c" pos="0 0 3"/></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ValueError, match=r"cannot draw.*'terrain'.*HFIELD"):
        render.make_context(m, "c")


def test_primitive_hits_closed_form():
    o = jnp.array([0.0, 0.0, 5.0])
    d = jnp.array([0.0, 0.0, -2.0])  # non-unit: t is in units of d
    size = jnp.array([1.0, 0.5, 0.25])
    assert np.isclose(intersect.hit_sphere(o, d, size, 0.0), 2.0)
    assert np.isclose(intersect.hit_ellipsoid(o, d, size, 0.0), (5 - 0.25) / 2)
    assert np.isclose(intersect.hit_box(o, d, size, 0.0), (5 - 0.25) / 2)
    assert np.isclose(intersect.hit_cylinder(o, d, size, 0.0), (5 - 0.5) / 2)
    assert np.isclose(intersect.hit_capsule(o, d, size, 0.0), (5 - 1.5) / 2)
    assert np.isclose(intersect.hit_plane(o, d, size, 0.0), 2.5)
    # A ray starting inside reports the exit; one pointing away misses.
    assert np.isclose(intersect.hit_sphere(jnp.zeros(3), d, size, 0.0), 0.5)
    assert np.isinf(intersect.hit_box(o, -d, size, 0.0))
    tri = intersect.hit_triangles(o, d, jnp.array([-1.0, -1.0, 1.0]), jnp.array([3.0, 0, 0]),
                                  jnp.array([0, 3.0, 0]), jnp.array(True), 0.0)
    assert np.isclose(tri[0], 2.0) and np.isclose(tri[1] + tri[2], 2 / 3)


def test_fast_shading_math_matches_numpy():
    from envs_mjx.render import shading

    base = np.concatenate([np.linspace(1e-6, 1.0, 20001), np.geomspace(1e-30, 1.0, 500)])
    for expo in (1.0, 3.7, 64.0, 128.0):
        got = np.asarray(shading.spec_pow(jnp.asarray(base, jnp.float32), jnp.float32(expo)))
        np.testing.assert_allclose(got, base ** expo, rtol=3e-4, atol=1e-30)
    v = np.geomspace(1e-12, 1e6, 20001)
    got = np.asarray(shading.rsqrt(jnp.asarray(v, jnp.float32)))
    np.testing.assert_allclose(got, 1.0 / np.sqrt(v), rtol=5e-7)


def test_mesh_edge_functions_match_moller_trumbore(jit_render):
    # The renderer's camera-space edge-function test against intersect.hit_triangles (the
    # textbook ray-triangle test) over every pixel ray, on a torus seen at a slant.
    v, f, _ = torus()
    xml = f"""<mujoco><asset><mesh name="t" vertex="{_fmt(v)}" face="{_fmt(f)}"/></asset>
      <worldbody><body euler="20 35 0"><geom type="mesh" mesh="t"/></body>
      <camera name="c" pos=".1 -.8 .5" xyaxes="1 0 0 0 .5 .87"/></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    ctx = render.make_context(m, "c", H, W)
    out = jit_render(ctx, poses(d))
    # Reference: world-frame rays against world-frame triangles, nearest t per pixel.
    rays = np.stack([ctx.rays[0], ctx.rays[1], -np.ones(H * W)], -1) @ d.cam_xmat.reshape(3, 3).T
    rot, pos = d.geom_xmat[0].reshape(3, 3), d.geom_xpos[0]
    world = lambda a: np.asarray(a[0]) @ rot.T  # noqa: E731
    v0, e1, e2 = world(ctx.mesh.v0) + pos, world(ctx.mesh.e1), world(ctx.mesh.e2)
    t, _, _ = intersect.hit_triangles(
        d.cam_xpos[0][:, None, None], rays.T[:, :, None], v0.T[:, None], e1.T[:, None],
        e2.T[:, None], np.asarray(ctx.mesh.valid[0])[None], ctx.znear)
    t_ref = np.asarray(t).min(axis=1).reshape(H, W)
    hit_ref = t_ref <= ctx.zfar
    seg = np.asarray(out.segmentation)
    assert hit_ref.mean() > 0.1 and (seg >= 0).mean() > 0.1
    assert ((seg >= 0) == hit_ref).mean() >= 0.999
    both = (seg >= 0) & hit_ref
    np.testing.assert_allclose(np.asarray(out.depth)[both], t_ref[both], rtol=1e-4)


CHECKER_FLOOR_XML = """<mujoco><asset>
  <texture name="checker" type="2d" builtin="checker" rgb1=".15 .3 .75" rgb2=".95 .95 .95"
           width="256" height="256"/>
  <material name="floor" texture="checker" texrepeat="10 10" texuniform="true"/></asset>
<worldbody><light pos="0 -2 6" dir="0 .3 -1" directional="true"/>
  <geom name="floor" type="plane" size="40 40 .1" material="floor"/>
  <camera name="front" pos=".3 -2.6 1.5" xyaxes="1 0 0 0 .5 .866"/>
  <camera name="turned" pos="1.1 -2.4 1.2" xyaxes=".866 .5 0 -.25 .433 .866"/>
</worldbody></mujoco>"""


def test_checker_floor_is_filtered_like_mujoco(jit_render):
    # HalfCheetah's / Ant's floor seen as their cameras see it. One nearest texel per pixel turns
    # the far checker into moire (measured mean |rgb error| 54-57 of 255 on the envs' floors);
    # the box-filtered checker follows MuJoCo's mipmapped texture (~3 here, without shadows).
    m = mujoco.MjModel.from_xml_string(CHECKER_FLOOR_XML)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    for camera in ("front", "turned"):
        with mujoco.Renderer(m, H, W) as r:
            r.update_scene(d, camera)
            ref = r.render().astype(np.float32)
        ctx = render.make_context(m, camera, H, W)
        assert ctx.checker_geoms == (0,)
        errors = []
        for c in (ctx, ctx.replace(checker_geoms=())):  # filtered, then nearest texel
            out = jit_render(c, poses(d))
            floor = np.asarray(out.segmentation) == 0
            assert floor.mean() > 0.5
            errors.append(np.abs(np.asarray(out.rgb, np.float32) - ref)[floor].mean())
        assert errors[0] < 8.0 and errors[1] > 25.0, (camera, errors)


def test_square_wave_mean_matches_numeric_average():
    from envs_mjx.render import shading

    u = np.linspace(-3.0, 3.0, 1001, dtype=np.float32)
    for width in (0.005, 0.05, 0.3, 1.0, 2.7):
        got = np.asarray(shading.square_wave_mean(jnp.asarray(u), jnp.float32(width)))
        x = u[:, None] + width * (np.arange(2000)[None] + 0.5) / 2000 - width / 2
        want = np.where(x - np.floor(x) < 0.5, 1.0, -1.0).mean(1)
        tol = 2.0 if width < 1e-2 else 2e-3  # point sample below min_width: only the sign
        assert np.abs(got - want).max() <= tol, (width, np.abs(got - want).max())
        if width < 1e-2:
            assert np.mean(np.sign(got) == np.sign(want)) > 0.98


def test_shaded_primitives_look_like_mujocos():
    """Shaded RGB against mujoco.Renderer on the pixels both give the same geom, per geom over
    4 random poses: the mean |difference| of every primitive type and the mesh stays small, and
    well below what the geom's flat colour would score (so the shading, not just the colour,
    matches). Measured at commit time: 9–23 of 255 shaded against 38–170 flat (the mesh is
    textured); the rest is MuJoCo's scene light and shadows, which the ray caster does not draw
    (docs/render.md)."""
    m = mujoco.MjModel.from_xml_string(all_geoms_xml())
    d = mujoco.MjData(m)
    ctx = render.make_context(m, "fixed", H, W)
    shaded, flat = {}, {}
    for p in random_poses(m, d, np.random.default_rng(0), 4):
        d.geom_xpos[:], d.geom_xmat[:] = p.geom_xpos, p.geom_xmat.reshape(-1, 9)
        d.cam_xpos[:], d.cam_xmat[:] = p.cam_xpos, p.cam_xmat.reshape(-1, 9)
        ref_seg = mujoco_segmentation(m, d, "fixed")
        with mujoco.Renderer(m, H, W) as r:
            r.update_scene(d, "fixed")
            ref = r.render().astype(float)
        out = jax.jit(render.render)(ctx, p)
        seg, rgb = np.asarray(out.segmentation), np.asarray(out.rgb).astype(float)
        for g in range(2, m.ngeom):  # the free bodies' geoms (0, 1: floor and tile)
            both = (seg == g) & (ref_seg == g)
            if both.sum() < 10:
                continue
            colour = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
            shaded.setdefault(g, []).append(np.abs(rgb[both] - ref[both]).mean())
            flat.setdefault(g, []).append(np.abs(colour[:3] * 255 - ref[both]).mean())
    assert set(m.geom_type[list(shaded)]) == {2, 3, 4, 5, 6, 7}, "every type seen"
    for g in shaded:
        assert np.mean(shaded[g]) < 30, (g, shaded[g])
        assert np.mean(shaded[g]) < 0.5 * np.mean(flat[g]), (g, shaded[g], flat[g])
