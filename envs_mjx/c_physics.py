"""C MuJoCo substeps inside a jitted, vmapped env step: the CPU physics backend.

On a CPU, MJX's JAX physics is many times slower than C MuJoCo stepping the same model
(benchmarks/RESULTS.md; docs/notes/rearrange.md). `CPhysics` steps a batch in C instead:
`mujoco.rollout` (a C++ thread pool, one MjData per thread, each env with its own MjModel)
called through `jax.pure_callback`, so the env's step stays one pure function that `jax.jit`,
`jax.vmap` and `lax.scan` take as before. The renderer, the LD state, the reward and everything
around the substeps stay JAX.

What the callback carries across: qpos, qvel and the time (through MuJoCo's full-physics state);
ctrl is held for the call's substeps. Not carried: the constraint solver's warm start (each call
starts cold; the arms' test against a plain `mj_step` loop measures what that changes) and
actuator activations (models with `na > 0` are refused). Only the positions and velocities come
back, and on request the bias forces and the poses the caller reads (computed in C after the
rollout): contacts and constraint forces are not returned.

Under `jax.vmap` the callback is called once with every batch axis (`vmap_method=
"broadcast_all"`), so a batch of envs is one rollout across the pool's threads. On a GPU the
callback copies the batch to the host and back each call: use it for CPU runs.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout

FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


class CPhysics:
    """Steps envs in C MuJoCo: env i of a call uses `models[slot[i]]`.

    models: one compiled MjModel per slot (every model the same sizes: nq, nv, nu, na).
    nthread: the thread pool's size (default: the machine's CPU count).
    """

    def __init__(self, models: Sequence[mujoco.MjModel], nthread: int | None = None):
        if not models:
            raise ValueError("CPhysics needs at least one MjModel")
        m = models[0]
        for other in models[1:]:
            sizes = [(a.nq, a.nv, a.nu, a.na) for a in (m, other)]
            if sizes[0] != sizes[1]:
                raise ValueError(f"CPhysics models differ in (nq, nv, nu, na): {sizes}")
        if m.na:
            raise ValueError(f"CPhysics does not carry actuator activations (model has na={m.na})")
        self._models = list(models)
        self.nq, self.nv, self.nu = m.nq, m.nv, m.nu
        # The full-physics state vector is [time, qpos, qvel, (act), mocap, userdata, ...]; a
        # fresh MjData's gives the parts not carried (mocap poses, equality flags) their defaults.
        data = mujoco.MjData(m)
        self._template = np.empty(mujoco.mj_stateSize(m, FULL))
        mujoco.mj_getState(m, data, self._template, FULL)
        self._nthread = max(1, nthread or os.cpu_count() or 1)
        self._pool: rollout.Rollout | None = None  # built at the first call, not per env object
        self._datas: list[mujoco.MjData] = []
        self._scratch_data: dict[int, mujoco.MjData] = {}
        self._lock = threading.Lock()

    def __del__(self):
        pool = getattr(self, "_pool", None)  # absent when __init__ raised
        if pool is not None:
            pool.close()

    def step(
        self, slot: jax.Array, qpos: jax.Array, qvel: jax.Array, ctrl: jax.Array, nstep: int,
        *, bias: bool = False,
    ) -> dict[str, jax.Array]:
        """`nstep` C substeps with `ctrl` held, for one env (any leading batch axes under vmap).

        Returns {"qpos", "qvel"} of the final state; with `bias`, also "qfrc_bias" as the last
        substep computed it (at the state one substep before the end, where `mj_step` and
        `mjx.step` leave it), computed in C: MJX's own kinematics of the Franka scene is slow on
        a CPU under XLA's default options (docs/notes/envs.md), and C needs no XLA program.
        """
        if nstep < 1 or (bias and nstep < 2):
            raise ValueError(f"nstep must be >= {2 if bias else 1}, got {nstep}")
        for name, x, n in (("qpos", qpos, self.nq), ("qvel", qvel, self.nv),
                           ("ctrl", ctrl, self.nu)):
            if jnp.shape(x) != (n,):
                raise ValueError(
                    f"CPhysics.step: {name} must have shape ({n},), got {jnp.shape(x)}"
                )
        shapes = {"qpos": (self.nq,), "qvel": (self.nv,)}
        if bias:
            shapes["qfrc_bias"] = (self.nv,)
        host = functools.partial(self._host, nstep=nstep, bias=bias)
        return jax.pure_callback(
            host,
            {k: jax.ShapeDtypeStruct(v, jnp.float32) for k, v in shapes.items()},
            jnp.asarray(slot, jnp.int32),
            jnp.asarray(qpos, jnp.float32),
            jnp.asarray(qvel, jnp.float32),
            jnp.asarray(ctrl, jnp.float32),
            vmap_method="broadcast_all",
        )

    def poses(self, slot: jax.Array, qpos: jax.Array, names: Sequence[str]) -> dict[str, jax.Array]:
        """MjData fields `names` (e.g. "geom_xpos", "cam_xmat") at qpos, from `mj_kinematics`,
        `mj_comPos` and `mj_camlight` in C; rotation matrices [n, 3, 3] as mjx.Data holds them.
        One env, any leading batch axes under vmap."""
        if jnp.shape(qpos) != (self.nq,):
            raise ValueError(
                f"CPhysics.poses: qpos must have shape ({self.nq},), got {jnp.shape(qpos)}"
            )
        shapes = {name: self._pose_shape(name) for name in names}
        return jax.pure_callback(
            functools.partial(self._host_poses, names=tuple(names)),
            {k: jax.ShapeDtypeStruct(v, jnp.float32) for k, v in shapes.items()},
            jnp.asarray(slot, jnp.int32),
            jnp.asarray(qpos, jnp.float32),
            vmap_method="broadcast_all",
        )

    def _pose_shape(self, name: str) -> tuple[int, ...]:
        value = getattr(self._scratch(0), name, None)
        if not isinstance(value, np.ndarray) or name in ("qpos", "qvel", "qfrc_bias"):
            raise ValueError(f"CPhysics.poses: {name!r} is not a pose field of MjData")
        return (len(value), 3, 3) if name.endswith("xmat") else value.shape

    def _scratch(self, slot: int) -> mujoco.MjData:
        """An MjData per slot's model, for the forward computations after a rollout."""
        if slot not in self._scratch_data:
            self._scratch_data[slot] = mujoco.MjData(self._models[slot])
        return self._scratch_data[slot]

    @staticmethod
    def _flat(slot, *arrays):
        """The callback's inputs (jax Arrays, any leading batch axes) as host numpy arrays with
        one batch axis: (lead shape, slot [n], each array [n, size])."""
        lead = np.shape(arrays[0])[:-1]
        n = int(np.prod(lead, dtype=np.int64))
        slot = np.broadcast_to(np.asarray(slot), lead).reshape(n)
        return lead, slot, *(np.asarray(x).reshape(n, -1) for x in arrays)

    def _host(self, slot, qpos, qvel, ctrl, *, nstep: int, bias: bool):
        lead, slot, qpos, qvel, ctrl = self._flat(slot, qpos, qvel, ctrl)
        n = len(slot)
        state = np.tile(self._template, (n, 1))
        state[:, 1 : 1 + self.nq] = qpos
        state[:, 1 + self.nq : 1 + self.nq + self.nv] = qvel
        control = ctrl[:, None, :].astype(np.float64)
        models = [self._models[s] for s in slot]
        out = {}
        with self._lock:
            if self._pool is None:
                self._pool = rollout.Rollout(nthread=self._nthread)
                self._datas = [mujoco.MjData(self._models[0]) for _ in range(self._nthread)]
            # Checks skipped (every array is built here, C-contiguous float64), outputs given.
            states = np.empty((n, nstep, len(self._template)))
            sensors = np.empty((n, nstep, self._models[0].nsensordata))
            self._pool.rollout(
                models, self._datas, state, np.repeat(control, nstep, axis=1), nstep=nstep,
                skip_checks=True, state=states, sensordata=sensors,
            )
            if bias:
                out["qfrc_bias"] = np.empty((n, self.nv))
                for i in range(n):
                    m, d = models[i], self._scratch(slot[i])
                    mujoco.mj_setState(m, d, states[i, -2], FULL)
                    mujoco.mj_kinematics(m, d)
                    mujoco.mj_comPos(m, d)
                    mujoco.mj_comVel(m, d)
                    mujoco.mj_rne(m, d, 0, out["qfrc_bias"][i])
        last = states[:, -1]
        out["qpos"] = last[:, 1 : 1 + self.nq]
        out["qvel"] = last[:, 1 + self.nq : 1 + self.nq + self.nv]
        return {k: v.astype(np.float32).reshape(*lead, *v.shape[1:]) for k, v in out.items()}

    def _host_poses(self, slot, qpos, *, names: tuple[str, ...]):
        lead, slot, qpos = self._flat(slot, qpos)
        n = len(slot)
        out = {name: np.empty((n, *self._pose_shape(name)), np.float32) for name in names}
        with self._lock:
            for i in range(n):
                m, d = self._models[slot[i]], self._scratch(slot[i])
                d.qpos[:] = qpos[i]
                mujoco.mj_kinematics(m, d)
                mujoco.mj_comPos(m, d)
                mujoco.mj_camlight(m, d)
                for name in names:
                    out[name][i] = getattr(d, name).reshape(out[name].shape[1:])
        return {k: v.reshape(*lead, *v.shape[1:]) for k, v in out.items()}
