"""Ray–primitive and ray–triangle intersection in a geom's local frame: pure, broadcasting math.

Conventions: `o` and `d` are ray origins and directions already expressed in the geom frame,
with shapes broadcasting to [..., 3]; directions need not be unit length (the renderer keeps the
camera-frame z component at -1 so that `t` is MuJoCo's linear depth). Every `hit_*` returns the
smallest `t > tmin` where the ray meets the surface, or +inf, with the broadcast leading shape.
Every `normal_*` maps a local surface point to the (unnormalised) outward local normal.
"""

import jax.numpy as jnp

INF = jnp.inf


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _first_root(t0, t1, tmin):
    """Smallest of two candidate distances exceeding tmin, +inf if neither does. [...]"""
    t0 = jnp.where(t0 > tmin, t0, INF)
    t1 = jnp.where(t1 > tmin, t1, INF)
    return jnp.minimum(t0, t1)


def _quadratic(a, b, c, tmin):
    """First root > tmin of a t² + 2 b t + c = 0 (half-b form), +inf if none. [...]"""
    disc = b * b - a * c
    ok = disc >= 0.0
    sq = jnp.sqrt(jnp.where(ok, disc, 0.0))
    # a > 0 for any non-degenerate ray; guard anyway so a zero never produces NaN.
    inv_a = 1.0 / jnp.where(a > 0.0, a, 1.0)
    t = _first_root((-b - sq) * inv_a, (-b + sq) * inv_a, tmin)
    return jnp.where(ok, t, INF)


def hit_plane(o, d, size, tmin):
    """Plane z=0 bounded by |x|<=size[0], |y|<=size[1]; a size <= 0 leaves that axis unbounded.

    o, d: [..., 3]; size: [..., 3] (MuJoCo geom_size). Returns t: [...]. Two-sided, as MuJoCo
    draws planes from below too.
    """
    dz = d[..., 2]
    safe = jnp.where(jnp.abs(dz) > 1e-12, dz, 1e-12)
    t = -o[..., 2] / safe
    p = o + t[..., None] * d
    sx, sy = size[..., 0], size[..., 1]
    inside = ((sx <= 0.0) | (jnp.abs(p[..., 0]) <= sx)) & ((sy <= 0.0) | (jnp.abs(p[..., 1]) <= sy))
    return jnp.where(inside & (t > tmin) & (jnp.abs(dz) > 1e-12), t, INF)


def normal_plane(p, size):
    """Local normal of a plane: +z. p: [..., 3] -> [..., 3]."""
    del size
    return jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0], p.dtype), p.shape)


def hit_sphere(o, d, size, tmin):
    """Sphere of radius size[0] at the origin. o, d, size: [..., 3] -> t: [...]."""
    r = size[..., 0]
    return _quadratic(_dot(d, d), _dot(o, d), _dot(o, o) - r * r, tmin)


def normal_sphere(p, size):
    """Outward normal of a sphere. p: [..., 3] -> [..., 3]."""
    del size
    return p


def hit_ellipsoid(o, d, size, tmin):
    """Ellipsoid with semi-axes size[0:3]: scaling space maps it to the unit sphere, t unchanged."""
    inv = 1.0 / size
    os_, ds = o * inv, d * inv
    return _quadratic(_dot(ds, ds), _dot(os_, ds), _dot(os_, os_) - 1.0, tmin)


def normal_ellipsoid(p, size):
    """Outward normal of an ellipsoid: gradient of sum (p/size)². p: [..., 3] -> [..., 3]."""
    return p / (size * size)


def hit_box(o, d, size, tmin):
    """Axis-aligned box, half-sizes size[0:3] (slab method). o, d, size: [..., 3] -> t: [...]."""
    # Replace zero direction components by a tiny number of the same sign: the slab then spans
    # ±huge, which is the right limit, and no NaN (0 * inf) appears.
    ds = jnp.where(jnp.abs(d) > 1e-12, d, jnp.where(d < 0, -1e-12, 1e-12))
    inv = 1.0 / ds
    t1 = (-size - o) * inv
    t2 = (size - o) * inv
    t_near = jnp.max(jnp.minimum(t1, t2), axis=-1)
    t_far = jnp.min(jnp.maximum(t1, t2), axis=-1)
    t = _first_root(t_near, t_far, tmin)
    return jnp.where(t_near <= t_far, t, INF)


def normal_box(p, size):
    """Outward normal of a box: the face whose slab the point is nearest to leaving."""
    excess = jnp.abs(p) / size
    axis = jnp.argmax(excess, axis=-1)
    return jnp.eye(3, dtype=p.dtype)[axis] * jnp.sign(p)


def _hit_tube(o, d, radius, half, tmin):
    """Open cylinder x²+y²=radius², |z|<=half. [..., 3] -> [...]."""
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = o[..., 0] * d[..., 0] + o[..., 1] * d[..., 1]
    c = o[..., 0] ** 2 + o[..., 1] ** 2 - radius * radius
    disc = b * b - a * c
    ok = (disc >= 0.0) & (a > 1e-12)
    sq = jnp.sqrt(jnp.where(ok, disc, 0.0))
    inv_a = 1.0 / jnp.where(a > 1e-12, a, 1.0)
    t0, t1 = (-b - sq) * inv_a, (-b + sq) * inv_a
    # Each root only counts where it lands on the finite part of the tube.
    z0 = o[..., 2] + t0 * d[..., 2]
    z1 = o[..., 2] + t1 * d[..., 2]
    t0 = jnp.where(jnp.abs(z0) <= half, t0, INF)
    t1 = jnp.where(jnp.abs(z1) <= half, t1, INF)
    return jnp.where(ok, _first_root(t0, t1, tmin), INF)


def hit_capsule(o, d, size, tmin):
    """Capsule: radius size[0], cylinder half-length size[1] along z, hemispherical caps."""
    r, h = size[..., 0], size[..., 1]
    tube = _hit_tube(o, d, r, h, tmin)
    dd = _dot(d, d)
    caps = []
    for sign in (1.0, -1.0):
        oc = o - jnp.stack([jnp.zeros_like(h), jnp.zeros_like(h), sign * h], axis=-1)
        caps.append(_quadratic(dd, _dot(oc, d), _dot(oc, oc) - r * r, tmin))
    return jnp.minimum(tube, jnp.minimum(caps[0], caps[1]))


def normal_capsule(p, size):
    """Outward normal of a capsule: from the nearest point of its axis segment."""
    h = size[..., 1]
    z = jnp.clip(p[..., 2], -h, h)
    return p - jnp.stack([jnp.zeros_like(z), jnp.zeros_like(z), z], axis=-1)


def hit_cylinder(o, d, size, tmin):
    """Closed cylinder: radius size[0], half-length size[1] along z, flat caps."""
    r, h = size[..., 0], size[..., 1]
    tube = _hit_tube(o, d, r, h, tmin)
    dz = d[..., 2]
    safe = jnp.where(jnp.abs(dz) > 1e-12, dz, 1e-12)
    caps = []
    for sign in (1.0, -1.0):
        t = (sign * h - o[..., 2]) / safe
        px = o[..., 0] + t * d[..., 0]
        py = o[..., 1] + t * d[..., 1]
        ok = (px * px + py * py <= r * r) & (t > tmin) & (jnp.abs(dz) > 1e-12)
        caps.append(jnp.where(ok, t, INF))
    return jnp.minimum(tube, jnp.minimum(caps[0], caps[1]))


def normal_cylinder(p, size):
    """Outward normal of a closed cylinder: cap or side, whichever surface the point is on."""
    r, h = size[..., 0], size[..., 1]
    rho = jnp.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2)
    on_cap = (jnp.abs(p[..., 2]) - h) > (rho - r)
    side = p * jnp.array([1.0, 1.0, 0.0], p.dtype)
    cap = jnp.stack([jnp.zeros_like(rho), jnp.zeros_like(rho), jnp.sign(p[..., 2])], axis=-1)
    return jnp.where(on_cap[..., None], cap, side)


def hit_triangles(o, d, v0, e1, e2, valid, tmin):
    """Möller–Trumbore against many triangles, two-sided.

    o, d: [..., 3] rays; v0, e1, e2: [..., 3] first vertex and the two edges from it (broadcast
    against the rays, typically rays [P, 1, 3] vs triangles [T, 3]); valid: [...] bool mask of
    padding triangles. Returns (t, u, v) each [...]; t is +inf where missed; (u, v) are the
    barycentric weights of vertices 1 and 2.
    """
    # Written per component so XLA fuses the whole test into one elementwise loop feeding the
    # caller's min-reduction, instead of materialising [..., 3] temporaries per triangle.
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    ax, ay, az = e1[..., 0], e1[..., 1], e1[..., 2]
    bx, by, bz = e2[..., 0], e2[..., 1], e2[..., 2]
    px, py, pz = dy * bz - dz * by, dz * bx - dx * bz, dx * by - dy * bx
    det = ax * px + ay * py + az * pz
    ok = jnp.abs(det) > 1e-14
    inv = 1.0 / jnp.where(ok, det, 1.0)
    sx, sy, sz = o[..., 0] - v0[..., 0], o[..., 1] - v0[..., 1], o[..., 2] - v0[..., 2]
    u = (sx * px + sy * py + sz * pz) * inv
    qx, qy, qz = sy * az - sz * ay, sz * ax - sx * az, sx * ay - sy * ax
    v = (dx * qx + dy * qy + dz * qz) * inv
    t = (bx * qx + by * qy + bz * qz) * inv
    hit = ok & valid & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > tmin)
    return jnp.where(hit, t, INF), u, v
