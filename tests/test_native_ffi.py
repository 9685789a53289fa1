"""The native backend's XLA custom call equals its pure_callback fallback, and its programs are
stored in and loaded from JAX's persistent compilation cache by a new process."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hdt.envs as E
from hdt.envs import native_ffi
from hdt.envs.physics import NativePhysics

pytestmark = pytest.mark.skipif(not native_ffi.available(), reason="no C++ compiler for the custom call")


@pytest.mark.parametrize("agent,task", [("point", "maze"), ("arm3", "push1"), ("ant", "steps")])
def test_custom_call_equals_callback(agent, task):
  env = E.make(agent, task, backend="native")
  m, fs = env.mj_model, env.agent.frame_skip
  cf = env.agent.contact_forces
  ffi = NativePhysics(m, fs, use_ffi=True, contact_forces=cf)
  cb = NativePhysics(m, fs, use_ffi=False, contact_forces=cf)
  ps = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 5)).physics
  acts = jax.random.uniform(jax.random.PRNGKey(1), (20, 5, m.nu), minval=-1, maxval=1)

  def roll(phys):
    step = lambda p, u: (jax.vmap(phys.step)(p, u),) * 2
    fwd = jax.vmap(phys.forward)(ps.time, ps.qpos, ps.qvel)
    return fwd, jax.lax.scan(step, ps, acts)[1]

  a, b = jax.jit(lambda: roll(ffi))(), jax.jit(lambda: roll(cb))()
  for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
  assert float(jnp.abs(a[1].qpos[-1] - ps.qpos).max()) > 1e-3  # the robots did move


@pytest.mark.parametrize("use_ffi", [True, False])
def test_masked_step_passes_inactive_envs_through_and_steps_the_rest(use_ffi):
  env = E.make("arm_point", "push1", backend="native")
  phys = NativePhysics(env.mj_model, env.agent.frame_skip, use_ffi=use_ffi)
  ps = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 6)).physics
  u = jax.random.uniform(jax.random.PRNGKey(1), (6, env.mj_model.nu), minval=-1, maxval=1)
  on = jnp.array([True, False, True, True, False, False])
  full = jax.jit(jax.vmap(phys.step))(ps, u)
  masked = jax.jit(jax.vmap(phys.step))(ps, u, on)
  none = jax.jit(jax.vmap(phys.step))(ps, u, jnp.zeros(6, bool))
  for f, m, p, n in zip(jax.tree.leaves(full), jax.tree.leaves(masked), jax.tree.leaves(ps), jax.tree.leaves(none)):
    f, m, p, n = map(np.asarray, (f, m, p, n))
    np.testing.assert_array_equal(m[np.asarray(on)], f[np.asarray(on)])
    np.testing.assert_array_equal(m[~np.asarray(on)], p[~np.asarray(on)])
    np.testing.assert_array_equal(n, p)
  assert float(jnp.abs(full.qvel - ps.qvel).max()) > 1e-3  # stepping does change the state


def test_unbatched_step_and_model_id_is_content_hash():
  env = E.make("point", "reach", backend="native")
  s = env.step(env.reset(jax.random.PRNGKey(0)), jnp.ones(env.action_size))
  assert np.isfinite(np.asarray(s.physics.qpos)).all()
  assert native_ffi.model_id(env.mj_model) == native_ffi.model_id(E.make("point", "reach").mj_model)
  assert native_ffi.model_id(env.mj_model) != native_ffi.model_id(E.make("point", "maze").mj_model)


_CACHED_RUN = textwrap.dedent("""
  import jax, numpy as np
  hits = []
  jax.monitoring.register_event_listener(lambda e, **kw: hits.append(e) if e == "/jax/compilation_cache/cache_hits" else None)
  import hdt.envs as E
  env = E.make("point", "reach", backend="native")
  def run(keys):
    s = jax.vmap(env.reset)(keys)
    return jax.lax.scan(lambda s, _: (jax.vmap(env.step)(s, jax.numpy.ones((4, 2))), None), s, None, 30)[0].physics.qpos
  out = jax.jit(run)(jax.random.split(jax.random.PRNGKey(0), 4))
  print("RESULT", len(hits), float(np.asarray(out).sum()))
""")


def test_native_programs_are_persistently_cached(tmp_path):
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
             JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
  runs = [subprocess.run([sys.executable, "-c", _CACHED_RUN], env=env, capture_output=True, text=True, check=True)
          for _ in range(2)]  # (other libraries print to stdout on import: pick our line)
  outs = [next(l for l in r.stdout.splitlines() if l.startswith("RESULT")).split()[1:] for r in runs]
  assert int(outs[0][0]) == 0 and int(outs[1][0]) > 0, outs  # the second process loads, not compiles
  assert outs[0][1] == outs[1][1]  # and the loaded program finds its model by content hash
