"""Physics backends behind one pure step: MJX (accelerators, the reference) and native MuJoCo (CPUs).

Both map ``PhysicsState -> PhysicsState`` for ``frame_skip`` substeps with the control held, so an
environment never knows which one it runs on. The state is backend-neutral (time, qpos, qvel,
actuator activations, and the sensor readings and optional contact forces of a forward pass at the
final state: ``mj_step`` computes them before it integrates, one substep behind the returned qpos);
the solver warm-start is not carried between environment steps by the native backend. Native MuJoCo runs as an XLA FFI custom call
(``native_ffi.cc``, multi-threaded C, ``mujoco.rollout``'s semantics) with a batched ``vmap_method``, so
it composes with jit, scan and vmap; where no C++ compiler is found it runs ``mujoco.rollout`` behind
``jax.pure_callback`` instead (same results, slower, and never in JAX's persistent compile cache).
``step`` takes an optional ``active`` mask: envs where it is false come back unchanged, and the native
backend does not step them (under ``vmap``, the envs whose HL step already stopped its LL loop).
Why two: on a CPU, contact-rich scenes under MJX run 100-200x slower than native MuJoCo (SPEC 7).
"""

from __future__ import annotations

import copy
import os
import threading
from typing import Literal

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import rollout

from hdt.envs import native_ffi

Backend = Literal["auto", "mjx", "native"]


@struct.dataclass
class PhysicsState:
  time: jax.Array  # ()
  qpos: jax.Array  # (nq,)
  qvel: jax.Array  # (nv,)
  # Absent fields are None rather than empty arrays (orbax does not save zero-size arrays).
  act: jax.Array | None  # (na,) actuator activations (filter servos); None when the model has none
  sensordata: jax.Array  # (nsensordata,) of a forward pass at (qpos, qvel, act)
  cfrc_ext: jax.Array | None  # (nbody * 6,) external contact wrenches at that pass, if asked for
  warmstart: jax.Array  # (nv,) MJX's solver warm-start (qacc_warmstart); the native backend keeps zeros


def resolve_backend(backend: Backend) -> str:
  if backend == "auto":
    return "native" if jax.default_backend() == "cpu" else "mjx"
  if backend not in ("mjx", "native"):
    raise ValueError(f"unknown physics backend {backend!r}: use 'auto', 'mjx' or 'native'")
  return backend


# MJX-only solver settings, applied to a copy of the MjModel (native MuJoCo keeps the MJCF's).
# Under vmap MJX's solver loop runs until the slowest env converges and its line search always runs
# all ls_iterations (a scan of conds, i.e. selects), so MuJoCo's defaults (100 / 50) cost several
# times what these scenes need: Newton with 4 / 6 runs ant, arm3 and quadruped 3-4x faster and
# still passes tests/test_backends.py (benchmarks/mjx_options.py; BENCHMARKS.md, "MJX").
MJX_OPTIONS: dict = dict(iterations=4, ls_iterations=6, solver=None, disable=())


def mjx_model_copy(model: mujoco.MjModel, options: dict | None = None) -> mujoco.MjModel:
  """A copy of ``model`` with the MJX options (``MJX_OPTIONS`` updated by ``options``) applied:
  ``iterations`` / ``ls_iterations`` (int), ``solver`` ("newton" or "cg"), ``disable`` (names of
  mjtDisableBit flags without the prefix, e.g. "eulerdamp"); None keeps the model's value."""
  opts = {**MJX_OPTIONS, **(options or {})}
  if set(opts) - set(MJX_OPTIONS):
    raise ValueError(f"unknown MJX option(s) {sorted(set(opts) - set(MJX_OPTIONS))}")
  m = copy.copy(model)
  if opts["iterations"] is not None:
    m.opt.iterations = opts["iterations"]
  if opts["ls_iterations"] is not None:
    m.opt.ls_iterations = opts["ls_iterations"]
  if opts["solver"] is not None:
    m.opt.solver = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}[opts["solver"]]
  for flag in opts["disable"]:
    m.opt.disableflags |= int(getattr(mujoco.mjtDisableBit, "mjDSBL_" + flag.upper()))
  return m


def _import_mjx():
  """``mujoco.mjx``, imported on first use: it is slow to import (BENCHMARKS.md, "Start-up"), and the
  native backend does not need it. It prints "Failed to import warp ..." to stdout when the
  optional warp package is absent (hdt does not use it), so stdout is muted while it imports."""
  import contextlib
  import io
  with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx
  return mjx


class MJXPhysics:
  """MJX (``impl='jax'``): pure JAX, the accelerator path."""

  name = "mjx"

  def __init__(self, model: mujoco.MjModel, frame_skip: int, options: dict | None = None,
               contact_forces: bool = False):
    self.mj_model = model
    self.frame_skip = frame_skip
    self.contact_forces = contact_forces
    self._mjx = mjx = _import_mjx()
    self.model = mjx.put_model(mjx_model_copy(model, options), impl="jax")
    self._data0 = mjx.make_data(self.model)

  def _observe(self, d) -> PhysicsState:
    d = self._mjx.forward(self.model, d)
    cfrc = None
    if self.contact_forces:
      from mujoco.mjx._src import smooth  # not exported by mujoco.mjx
      cfrc = smooth.rne_postconstraint(self.model, d).cfrc_ext.reshape(-1)
    act = d.act if self.mj_model.na else None
    return PhysicsState(d.time, d.qpos, d.qvel, act, d.sensordata, cfrc, d.qacc_warmstart)

  def _act(self, act):
    return self._data0.act if act is None else act

  def forward(self, time, qpos, qvel, act=None) -> PhysicsState:
    return self._observe(self._data0.replace(time=time, qpos=qpos, qvel=qvel, act=self._act(act)))

  def step(self, ps: PhysicsState, ctrl: jax.Array, active: jax.Array | None = None) -> PhysicsState:
    # Carrying the warm-start matters: without it the solver starts cold every env step and, under
    # vmap, runs until the slowest env converges (measured: ant 79 env steps/s instead of thousands).
    d = self._data0.replace(time=ps.time, qpos=ps.qpos, qvel=ps.qvel, act=self._act(ps.act),
                            qacc_warmstart=ps.warmstart, ctrl=ctrl)
    d = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: self._mjx.step(self.model, d), d)
    return _keep_inactive(self._observe(d), ps, active)


class NativePhysics:
  """Native MuJoCo, batched and multi-threaded: the FFI custom call, or ``mujoco.rollout`` inside
  ``jax.pure_callback`` when the custom call is unavailable or ``use_ffi=False``."""

  name = "native"

  def __init__(self, model: mujoco.MjModel, frame_skip: int, nthread: int | None = None,
               use_ffi: bool | None = None, contact_forces: bool = False):
    self.mj_model = model
    self.frame_skip = frame_skip
    self.contact_forces = contact_forces
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    self._nstate = mujoco.mj_stateSize(model, spec)
    if self._nstate != 1 + model.nq + model.nv + model.na:
      raise NotImplementedError(
          "the native backend packs (time, qpos, qvel, act) only; this model also has mocap "
          "bodies, plugin state or equality flags in its state: use backend='mjx'")
    self._nthread = nthread or min(os.cpu_count() or 1, 8)
    self._datas = [mujoco.MjData(model) for _ in range(self._nthread)]
    self._lock = threading.Lock()  # rollout's MjData are reused across calls
    self.use_ffi = native_ffi.available() if use_ffi is None else use_ffi
    self._model_id = native_ffi.register(model) if self.use_ffi else None
    nc = 6 * model.nbody if contact_forces else 0
    self._sizes = (model.nq, model.nv, model.na, model.nsensordata, nc)
    self._out_shapes = (jax.ShapeDtypeStruct((), jnp.float32),
                        *(jax.ShapeDtypeStruct((n,), jnp.float32) for n in self._sizes))

  def _shapes(self, batch):
    return tuple(jax.ShapeDtypeStruct(batch + s.shape, s.dtype) for s in self._out_shapes)

  def _forward_host(self, time, qpos, qvel, act, ctrl=None):
    """(time, qpos, qvel, act, sensordata, cfrc_ext) of mj_forward at each state (with ``ctrl``
    held, else zero controls), as numpy: what the custom call computes."""
    time, qpos, qvel, act = map(np.asarray, (time, qpos, qvel, act))
    batch, m = np.shape(time), self.mj_model
    t = np.reshape(time, (-1,))
    ctrl = np.zeros((t.shape[0], m.nu)) if ctrl is None else np.reshape(ctrl, (t.shape[0], m.nu))
    ins = [np.reshape(x, (t.shape[0], n)) for x, n in zip((qpos, qvel, act), self._sizes)]
    outs = [np.zeros((t.shape[0], n), np.float32) for n in self._sizes]
    with self._lock:
      d = self._datas[0]
      for i in range(t.shape[0]):
        d.time, d.qpos[:], d.qvel[:], d.act[:] = t[i], ins[0][i], ins[1][i], ins[2][i]
        d.ctrl[:], d.qacc_warmstart[:] = ctrl[i], 0.0
        mujoco.mj_forward(m, d)
        if self.contact_forces:
          mujoco.mj_rnePostConstraint(m, d)
          outs[4][i] = d.cfrc_ext.reshape(-1)
        outs[0][i], outs[1][i], outs[2][i], outs[3][i] = d.qpos, d.qvel, d.act, d.sensordata
    return (np.array(t, np.float32).reshape(batch),
            *(o.reshape(batch + (n,)) for o, n in zip(outs, self._sizes)))

  def _step_host(self, time, qpos, qvel, act, ctrl, active):
    time, qpos, qvel, act, ctrl, active = map(np.asarray, (time, qpos, qvel, act, ctrl, active))
    m, b = self.mj_model, np.size(time)  # (explicit row counts: a (-1, 0) reshape is ambiguous)
    state = np.concatenate([np.reshape(time, (b, 1)), np.reshape(qpos, (b, m.nq)),
                            np.reshape(qvel, (b, m.nv)), np.reshape(act, (b, m.na))],
                           axis=1).astype(np.float64)
    ctrl = np.repeat(np.reshape(ctrl, (b, 1, m.nu)).astype(np.float64), self.frame_skip, axis=1)
    rows = np.flatnonzero(np.reshape(active, (-1,)))  # inactive envs pass through (as the custom call)
    out, n = state.copy(), len(rows)
    if n:
      with self._lock:  # one chunk per thread: per-call dispatch dominates at a few substeps per call
        out_state, _ = rollout.rollout(
            m, self._datas[:n], state[rows], ctrl[rows], nstep=self.frame_skip,
            chunk_size=-(-n // min(n, self._nthread)), persistent_pool=True)
      out[rows] = out_state[:, -1]
    split = np.cumsum([1, m.nq, m.nv])
    t, qp, qv, ac = np.split(out, split, axis=1)
    res = self._forward_host(t.reshape(np.shape(time)), qp, qv, ac, ctrl[:, 0])
    off = np.reshape(active, np.shape(time)) == 0  # as the custom call: zero sensors and forces
    for r in res[4:]:
      r[off] = 0.0
    return res

  def _act(self, time, act):
    return jnp.zeros(jnp.shape(time) + (self.mj_model.na,), jnp.float32) if act is None else act

  def _state(self, out, warmstart) -> PhysicsState:
    t, qpos, qvel, act, sens, cfrc = out
    return PhysicsState(t, qpos, qvel, act if self.mj_model.na else None, sens,
                        cfrc if self.contact_forces else None, warmstart)

  def forward(self, time, qpos, qvel, act=None) -> PhysicsState:
    act = self._act(time, act)
    shapes = self._shapes(jnp.shape(time))
    if self.use_ffi:
      out = jax.ffi.ffi_call(native_ffi.FORWARD_TARGET, shapes, vmap_method="broadcast_all")(
          *_f32(time, qpos, qvel, act), model_id=np.int64(self._model_id),
          cfrc=np.int64(self.contact_forces))
    else:
      out = jax.pure_callback(self._forward_host, shapes, time, qpos, qvel, act,
                              vmap_method="broadcast_all")
    return self._state(out, jnp.zeros_like(qvel))

  def step(self, ps: PhysicsState, ctrl: jax.Array, active: jax.Array | None = None) -> PhysicsState:
    shapes = self._shapes(jnp.shape(ps.time))
    on = jnp.ones_like(ps.time) if active is None else jnp.asarray(active, jnp.float32)
    act = self._act(ps.time, ps.act)
    if self.use_ffi:
      out = jax.ffi.ffi_call(native_ffi.STEP_TARGET, shapes, vmap_method="broadcast_all")(
          *_f32(ps.time, ps.qpos, ps.qvel, act, ctrl, on), model_id=np.int64(self._model_id),
          frame_skip=np.int64(self.frame_skip), cfrc=np.int64(self.contact_forces))
    else:
      out = jax.pure_callback(self._step_host, shapes, ps.time, ps.qpos, ps.qvel, act, ctrl, on,
                              vmap_method="broadcast_all")
    return _keep_inactive(self._state(out, ps.warmstart), ps, active)


def _keep_inactive(new: PhysicsState, old: PhysicsState, active: jax.Array | None) -> PhysicsState:
  """``new`` where ``active``, ``old`` (unstepped, its sensors included) elsewhere."""
  if active is None:
    return new
  return jax.tree.map(lambda n, o: jnp.where(active, n, o), new, old)


def _f32(*xs):
  return tuple(jnp.asarray(x, jnp.float32) for x in xs)


def make_physics(model: mujoco.MjModel, frame_skip: int, backend: Backend = "auto",
                 contact_forces: bool = False):
  """``contact_forces``: also return cfrc_ext (the authors' legged observations read it)."""
  backend = resolve_backend(backend)
  cls = MJXPhysics if backend == "mjx" else NativePhysics
  return cls(model, frame_skip, contact_forces=contact_forces)
