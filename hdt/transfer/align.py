"""Discriminative LL alignment (paper Algorithm 1): train B's LL on its reach task with the
authors' discriminator reward ``(1 - w) r + [step > 200] w clip(-2 log D, 0, 10)`` against A's
goal-reaching behaviour (``bot_transfer/algs/discrim_sac.py``, see :mod:`hdt.agents.discriminator`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np

from hdt.agents import discriminator as disc_lib
from hdt.agents.discriminator import DiscConfig
from hdt.agents.sac import SACConfig
from hdt.envs import make
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs
from hdt.transfer.card import AlignedTo, PolicyCard, load_low
from hdt.transfer.runner import Level, RunOptions, RunResult, Stage, Weight, run_stage

# The authors imitate A's best model (hierarchical.py DiscriminatorEnv: load(policy, ..., best=True);
# final when the run kept no best).
IMITATE_PARAMS = "best"
OFFLINE_ENVS = 64  # envs of A's LL run side by side to collect the "fixed" data


@dataclasses.dataclass(frozen=True)
class AlignSpec:
  """What an LL is aligned to (Algorithm 1): A's LL run and how B's discriminator sees it.

  imitate: A's LL run directory (or ``zoo:NAME``); imitate_seed: its seed; imitate_params: its "best"
    evaluation's parameters (default, the authors') or its "final" ones (``aligned_to["params"]``
    records which were used).
  disc: the discriminator; default :func:`hdt.transfer.configs.disc_config` of A's agent (the paper's
    hyper-parameters by A; offline data for nav, online for manipulation). Its ``data``
    (:mod:`hdt.agents.discriminator`): "offline" and "online", A's LL runs in A's reach env (episodes of
    ``disc.expert_time_limit`` steps) alongside each of B's envs; "fixed", ``n_offline`` transitions
    of A's deterministic LL on uniformly sampled goals (:func:`collect_offline`, key
    ``PRNGKey(offline_seed)``), shared by all seeds.
  """

  imitate: str | Path
  disc: DiscConfig | None = None
  n_offline: int = 20_000
  imitate_seed: int = 0
  imitate_params: str = IMITATE_PARAMS
  offline_seed: int = 0

  def __post_init__(self):
    ckpt.check_which(self.imitate_params, "imitate_params")
    if self.disc is not None and not isinstance(self.disc, DiscConfig):
      raise ValueError(f"disc={self.disc!r}: pass a hdt.agents.discriminator.DiscConfig (or None: A's paper values)")

  @classmethod
  def of(cls, imitate) -> "AlignSpec":
    """``imitate`` as an AlignSpec: itself, or A's run directory with the defaults."""
    return imitate if isinstance(imitate, AlignSpec) else cls(imitate)


def align_low(agent: str, imitate: AlignSpec | str | Path, config: SACConfig | None = None, *,
              backend: str = "auto", options: RunOptions = RunOptions(), **env_overrides) -> RunResult:
  """Goal-conditioned LL of ``agent`` aligned to the LL of agent A that ``imitate`` names (A's run
  directory, or an :class:`AlignSpec`). Writes a level-"low" run whose card records ``aligned_to``
  (A's run, agent, seed, parameters) and ``discriminator`` (the DiscConfig). backend: the physics
  backend; options: how it runs (:class:`hdt.transfer.runner.RunOptions`)."""
  return run_stage(align_stage(agent, imitate, config, backend, **env_overrides), options)


def align_stage(agent: str, imitate: AlignSpec | str | Path, config: SACConfig | None = None,
                backend: str = "auto", **env_overrides) -> Stage:
  """The stage of :func:`align_low`: B's reach env and LL config, the discriminator plug-in against
  A's data, and a card that records A."""
  configs.check_config(config, allow_none=True)
  spec = AlignSpec.of(imitate)
  params_a, card_a, fn_a = load_low(spec.imitate, spec.imitate_seed, spec.imitate_params)
  disc = configs.disc_config(card_a.agent) if spec.disc is None else spec.disc
  env = make(agent, "reach", backend=backend, **env_overrides)
  config = configs.stage_default("low", backend, agent) if config is None else config
  card_a.check_imitated_by(PolicyCard.from_env(env, "low", config, env_overrides=env_overrides))
  tau_scale = float(card_a.delta_max or 1.0) if disc.scale_inputs else 1.0
  if disc.data != "fixed":
    limit = {"ll_horizon": disc.expert_time_limit} if disc.expert_time_limit else {}
    env_a = card_a.make_env("reach", backend, **limit)
    expert = disc_lib.OnlineExpert(env_a, fn_a, params_a["policy"])
    al = disc_lib.make_alignment(disc, None, config.total_env_steps, config.num_envs,
                                 tau_scale=tau_scale, expert=expert)
  else:
    tau_a = _policy_inputs(card_a.make_env("reach", backend), fn_a, params_a["policy"], spec.n_offline,
                           jax.random.PRNGKey(spec.offline_seed), OFFLINE_ENVS, disc.include_z)
    al = disc_lib.make_alignment(disc, tau_a, config.total_env_steps, config.num_envs,
                                 tau_scale=tau_scale)
  aligned_to = AlignedTo(spec.imitate, agent=card_a.agent, seed_index=spec.imitate_seed, params=card_a.loaded,
                         params_env_steps=card_a.loaded_env_steps,
                         n_offline=int(spec.n_offline) if disc.data == "fixed" else 0,
                         offline_seed=spec.offline_seed, tau_scale=tau_scale,
                         sha256=ckpt.content_hash(spec.imitate, spec.imitate_seed))
  card = PolicyCard.from_env(env, "low", config, env_overrides=env_overrides, aligned_to=aligned_to,
                             discriminator=dataclasses.asdict(disc))
  return Stage(env, config, card, f"align {agent}<-{card_a.agent}", plugins=(al.plugin,),
               # kept with the LL so the alignment can be inspected (load_discriminator) or resumed
               save_extra=lambda ts: {"discriminator": ts.aux["discriminator"].params}, point_card=_point_card,
               legacy_meta={"discriminator": disc_lib.ADDED_FIELDS})


def _point_card(card: PolicyCard, hyper: dict) -> PolicyCard:
  """The card of a grid point over the discriminator's ``disc_weight`` (its initial weight w0)."""
  if disc_lib.WEIGHT not in hyper:
    return card
  disc = dict(card.extra["discriminator"], weight=hyper[disc_lib.WEIGHT])
  return card.replace(extra=dict(card.extra, discriminator=disc))


def load_discriminator(aligned_run, seed_index: int = 0):
  """(logit_fn(x) -> logit of "x came from B", card) of an aligned LL's saved discriminator; ``x``
  (:func:`hdt.agents.discriminator.disc_input`) in raw goal-space units (the saved net saw
  x / tau_scale)."""
  params, meta = ckpt.load(aligned_run, seed_index)
  card = PolicyCard.from_json(meta, aligned_run)
  if "discriminator" not in params or "discriminator" not in card.extra or card.aligned_to is None:
    raise ckpt.CheckpointError(f"{aligned_run} holds no discriminator: it is not an aligned LL "
                               f"(train one with train_low(agent, imitate=A_run))")
  net = disc_lib.Discriminator(tuple(card.extra["discriminator"]["hidden_sizes"]))
  scale = float(card.aligned_to.tau_scale or 1.0)
  return (lambda tau: net.apply(params["discriminator"], np.asarray(tau, np.float32) / scale)), card


def collect_offline(low_run_dir, n: int, key, backend: str = "auto", num_envs: int = OFFLINE_ENVS,
                    seed_index: int = 0, include_z: bool = True, which: str = IMITATE_PARAMS) -> np.ndarray:
  """(n, 6) discriminator inputs ``(g - s_t, g - s_{t+1}, z)`` ((n, 4) without z) of A's saved LL
  (deterministic actions) on its reach task (uniform goals in its goal box, the LL training episode
  structure), ``num_envs`` envs in parallel; z is the relative goal of A's own episode. ``which``:
  A's "best" or "final" parameters."""
  params, card, fn = load_low(low_run_dir, seed_index, which)
  env = card.make_env("reach", backend)
  return _policy_inputs(env, fn, params["policy"], n, key, num_envs, include_z)


def _policy_inputs(env, fn, policy, n: int, key, num_envs: int, include_z: bool) -> np.ndarray:
  """:func:`collect_offline` for an LL already loaded (``fn(policy, obs)``) and its reach ``env``."""
  steps = -(-int(n) // num_envs)
  v_reset, v_step = jax.vmap(env.reset), jax.vmap(env.step)
  size = disc_lib.TAU_SIZE + (disc_lib.Z_SIZE if include_z else 0)

  @jax.jit
  def rollout(key):
    s0 = v_reset(jax.random.split(key, num_envs))

    def step(s, _):
      nxt = v_step(s, fn(policy, s.obs))
      return nxt, disc_lib.disc_input(s.obs, nxt.next_obs, s.task["t"]["z"] if include_z else None)

    _, x = jax.lax.scan(step, s0, None, length=steps)
    return x.reshape(-1, size)

  return np.asarray(rollout(key))[:n]


def _check_disc_weight(value, stage: dict) -> None:
  """The discriminator's initial weight must be one its DiscConfig accepts ([0, 1])."""
  disc = AlignSpec.of(stage["imitate"]).disc if stage.get("imitate") is not None else None
  dataclasses.replace(disc or DiscConfig(), weight=value)


ALIGN = Level("align", align_stage, needs=("agent", "imitate"), sac_level="low",
              weights=(Weight(disc_lib.WEIGHT, check=_check_disc_weight),))
