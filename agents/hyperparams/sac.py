"""``agents/hyperparams/sac.yml`` by module name, for rl-zoo3's ``--conf-file agents.hyperparams.sac``."""

from agents.hyperparams import load

#: One entry per env id, as in ``sac.yml``.
hyperparams = load("sac")
