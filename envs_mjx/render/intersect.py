"""Ray–primitive and ray–triangle intersection in a geom's local frame: pure, elementwise math.

Conventions: vectors are component-first — `o`, `d`, `size` are anything indexable as
`v[0], v[1], v[2]` (a [3] array, a [3, ...] array, or a tuple of three arrays) whose components
broadcast together. The renderer passes per-geom scalars for `o` and `size` and per-pixel [P]
arrays for `d`, so every test is one fused elementwise loop with pixels as the contiguous axis.
Directions need not be unit length (the renderer keeps the camera-frame z component at -1 so
that `t` is MuJoCo's linear depth). Every `hit_*` returns the smallest `t > tmin` where the ray
meets the surface, or +inf, with the broadcast shape. Every `normal_*` maps a local surface point
(a component tuple) to the (unnormalised) outward local normal, as a tuple of three arrays.
"""

import jax.numpy as jnp

INF = jnp.inf


def _xyz(v):
    return v[0], v[1], v[2]


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _first_root(t0, t1, tmin):
    """Smallest of two candidate distances exceeding tmin, +inf if neither does."""
    t0 = jnp.where(t0 > tmin, t0, INF)
    t1 = jnp.where(t1 > tmin, t1, INF)
    return jnp.minimum(t0, t1)


def _quadratic(a, b, c, tmin):
    """First root > tmin of a t² + 2 b t + c = 0 (half-b form), +inf if none."""
    disc = b * b - a * c
    ok = disc >= 0.0
    sq = jnp.sqrt(jnp.where(ok, disc, 0.0))
    # a > 0 for any non-degenerate ray; guard anyway so a zero never produces NaN.
    inv_a = 1.0 / jnp.where(a > 0.0, a, 1.0)
    # The near root is tried first; the far one only matters for rays starting inside.
    t0, t1 = (-b - sq) * inv_a, (-b + sq) * inv_a
    return jnp.where(ok, jnp.where(t0 > tmin, t0, jnp.where(t1 > tmin, t1, INF)), INF)


def _safe(x):
    """x with magnitudes below 1e-12 replaced by ±1e-12 (same sign): no 0 division, no NaN."""
    return jnp.where(jnp.abs(x) > 1e-12, x, jnp.where(x < 0, -1e-12, 1e-12))


def hit_plane(o, d, size, tmin):
    """Plane z=0 bounded by |x|<=size[0], |y|<=size[1]; a size <= 0 leaves that axis unbounded.

    Two-sided, as MuJoCo draws planes from below too.
    """
    ox, oy, oz = _xyz(o)
    dx, dy, dz = _xyz(d)
    t = -oz / _safe(dz)
    sx, sy = size[0], size[1]
    inside = (((sx <= 0.0) | (jnp.abs(ox + t * dx) <= sx))
              & ((sy <= 0.0) | (jnp.abs(oy + t * dy) <= sy)))
    return jnp.where(inside & (t > tmin), t, INF)


def normal_plane(p, size):
    """Local normal of a plane: +z."""
    del size
    one = jnp.ones_like(p[0])
    return 0.0 * one, 0.0 * one, one


def hit_sphere(o, d, size, tmin):
    """Sphere of radius size[0] at the origin."""
    r = size[0]
    return _quadratic(_dot(d, d), _dot(o, d), _dot(o, o) - r * r, tmin)


def normal_sphere(p, size):
    del size
    return _xyz(p)


def hit_ellipsoid(o, d, size, tmin):
    """Ellipsoid with semi-axes size[0:3]: scaling space maps it to the unit sphere, t unchanged."""
    os_ = tuple(o[i] / size[i] for i in range(3))
    ds = tuple(d[i] / size[i] for i in range(3))
    return _quadratic(_dot(ds, ds), _dot(os_, ds), _dot(os_, os_) - 1.0, tmin)


def normal_ellipsoid(p, size):
    """Outward normal of an ellipsoid: gradient of sum (p/size)²."""
    return tuple(p[i] / (size[i] * size[i]) for i in range(3))


def hit_box(o, d, size, tmin):
    """Box centred at the origin with half-sizes size[0:3] (slab method)."""
    # A zero direction component becomes a tiny one of the same sign: the slab then spans
    # ±huge, which is the right limit, and no NaN (0 * inf) appears.
    near, far = [], []
    for i in range(3):
        inv = 1.0 / _safe(d[i])
        t1 = (-size[i] - o[i]) * inv
        t2 = (size[i] - o[i]) * inv
        near.append(jnp.minimum(t1, t2))
        far.append(jnp.maximum(t1, t2))
    t_near = jnp.maximum(jnp.maximum(near[0], near[1]), near[2])
    t_far = jnp.minimum(jnp.minimum(far[0], far[1]), far[2])
    t = jnp.where(t_near > tmin, t_near, jnp.where(t_far > tmin, t_far, INF))
    return jnp.where(t_near <= t_far, t, INF)


def normal_box(p, size):
    """Outward normal of a box: the face whose slab the point is nearest to leaving."""
    ex, ey, ez = (jnp.abs(p[i]) / size[i] for i in range(3))
    on_x = (ex >= ey) & (ex >= ez)
    on_y = ~on_x & (ey >= ez)
    on_z = ~on_x & ~on_y
    zero = jnp.zeros_like(ex)
    return (jnp.where(on_x, jnp.sign(p[0]), zero), jnp.where(on_y, jnp.sign(p[1]), zero),
            jnp.where(on_z, jnp.sign(p[2]), zero))


def _hit_tube(o, d, radius, half, tmin):
    """Open cylinder x²+y²=radius², |z|<=half."""
    a = d[0] * d[0] + d[1] * d[1]
    b = o[0] * d[0] + o[1] * d[1]
    c = o[0] * o[0] + o[1] * o[1] - radius * radius
    disc = b * b - a * c
    ok = (disc >= 0.0) & (a > 1e-12)
    sq = jnp.sqrt(jnp.where(ok, disc, 0.0))
    inv_a = 1.0 / jnp.where(a > 1e-12, a, 1.0)
    t0, t1 = (-b - sq) * inv_a, (-b + sq) * inv_a
    # Each root only counts where it lands on the finite part of the tube.
    t0 = jnp.where(jnp.abs(o[2] + t0 * d[2]) <= half, t0, INF)
    t1 = jnp.where(jnp.abs(o[2] + t1 * d[2]) <= half, t1, INF)
    return jnp.where(ok, _first_root(t0, t1, tmin), INF)


def hit_capsule(o, d, size, tmin):
    """Capsule: radius size[0], cylinder half-length size[1] along z, hemispherical caps."""
    r, h = size[0], size[1]
    tube = _hit_tube(o, d, r, h, tmin)
    dd = _dot(d, d)
    caps = []
    for sign in (1.0, -1.0):
        oc = (o[0], o[1], o[2] - sign * h)
        caps.append(_quadratic(dd, _dot(oc, d), _dot(oc, oc) - r * r, tmin))
    return jnp.minimum(tube, jnp.minimum(caps[0], caps[1]))


def normal_capsule(p, size):
    """Outward normal of a capsule: from the nearest point of its axis segment."""
    h = size[1]
    return p[0], p[1], p[2] - jnp.clip(p[2], -h, h)


def hit_cylinder(o, d, size, tmin):
    """Closed cylinder: radius size[0], half-length size[1] along z, flat caps."""
    r, h = size[0], size[1]
    tube = _hit_tube(o, d, r, h, tmin)
    dz = d[2]
    inv = 1.0 / _safe(dz)
    caps = []
    for sign in (1.0, -1.0):
        t = (sign * h - o[2]) * inv
        px = o[0] + t * d[0]
        py = o[1] + t * d[1]
        ok = (px * px + py * py <= r * r) & (t > tmin) & (jnp.abs(dz) > 1e-12)
        caps.append(jnp.where(ok, t, INF))
    return jnp.minimum(tube, jnp.minimum(caps[0], caps[1]))


def normal_cylinder(p, size):
    """Outward normal of a closed cylinder: cap or side, whichever surface the point is on."""
    r, h = size[0], size[1]
    rho = jnp.sqrt(p[0] * p[0] + p[1] * p[1])
    on_cap = (jnp.abs(p[2]) - h) > (rho - r)
    zero = jnp.zeros_like(rho)
    return (jnp.where(on_cap, zero, p[0]), jnp.where(on_cap, zero, p[1]),
            jnp.where(on_cap, jnp.sign(p[2]), zero))


def hit_triangles(o, d, v0, e1, e2, valid, tmin):
    """Möller–Trumbore, two-sided: the reference the renderer's edge-function mesh test matches.

    o, d: rays; v0, e1, e2: first vertex and the two edges from it; valid: bool mask of padding
    triangles; all component-first and broadcasting. Returns (t, u, v); t is +inf where missed;
    (u, v) are the barycentric weights of vertices 1 and 2.
    """
    dx, dy, dz = _xyz(d)
    ax, ay, az = _xyz(e1)
    bx, by, bz = _xyz(e2)
    px, py, pz = dy * bz - dz * by, dz * bx - dx * bz, dx * by - dy * bx
    det = ax * px + ay * py + az * pz
    ok = jnp.abs(det) > 1e-14
    inv = 1.0 / jnp.where(ok, det, 1.0)
    sx, sy, sz = o[0] - v0[0], o[1] - v0[1], o[2] - v0[2]
    u = (sx * px + sy * py + sz * pz) * inv
    qx, qy, qz = sy * az - sz * ay, sz * ax - sx * az, sx * ay - sy * ax
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (bx * qx + by * qy + bz * qz) * inv
    hit = ok & valid & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > tmin)
    return jnp.where(hit, t, INF), u, v
