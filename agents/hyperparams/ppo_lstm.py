"""``agents/hyperparams/ppo_lstm.yml`` by module name, for rl-zoo3's ``--conf-file agents.hyperparams.ppo_lstm``."""

from agents.hyperparams import load

#: One entry per env id, as in ``ppo_lstm.yml``.
hyperparams = load("ppo_lstm")
