"""Finetuning a transferred high level on a new low level, optionally KL-regularised (SPEC section 4).

``finetune_high(high=A's HL run, low=B's LL run, task, spec=FinetuneSpec(...))`` trains SAC on the HL
env of ``task`` over B's frozen LL, starting the policy from A's HL and adding ``w * KL(pi_B || pi_A)``
(pre-tanh diagonal Gaussians, closed form) to the actor loss, the weight ``w`` annealed linearly from
``kl_weight`` (the paper's beta) to ``1e-5 kl_weight`` (KLSAC's floor) over the first ``anneal_frac``
of training. ``kl_weight=0`` is plain finetuning.

Learning rates (:func:`start_fields`): KL finetuning uses the task's (paper Appendix D: 0.01 Waypoint and
manipulation, 0.001 Maze); plain finetuning keeps A's own, as the paper compares ("the original learning
rate of the policy tended to perform best") and the authors' ``scripts/finetune_high_level.py`` does.

The other baselines need no new code: "HL from scratch on B's LL" is
:func:`hdt.transfer.pipeline.train_high`, "Full" is :func:`hdt.transfer.pipeline.train_full`.

Start (``init="sac"``, default, as the authors' ``scripts/finetune_high_level_kl.py``, which loads
A's whole stable-baselines SAC with ``bot_transfer/utils/loader.py:load`` and sets
``learning_starts = 0``): every seed starts from A's policy, both critics, target critics and log
temperature, with no uniform-random warm-up. As in SB2's ``load`` (only the trainable variables are
saved), the Adam states, the update counter and the replay buffer start fresh. ``init="policy",
learning_starts=None`` restores hdt's earlier start: A's policy only, fresh critics at
``config.init_alpha``, and the config's random warm-up.
HLs saved before ``target_q`` / ``log_alpha`` were kept fall back (with a warning) to A's critics as
targets and alpha = ``config.init_alpha``.

Seeds: the HL seed of index ``i`` starts from A's HL seed ``i % n_A`` (its final parameters, as the script's
``load(args.high, ..., best=False)``). The frozen KL reference is A's seed ``reference_seed``
(default 0) for every seed, by default its best evaluation's parameters (KLSAC ``setup_model``:
``load_from_name(kl_policy, best=True)``; final when the run kept no best), kept per seed in the training state
(:func:`hdt.agents.kl.kl_plugin`). Both the start from A and the KL term are plug-ins of one trainer
(:mod:`hdt.agents.plugins`). A's observation statistics, if it has some (saved beside its
parameters), are B's starting statistics, and the KL reference applies its own.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from hdt.agents import train as sac_train
from hdt.agents.kl import MODES, WEIGHT as KL_WEIGHT, kl_plugin
from hdt.agents.plugins import Plugin
from hdt.agents.sac import SACConfig, make_optimizers
from hdt.transfer import checkpoint as ckpt
from hdt.transfer import configs
from hdt.transfer.card import FinetunedFrom, LowRef, PolicyCard, check_level
from hdt.transfer.pipeline import high_env_with_low, sac_extras
from hdt.transfer.runner import Level, RunOptions, RunResult, Stage, Weight, run_stage

INITS = ("sac", "policy")
# The authors start finetuning from A's final model and tie it to A's best (module docstring).
INIT_PARAMS = "final"
REFERENCE_PARAMS = "best"


def load_high_sac(high: str | Path, which: str = "final"):
  """(params stacked over A's seeds: "policy", "q" and, when saved, "target_q", "log_alpha", "obs_norm"; metas)
  of a saved HL, checked to be a high level; ``which``: its "final" parameters (as the authors'
  finetune scripts) or its "best" evaluation's."""
  params, metas = ckpt.load_all(high, which)
  check_level(metas[0].get("level"), high, "high", "finetune_high")
  return params, metas


def load_high(high: str | Path, which: str = "final"):
  """(policy params stacked over A's seeds, metas) of a saved HL, checked to be a high level."""
  params, metas = load_high_sac(high, which)
  return params["policy"], metas


def _check_fits(name, loaded, fresh, high):
  if jax.tree.structure(loaded) != jax.tree.structure(fresh) or any(
      a.shape != b.shape for a, b in zip(jax.tree.leaves(loaded), jax.tree.leaves(fresh))):
    raise ckpt.CheckpointError(f"the {name} parameters in {high} do not fit this SAC (another "
                               f"architecture or observation/action size)")


def start_from_a(agent, a_params, config, high, init: str = "sac"):
  """``agent`` (one seed's fresh SACState) with A's SAC of one seed (``a_params``, no seed axis) put
  in: the policy and its observation statistics, and with ``init="sac"`` also both critics, target
  critics and log_alpha (fresh Adam states for all)."""
  f32 = lambda tree: jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), tree)
  pi_opt, q_opt, a_opt = make_optimizers(config)
  policy = f32(a_params["policy"])
  _check_fits("policy", policy, agent.policy_params, high)
  agent = agent.replace(policy_params=policy, policy_opt_state=pi_opt.init(policy),
                        policy_ema_params=None if agent.policy_ema_params is None else policy)
  if agent.obs_norm is not None:  # the statistics the policy was trained with
    norm = f32(a_params[ckpt.NORM])
    _check_fits("observation statistics", norm, agent.obs_norm, high)
    agent = agent.replace(obs_norm=norm)
  if init == "policy":
    return agent
  q = f32(a_params["q"])
  _check_fits("critic", q, agent.q_params, high)
  target_q = f32(a_params["target_q"]) if "target_q" in a_params else q
  _check_fits("target critic", target_q, agent.target_q_params, high)
  log_alpha = f32(a_params["log_alpha"]) if "log_alpha" in a_params else agent.log_alpha
  return agent.replace(q_params=q, target_q_params=target_q, q_opt_state=q_opt.init(q),
                       log_alpha=jnp.reshape(log_alpha, agent.log_alpha.shape),
                       alpha_opt_state=a_opt.init(log_alpha))


def start_plugin(a_params, config, high, init: str = "sac") -> Plugin:
  """A plug-in whose init starts the seed of index ``i`` from A's seed ``i % n_A`` (:func:`start_from_a`;
  ``a_params``: A's parameters stacked over its n_A seeds)."""
  if init == "sac" and "q" not in a_params:
    raise ckpt.CheckpointError(f"{high} keeps only its policy (a policy-only zoo entry), and finetuning starts "
                               f"from A's whole SAC: finetune from its run directory, or re-export it with "
                               f"hdt zoo export --keep-sac")
  missing = [k for k in ("target_q", "log_alpha") if k not in a_params]
  if init == "sac" and missing:
    print(f"warning: {high} has no saved {' or '.join(missing)} (an HL saved before they were kept): "
          f"finetuning starts from A's critics as targets and alpha={config.init_alpha}", file=sys.stderr)
  wanted = ("policy", ckpt.NORM) if init == "policy" else ("policy", "q", "target_q", "log_alpha", ckpt.NORM)
  per_seed = {k: jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), a_params[k]) for k in wanted if k in a_params}
  n_a = jax.tree.leaves(per_seed["policy"])[0].shape[0]

  def init_fn(key, agent, seed_index):
    a = jax.tree.map(lambda x: x[seed_index % n_a], per_seed)
    return start_from_a(agent, a, config, high, init), {}

  return Plugin(name="start_from_a", init=init_fn, scales_with_budget=False)


def check_kl_weight(kl_weight) -> None:
  """Refuses (one line) a KL weight that is not a finite number >= 0."""
  if isinstance(kl_weight, bool) or not isinstance(kl_weight, (int, float, np.number)) or \
      not (kl_weight >= 0 and np.isfinite(kl_weight)):
    raise ValueError(f"kl_weight={kl_weight!r}: the KL weight must be a finite number >= 0 (0 = plain finetuning)")


def check_anneal_frac(anneal_frac) -> None:
  """Refuses (one line) an ``anneal_frac`` that is not a fraction of training, in [0, 1]."""
  if isinstance(anneal_frac, (bool, np.bool_)) or not isinstance(anneal_frac, (int, float, np.number)) \
      or not 0 <= anneal_frac <= 1:
    raise ValueError(f"anneal_frac={anneal_frac!r}: must be in [0, 1], the fraction of training over which "
                     f"the KL weight decays to 0 (e.g. 0.5)")


PLAIN_LR_FIELDS = ("actor_lr", "critic_lr", "alpha_lr")


def start_fields(card_a: PolicyCard, task: str, kl_weight: float | None = None) -> dict:
  """SACConfig fields finetuning takes from A's HL (``card_a``): its network and SAC kind, since every
  seed starts from A's whole SAC; and, for plain finetuning (``kl_weight`` 0), A's own learning rates
  (the module docstring). None: the task's KL weight, which is never 0."""
  sac = card_a.sac
  out = dict(hidden_sizes=tuple(card_a.hidden_sizes), value_net=bool(sac.get("value_net", False)),
             critic_layer_norm=bool(sac.get("critic_layer_norm", False)))
  if kl_weight == 0:
    default = configs.high_config(task)  # an HL whose card records no learning rate trained at the paper's
    out |= {k: float(sac.get(k, getattr(default, k))) for k in PLAIN_LR_FIELDS}
  return out


@dataclasses.dataclass(frozen=True)
class FinetuneSpec:
  """How A's HL is finetuned on B (module docstring); checked when made, one line per bad field.

  kl_weight: initial weight of the KL term (the paper's beta); None: the task's, as the paper (1 for
    Waypoint and manipulation, 0.01 for Maze and Steps, :func:`configs.finetune_params`); 0 = plain
    finetuning.
  anneal_frac: the weight goes linearly to ``1e-5 kl_weight`` at ``anneal_frac * config.total_env_steps``
    env steps (:func:`hdt.agents.kl.linear_anneal`).
  mode: "forward" KL(pi_B || pi_A) (paper) or "reverse" KL(pi_A || pi_B); mean_only: only the means are
    tied (the authors' kl_type="mean"), see :func:`hdt.agents.kl.make_kl_term`.
  lr: if given, overrides actor, critic and temperature learning rates of the config.
  init: "sac" (default, the authors'): start from A's policy, critics, target critics and temperature;
    "policy": A's policy only, fresh critics and temperature (see the module docstring).
  learning_starts: env steps of uniform-random actions before learning; 0 (default) as the authors'
    finetuning script; None keeps ``config.learning_starts``.
  reference_seed: A's seed used as the frozen KL reference for every seed; reference_params: which of
    its parameters, "best" (default, the authors') or "final".
  """

  kl_weight: float | None = None
  anneal_frac: float = 0.5
  mode: str = "forward"
  mean_only: bool = False
  lr: float | None = None
  init: str = "sac"
  learning_starts: int | None = 0
  reference_seed: int = 0
  reference_params: str = REFERENCE_PARAMS

  def __post_init__(self):
    if self.kl_weight is not None:
      check_kl_weight(self.kl_weight)
    check_anneal_frac(self.anneal_frac)
    if self.mode not in MODES:
      raise ValueError(f"mode={self.mode!r}: use 'forward' (KL(pi_B || pi_A)) or 'reverse' (KL(pi_A || pi_B))")
    if self.init not in INITS:
      raise ValueError(f"init={self.init!r}: use 'sac' (A's whole SAC) or 'policy' (A's policy only)")
    ckpt.check_which(self.reference_params, "reference_params")

  def for_task(self, task: str) -> "FinetuneSpec":
    """This spec with the task's KL weight where it has none (the one place that default is read)."""
    if self.kl_weight is not None:
      return self
    return dataclasses.replace(self, kl_weight=configs.finetune_params(task)["kl_weight"])


def finetune_high(high: str | Path, low: LowRef | str | Path, task: str, config: SACConfig | None = None, *,
                  spec: FinetuneSpec = FinetuneSpec(), backend: str = "auto", options: RunOptions = RunOptions(),
                  **task_overrides) -> RunResult:
  """SAC on ``task``'s HL env over the LL ``low`` (a run directory or a :class:`LowRef`, as in
  ``train_high``), initialised from (and KL-tied to) the HL in ``high``, as ``spec`` says
  (:class:`FinetuneSpec`).

  config: SAC config; default :func:`configs.finetune_config` of ``task`` (the task's finetuning
    learning rate, the paper's) with A's hidden sizes and SAC kind.
  backend: the physics backend; options: how it runs (:class:`hdt.transfer.runner.RunOptions`; a
    resumed run restarts from its saved state, not from A's HL).
  """
  return run_stage(finetune_stage(high, low, task, config, spec, backend, **task_overrides), options)


def finetune_stage(high: str | Path, low: LowRef | str | Path, task: str, config: SACConfig | None = None,
                   spec: FinetuneSpec = FinetuneSpec(), backend: str = "auto", **task_overrides) -> Stage:
  """The stage of :func:`finetune_high`: B's HL env, the start-from-A and KL plug-ins, and a card that
  records A."""
  configs.check_config(config, allow_none=True)
  if not isinstance(spec, FinetuneSpec):
    raise ValueError(f"spec={spec!r}: pass a hdt.transfer.finetune.FinetuneSpec")
  spec = spec.for_task(task)
  kl_weight, reference_seed = spec.kl_weight, spec.reference_seed
  a_params, a_metas = load_high_sac(high, INIT_PARAMS)
  n_a = len(a_metas)
  if not 0 <= reference_seed < n_a:
    raise ValueError(f"reference_seed={reference_seed}: {high} has seeds 0..{n_a - 1}")
  ref_meta = a_metas[reference_seed]
  if kl_weight > 0 and spec.reference_params != INIT_PARAMS:
    ref_params, ref_metas = load_high_sac(high, spec.reference_params)
    ref_meta = ref_metas[reference_seed]
  else:
    ref_params = a_params

  card_a = PolicyCard.from_json(a_metas[0], high)
  env, low = high_env_with_low(task, low, backend, **(card_a.obs_layout.task_options() | task_overrides))
  a_norm = ckpt.NORM in a_params  # A's observation statistics, saved beside its policy
  a_vnet = "v" in a_params["q"]  # A ran SB2's SAC (SACConfig.value_net)
  a_ln = bool(card_a.sac.get("critic_layer_norm", False))
  if config is None:
    config = configs.stage_default("finetune", backend, task=task, **(
        start_fields(card_a, task, kl_weight) | dict(normalize_observations=a_norm, value_net=a_vnet)))
  if spec.init == "sac" and config.value_net != a_vnet:
    raise ckpt.CheckpointError(f"{high} was trained with value_net={a_vnet} and finetuning starts from its "
                               f"critics: pass --value-net {a_vnet} (or init='policy')")
  if spec.init == "sac" and config.critic_layer_norm != a_ln:
    raise ckpt.CheckpointError(f"{high} was trained with critic_layer_norm={a_ln} and finetuning starts from "
                               f"its critics: pass --critic-layer-norm {a_ln} (or init='policy')")
  card_b = lambda config, **extra: PolicyCard.from_env(env, "high", config, low=low, task_overrides=task_overrides,
                                                       **extra)
  card_a.check_finetunes_to(card_b(config).replace(source=low.path))
  if spec.lr is not None:
    config = configs.replace(config, actor_lr=spec.lr, critic_lr=spec.lr, alpha_lr=spec.lr)
  if spec.learning_starts is not None:
    config = dataclasses.replace(config, learning_starts=int(spec.learning_starts))

  anneal_steps = spec.anneal_frac * config.total_env_steps

  # Plug-ins of one trainer: every seed starts from A's SAC (or policy), with fresh optimiser states
  # and replay, and (kl > 0) keeps its own copy of the KL reference.
  plugins = [start_plugin(a_params, config, high, spec.init)]
  if kl_weight > 0:
    reference = jax.tree.map(lambda x: x[reference_seed], ref_params["policy"])
    reference_norm = jax.tree.map(lambda x: x[reference_seed], ref_params.get(ckpt.NORM))
    policy_apply = sac_train.make_networks(env, config).policy_apply  # pure: the trainer's own is the same
    plugins.append(kl_plugin(policy_apply, reference, kl_weight, anneal_steps, spec.mode, spec.mean_only,
                             reference_norm))

  kl_tied = kl_weight > 0
  finetuned_from = FinetunedFrom(high, agent=card_a.agent, task=card_a.task, params=ckpt.params_label(a_metas),
                                 sha256=ckpt.content_hash(high), seeds=n_a,
                                 reference_seed=reference_seed,
                                 reference_params=ref_meta.get("params", "final") if kl_tied else None,
                                 reference_params_env_steps=ref_meta.get("params_env_steps") if kl_tied else None)
  card = card_b(config, finetuned_from=finetuned_from, init=spec.init, kl_weight=float(kl_weight), mode=spec.mode,
                mean_only=bool(spec.mean_only), anneal_frac=float(spec.anneal_frac),
                anneal_env_steps=float(anneal_steps))
  label = f"finetune {card_a.agent}->{env.env.agent.name} {task} kl_weight={kl_weight:g}"
  # without the KL plug-in nothing reads the budget: a plain finetuning run extends like any SAC run
  budget_meta = () if kl_weight > 0 else ("anneal_env_steps",)
  return Stage(env, config, card, label, plugins=tuple(plugins), save_extra=sac_extras, budget_meta=budget_meta)


def _kl_for_points(stage: dict, values: list) -> dict:
  """Points of one program share one KL plug-in, which exists only for a weight > 0: built with their
  largest weight (each point's own is its hyper value)."""
  spec = stage.get("spec", FinetuneSpec())
  return stage | {"spec": dataclasses.replace(spec, kl_weight=max(values) or 1.0)}


FINETUNE = Level("finetune", finetune_stage, needs=("high", "low", "task"),
                 weights=(Weight(KL_WEIGHT, check=lambda value, stage: check_kl_weight(value),
                                 prepare=_kl_for_points),))
