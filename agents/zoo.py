"""rl-zoo3's scripts with the SeifExplore envs registered: ``python -m agents.zoo SCRIPT [ARGS...]``.

.. code-block:: bash

    python -m agents.zoo train --algo ppo --env SeifExplore-v2 -n 100000 --eval-freq -1
    python -m agents.zoo enjoy --algo ppo --env SeifExplore-v2 -f logs --no-render -n 400
    python -m agents.zoo record_video --algo ppo --env SeifExplore-v2 -f logs -n 400

``rl_zoo3.train`` and ``rl_zoo3.enjoy`` take ``--gym-packages seif_gym``,
and need nothing from here. ``rl_zoo3.record_video`` (2.9) has no such option
and cannot make an env it does not find registered (``--env
seif_gym:ID`` fails in its Atari check); this module imports ``seif_gym``
and then runs the script unchanged, as ``python -m rl_zoo3.SCRIPT ARGS``
would. ``train`` without ``--conf-file`` reads the project's config
(``agents.hyperparams.<algo>``) rather than rl-zoo3's own, which has no
SeifExplore entries.
"""

from __future__ import annotations

import runpy
import sys
from collections.abc import Sequence

#: The rl-zoo3 modules this runs (``rl_zoo3.<name>``).
SCRIPTS: tuple[str, ...] = ("train", "enjoy", "record_video", "record_training")

_USAGE = f"usage: python -m agents.zoo {{{','.join(SCRIPTS)}}} [ARGS...]  (the script's own --help for its arguments)"


def _algo(arguments: Sequence[str]) -> str:
    """The value of ``--algo`` in ``arguments`` (rl-zoo3's default ``ppo``)."""
    for i, argument in enumerate(arguments):
        if argument == "--algo" and i + 1 < len(arguments):
            return arguments[i + 1]
        if argument.startswith("--algo="):
            return argument.partition("=")[2]
    return "ppo"


def main(argv: Sequence[str] | None = None) -> None:
    """Run ``rl_zoo3.<SCRIPT>`` as ``__main__`` with ``seif_gym`` imported; ``argv`` defaults to ``sys.argv[1:]``."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    if not arguments or arguments[0] not in SCRIPTS:
        raise SystemExit(_USAGE)
    script, rest = arguments[0], arguments[1:]
    import seif_gym  # noqa: F401  (registers the envs before the script looks them up)

    if script == "train" and not any(a in ("-conf", "--conf-file") or a.startswith("--conf-file=") for a in rest):
        rest = [*rest, "--conf-file", f"agents.hyperparams.{_algo(rest)}"]
    sys.argv = [f"rl_zoo3.{script}", *rest]
    runpy.run_module(f"rl_zoo3.{script}", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
