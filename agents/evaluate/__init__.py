r"""Compare agents on the same seeds: ``python -m agents.evaluate``.

.. code-block:: bash

    python -m agents.evaluate --agents random,frontier,revisit,info_gain,runs/ppo/model.zip \
        --episodes 10 --seed 1000 [--env SeifExplore-v2] [--env-kwargs '{"layout": "loop"}'] [--out DIR] \
        [--bootstrap 10000] [--workers N | --ray auto|ADDRESS] [--no-batch] [--batch-size 100] [--threads 1] \
        [--resume OUT] [--quiet]

Every agent runs ``N`` episodes on the seeds ``S, S+1, …, S+N−1`` of the task
``--env`` (an env id, or a family for its newest version; the same seeds for
every agent: ``env.reset(seed=s)`` fixes the landmark layout, the start and
all noise of episode ``s``). An agent is what :func:`agents.load_agent`
builds: a name of :data:`agents.BASELINES` (``random`` is seeded with ``S``),
a shipped policy's name (:data:`agents.loading.SHIPPED_POLICIES`), the path
of a Stable-Baselines3 / sb3-contrib ``.zip`` (PPO, RecurrentPPO or SAC,
:func:`agents.sb3_agent.sb3_algorithm`; the observation normalisation saved
with it is applied; labelled by the file's stem, or by its folder's name for
``model.zip`` / ``best_model.zip``) or ``rllib:CHECKPOINT``; any of them may
be labelled ``LABEL=SPEC``. Every agent acts with ``deterministic=True``.
``--env-kwargs`` is a JSON object passed to ``gym.make`` (it may hold
``max_episode_steps``). The episodes run in this process, on ``--workers N``
local processes or as Ray tasks on a cluster (``--ray``; :mod:`agents.parallel`,
``docs/training/ray.md``), with the same rows but for the measured
``decision_time_ms``.

An agent's episodes run as the sub-envs of one native vector env
(:class:`~seif_gym.envs.vector.SeifExploreVectorEnv`, ``--batch-size`` of them
at most), each from ``reset(seed=s)``, and the agent acts for all of them in
one call: a saved policy's forward pass is batched with each row's bits those
of that row alone (:meth:`~agents.sb3_agent.SB3Agent.exact_batches`), so the
rows equal those of one episode at a time (``--no-batch``).
:mod:`~agents.evaluate.batched` says which agents and tasks run so; the others
(``random``, ``info_gain``, RLlib checkpoints; the ``-v0`` tasks and other
configurations the vector env runs as single envs) run one episode at a time,
and the progress says so once. Each process computes on ``--threads`` BLAS and
torch threads (default one: a small network's forward pass gains nothing from
more, and loses much when other processes want the cores).

The package's modules: :mod:`~agents.evaluate.rollout` (running the
episodes), :mod:`~agents.evaluate.batched` (running them batched),
:mod:`~agents.evaluate.statistics` (intervals and paired
differences), :mod:`~agents.evaluate.report` (tables, plot, files, stored
runs), :mod:`~agents.evaluate.journal` (the kept tasks of a run, its
manifest), :mod:`~agents.evaluate.schema` (the names below) and
:mod:`~agents.evaluate.cli` (the command line). Every public name of them is
importable from :mod:`agents.evaluate`.

The metrics come from the env's ``info`` (the ground truth is read here, by
the evaluation, never by the agents). Written to ``--out`` (default
``eval``):

``results.csv``
    One row per agent × episode, columns :data:`RESULT_COLUMNS`:

    ==================== ==========================================================
    column               meaning
    ==================== ==========================================================
    ``agent``            agent label (baseline name, or the ``.zip``'s file stem)
    ``episode``          0 … N−1
    ``seed``             seed of ``env.reset``
    ``final_map_error``  ``info["map_error"]`` at the end, metres (mean over all
                         true landmarks of the capped error, unmapped = ``d_cap``)
    ``initial_map_error`` ``info["map_error"]`` after ``reset``
    ``pose_rmse``        RMS over all observations of the episode (reset
                         included) of ``‖true_pose[:2] − pose_estimate[:2]‖``, m
    ``landmarks_mapped`` ``info["landmarks_mapped"]`` at the end
    ``landmarks_total``  ``info["landmarks_total"]``
    ``return``           sum of the rewards
    ``length``           steps of the episode
    ``wall_contacts``    steps with ``info["wall_contact"]``
    ``diverged``         1 if the episode ended by divergence, else 0
    ``decision_time_ms`` mean wall time of one decision, milliseconds: of one
                         ``predict`` call, or of a batched call divided by
                         the sub-envs it acted for
    ==================== ==========================================================

``summary.json``
    ``{key: …}`` with the keys :data:`SUMMARY_KEYS`: ``schema_version``
    (:data:`SCHEMA_VERSION`), ``env_id``, ``env_kwargs``, ``episodes``,
    ``seeds`` (list), ``metrics`` (:data:`SUMMARY_METRICS`), ``agents``.
    ``agents[label]`` has the keys :data:`AGENT_KEYS`: ``spec`` (as given on
    the command line), ``episodes``, one entry per metric of
    :data:`SUMMARY_METRICS`, each a dict with the keys :data:`STAT_KEYS`
    (``mean``, ``std`` (``ddof=1``), ``ci95_low``, ``ci95_high``,
    ``ci95_half_width``, ``n``; the 95 % confidence interval of the mean
    from Student's t, ``null`` for a single episode), and
    ``map_error_over_time``, a dict with the keys :data:`CURVE_KEYS`:
    ``step`` (0 … longest length), ``mean``, ``ci95_low``, ``ci95_high``
    of ``info["map_error"]`` over the episodes at each step (an episode that
    ended early keeps its last value). ``diverged`` is the fraction of
    diverged episodes.

    ``paired`` compares every agent with the *best baseline* (the baseline of
    lowest mean final map error) on the same seeds (:func:`paired_comparison`):
    a dict with the keys :data:`PAIRED_KEYS`: ``metric``
    (``final_map_error``), ``reference`` (the best baseline; ``null`` when no
    agent is a baseline), ``confidence`` (0.95), ``bootstrap`` (resamples of
    the optional bootstrap interval, 0 for none) and ``agents``: label -> the
    keys :data:`PAIRED_STAT_KEYS` and ``verdict``, for every agent but the
    reference. ``mean`` is the mean per-seed difference (agent minus
    reference; negative is better), ``std`` its standard deviation
    (``ddof=1``), ``ci95_low`` / ``ci95_high`` its Student-t interval,
    ``bootstrap_ci95_low`` / ``bootstrap_ci95_high`` a percentile bootstrap
    interval (``null`` without ``--bootstrap``), ``n`` the number of seeds.
    ``verdict`` (:func:`paired_verdict`) is ``beats`` only when the t
    interval lies below zero (``worse`` above it, ``tie (interval holds 0)``
    otherwise).

    ``stored_run`` is the folder of the earlier run whose episodes joined
    this one (``--stored-run``, :func:`load_stored_run`), ``null`` for none.

``map_error.png``
    The mean map error over time per agent with its 95 % band.

``manifest.json``
    Written last (:func:`~agents.evaluate.journal.write_manifest`): the
    command, its configuration, the version and every file with its SHA-256.
    A folder without one holds no finished run, and :func:`read_run` (so
    ``--stored-run``) refuses it.

Every file is written whole or not at all (:mod:`seif_gym._atomic`). While a
run goes on, its folder holds ``.journal/``, each task's episodes kept as it
finishes (:class:`~agents.evaluate.journal.RunJournal`): a run killed at any
moment goes on with the same arguments and ``--resume OUT``, running only
what it had not finished, to the files of a run left alone (but for
``decision_time_ms``). Every input is checked before any episode runs and
before anything is written (:mod:`agents.cli`): a bad one exits with status 2
and one line naming the option or the file.

The Markdown table of the means ± CI half-widths and the table of the
paired differences (:func:`paired_table`) are printed and also written to
``summary.md``. Progress goes to stderr (``--quiet``: none).

From Python: :func:`evaluate_agents` returns ``(rows, summary)`` as above,
:func:`write_outputs` writes the files.
"""

from __future__ import annotations

from agents.evaluate.batched import BATCHED_BASELINES, batch_env, batch_refusal, run_batched_episodes
from agents.evaluate.cli import main
from agents.evaluate.journal import (
    ResumeError,
    RunFinished,
    RunJournal,
    UnfinishedRunError,
    read_manifest,
    verify_manifest,
    write_manifest,
)
from agents.evaluate.report import (
    load_stored_run,
    markdown_table,
    paired_table,
    plot_map_error,
    read_run,
    save_figure,
    signed,
    signed_interval,
    write_outputs,
)
from agents.evaluate.rollout import (
    DEFAULT_BATCH_SIZE,
    build_agent,
    evaluate_agents,
    limited_threads,
    make_evaluation_env,
    run_episode,
    without_exact_nees,
)
from agents.evaluate.schema import (
    AGENT_KEYS,
    CURVE_KEYS,
    INTEGER_COLUMNS,
    PAIRED_KEYS,
    PAIRED_METRIC,
    PAIRED_STAT_KEYS,
    READABLE_SCHEMA_VERSIONS,
    RECIPE_KEYS,
    RECIPE_STAT_KEYS,
    RESULT_COLUMNS,
    SCHEMA_VERSION,
    STAT_KEYS,
    SUMMARY_KEYS,
    SUMMARY_METRICS,
    TABLE_COLUMNS,
)
from agents.evaluate.statistics import (
    mean_ci,
    mean_curve,
    paired_comparison,
    paired_difference,
    paired_verdict,
    recipe_comparison,
    recipe_difference,
)

# kept importable from here, where they lived before agents.loading and agents.sb3_agent
from agents.loading import agent_label, agent_labels, check_agent_spec
from agents.sb3_agent import SB3Agent, sb3_algorithm

__all__ = [
    "RESULT_COLUMNS",
    "SUMMARY_KEYS",
    "SUMMARY_METRICS",
    "AGENT_KEYS",
    "STAT_KEYS",
    "CURVE_KEYS",
    "PAIRED_METRIC",
    "PAIRED_KEYS",
    "PAIRED_STAT_KEYS",
    "SCHEMA_VERSION",
    "INTEGER_COLUMNS",
    "READABLE_SCHEMA_VERSIONS",
    "RECIPE_STAT_KEYS",
    "RECIPE_KEYS",
    "TABLE_COLUMNS",
    "SB3Agent",
    "sb3_algorithm",
    "agent_label",
    "agent_labels",
    "check_agent_spec",
    "build_agent",
    "make_evaluation_env",
    "without_exact_nees",
    "run_episode",
    "DEFAULT_BATCH_SIZE",
    "BATCHED_BASELINES",
    "batch_env",
    "batch_refusal",
    "run_batched_episodes",
    "limited_threads",
    "mean_ci",
    "mean_curve",
    "paired_difference",
    "paired_verdict",
    "paired_comparison",
    "recipe_difference",
    "recipe_comparison",
    "read_run",
    "load_stored_run",
    "RunJournal",
    "ResumeError",
    "RunFinished",
    "UnfinishedRunError",
    "read_manifest",
    "verify_manifest",
    "write_manifest",
    "save_figure",
    "evaluate_agents",
    "write_outputs",
    "plot_map_error",
    "markdown_table",
    "paired_table",
    "signed",
    "signed_interval",
    "main",
]
