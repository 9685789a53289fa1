"""SAC in pure JAX: networks, replay, losses and a vmappable training loop.

    from hdt.agents import SACConfig, make_train, run
"""

from hdt.agents.networks import SACNetworks, make_sac_networks
from hdt.agents.replay import ReplayState, Transition
from hdt.agents.sac import SACConfig, SACState, make_losses, make_update
from hdt.agents.train import RunResult, Trainer, TrainState, make_train, run, seed_keys, vmapped

__all__ = [
    "RunResult",
    "ReplayState",
    "SACConfig",
    "SACNetworks",
    "SACState",
    "TrainState",
    "Trainer",
    "Transition",
    "make_losses",
    "make_sac_networks",
    "make_train",
    "make_update",
    "run",
    "seed_keys",
    "vmapped",
]
