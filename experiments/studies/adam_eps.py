"""How much TF1's Adam (the authors', SB2's ``tf.train.AdamOptimizer``) and optax's differ on the
discriminator (SPEC 8.3, the "Discriminator lr" row).

TF1 puts epsilon on the uncorrected root: ``lr sqrt(1 - b2^t) / (1 - b1^t) m / (sqrt(v) + eps)``; optax
on the corrected one: ``lr m_hat / (sqrt(v_hat) + eps)``. Both train hdt's discriminator on the same
class-balanced batches of real inputs (B: the 3Link LL's, A: the manipulation point mass's, each on its
own reach goals), for the updates of a 400k-step alignment (``DiscConfig`` defaults: one per 8 env steps
until half the run, the authors' decaying lr), from the same init. Prints the largest differences.

  python experiments/studies/adam_eps.py [--low-b zoo:arm3/low_paper] [--low-a zoo:arm_point/low]
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np
import optax

from hdt.agents import discriminator as D
from hdt.transfer.align import collect_offline


EPS = 1e-8  # both optimisers' default epsilon (TF1's and optax's)


def tf1_adam(b1=0.9, b2=0.999, eps=EPS) -> optax.GradientTransformation:
  """tf.compat.v1.train.AdamOptimizer's direction (before its learning rate)."""
  def init(params):
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    return optax.ScaleByAdamState(count=jnp.zeros([], jnp.int32), mu=zeros, nu=zeros)

  def update(g, state, params=None):
    t = state.count + 1
    mu = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, state.mu, g)
    nu = jax.tree_util.tree_map(lambda v, g: b2 * v + (1 - b2) * g * g, state.nu, g)
    c = jnp.sqrt(1 - b2 ** t) / (1 - b1 ** t)
    upd = jax.tree_util.tree_map(lambda m, v: c * m / (jnp.sqrt(v) + eps), mu, nu)
    return upd, optax.ScaleByAdamState(count=t, mu=mu, nu=nu)
  return optax.GradientTransformation(init, update)


def main(argv=None):
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--low-b", default="zoo:arm3/low_paper")
  ap.add_argument("--low-a", default="zoo:arm_point/low")
  ap.add_argument("--lr", type=float, default=3e-4, help="the discriminator lr (PM as A: 3e-4)")
  ap.add_argument("--env-steps", type=int, default=400_000, help="the alignment's length")
  ap.add_argument("--n", type=int, default=40_000, help="inputs collected per class")
  args = ap.parse_args(argv)
  cfg = D.DiscConfig(lr=args.lr)
  key = jax.random.PRNGKey(0)
  x_b = jnp.asarray(collect_offline(args.low_b, args.n, jax.random.fold_in(key, 1)))
  x_a = jnp.asarray(collect_offline(args.low_a, args.n, jax.random.fold_in(key, 2)))
  held = args.n // 10  # the last tenth of each class only measures
  net = D.Discriminator(cfg.hidden_sizes)
  apply = net.apply
  params0 = net.init(jax.random.fold_in(key, 3), x_b[:1])
  T = args.env_steps
  steps = jnp.arange(0, int(cfg.stop * T), cfg.update_every)  # DSAC.learn: step % freq == 0, step < stop T

  def train(opt):
    def body(carry, xs):
      params, st = carry
      s, k = xs
      kb, ki = jax.random.split(k)
      is_b = jax.random.bernoulli(kb, 0.5, (cfg.batch_size,))
      i = jax.random.randint(ki, (cfg.batch_size,), 0, args.n - held)
      x = jnp.where(is_b[:, None], x_b[i], x_a[i])
      labels = jnp.where(is_b, D.B_LABEL, D.A_LABEL)
      g = jax.grad(lambda p: D.disc_loss(apply, p, x, labels)[0])(params)
      upd, st = opt.update(g, st, params)
      lr = D.disc_lr(cfg, s, T)
      params = optax.apply_updates(params, jax.tree_util.tree_map(lambda u: -lr * u, upd))
      root_v = jnp.min(jnp.stack([jnp.min(jnp.sqrt(v)) for v in jax.tree_util.tree_leaves(st.nu)]))
      return (params, st), root_v
    keys = jax.random.split(jax.random.fold_in(key, 4), steps.shape[0])
    (params, st), root_v = jax.jit(lambda: jax.lax.scan(body, (params0, opt.init(params0)), (steps, keys)))()
    return params, np.asarray(root_v)

  (p_optax, rv_optax), (p_tf1, _) = train(optax.scale_by_adam(eps=EPS)), train(tf1_adam())
  x_test = jnp.concatenate([x_b[-held:], x_a[-held:]])
  lab = np.r_[np.full(held, D.B_LABEL), np.full(held, D.A_LABEL)]
  d = {n: np.asarray(jax.nn.sigmoid(apply(p, x_test))).reshape(-1) for n, p in (("optax", p_optax), ("tf1", p_tf1))}
  acc = {n: float(np.mean((v > 0.5) == (lab > 0.5))) for n, v in d.items()}
  flat = lambda p: np.concatenate([np.ravel(v) for v in jax.tree_util.tree_leaves(p)])
  dp = np.abs(flat(p_optax) - flat(p_tf1))
  out = dict(updates=int(steps.shape[0]), lr=args.lr, low_b=args.low_b, low_a=args.low_a,
             held_out_acc=acc, max_abs_dD=float(np.max(np.abs(d["optax"] - d["tf1"]))),
             mean_abs_dD=float(np.mean(np.abs(d["optax"] - d["tf1"]))),
             max_abs_dparam=float(dp.max()), max_abs_param=float(np.abs(flat(p_optax)).max()),
             min_sqrt_v_over_eps=float(rv_optax.min() / EPS),
             min_sqrt_v_over_eps_after_100=float(rv_optax[100:].min() / EPS))
  print(json.dumps(out, indent=1))
  return out


if __name__ == "__main__":
  main()
