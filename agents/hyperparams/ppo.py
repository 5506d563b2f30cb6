"""``agents/hyperparams/ppo.yml`` by module name, for rl-zoo3's ``--conf-file agents.hyperparams.ppo``."""

from agents.hyperparams import load

#: One entry per env id, as in ``ppo.yml``.
hyperparams = load("ppo")
