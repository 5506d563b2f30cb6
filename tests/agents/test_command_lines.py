"""One vocabulary across the commands of ``agents``: tasks, agents, counts, and the old spellings that still work."""

from __future__ import annotations

import pytest

import seif_gym
from agents import benchmark, robustness
from agents.cli import resolve_task, resolve_tasks, task_families
from agents.evaluate.cli import _parser as evaluate_parser
from agents.loading import SHIPPED_POLICIES


class _Stop(Exception):
    """Raised by a stand-in to stop a command once its arguments are known."""


def test_a_task_is_an_env_id_or_a_family_for_its_newest_version():
    assert resolve_task("SeifExploreLoop-v1") == "SeifExploreLoop-v1"
    assert resolve_task("SeifExploreLoop") == f"SeifExploreLoop-v{seif_gym.LATEST_VERSION}"
    assert resolve_task("SeifExploreMRCLAM") == "SeifExploreMRCLAM-v1"  # its newest, not the newest of all
    assert resolve_task("SeifExplore", version=0) == "SeifExplore-v0"
    assert resolve_tasks(["SeifExplore", "SeifExplore-v2", "SeifExploreBudget"]) == [
        "SeifExplore-v2", "SeifExploreBudget-v2"]  # fmt: skip
    assert task_families()["SeifExploreMRCLAM"] == (0, 1)
    with pytest.raises(ValueError, match="SeifExploreMRCLAM has no version 2"):
        resolve_task("SeifExploreMRCLAM", version=2)
    with pytest.raises(ValueError, match="env_id: unknown env 'Nope'.*SeifExploreMRCLAM-v0/v1"):
        resolve_task("Nope")
    with pytest.raises(TypeError, match="env_id must be a str"):
        resolve_task(2)  # type: ignore[arg-type]


def test_the_help_of_each_comparison_lists_tasks_and_agents():
    helps = {"evaluate": evaluate_parser().format_help(), "benchmark": benchmark._parser().format_help(),
             "robustness": robustness._parser().format_help()}  # fmt: skip
    for command, text in helps.items():
        flat = " ".join(text.split())
        for word in ("info_gain", *SHIPPED_POLICIES, "LABEL=SPEC", "PATH.zip", "rllib:CHECKPOINT",
                     "SeifExploreLoopBudget-v0/v1/v2", "SeifExploreMRCLAM-v0/v1"):  # fmt: skip
            assert word in flat, (command, word)
    assert "uniform, clustered, loop" in " ".join(helps["robustness"].split())


def test_benchmark_takes_tasks_and_the_old_variants_spelling(monkeypatch, tmp_path, capsys):
    seen: list[list[str]] = []

    def run(variants, *_args, **_kwargs):
        seen.append(list(variants))
        raise _Stop

    monkeypatch.setattr(benchmark, "run_benchmark", run)
    with pytest.raises(_Stop):
        benchmark.main(["--tasks", "SeifExploreMRCLAM,SeifExploreLoop-v1", "--out", str(tmp_path)])
    with pytest.warns(FutureWarning, match="--variants is deprecated: use --tasks"), pytest.raises(_Stop):
        benchmark.main(["--variants", "SeifExploreLoop", "--out", str(tmp_path)])
    with pytest.raises(_Stop):
        benchmark.main(["--version", "1", "--out", str(tmp_path)])
    assert seen == [["SeifExploreMRCLAM-v1", "SeifExploreLoop-v1"], [f"SeifExploreLoop-v{seif_gym.LATEST_VERSION}"],
                    benchmark.default_variants(1)]  # fmt: skip
    with pytest.raises(SystemExit):
        benchmark.main(["--tasks", "SeifExploreMRCLAM", "--version", "2"])
    assert "--tasks: env_id: SeifExploreMRCLAM has no version 2 (versions 0, 1)" in capsys.readouterr().err


def test_robustness_takes_agents_and_episodes_and_the_old_spellings(monkeypatch, tmp_path):
    seen: list[tuple] = []

    def record(policies, layouts, seeds, steps, filters, **kwargs):
        seen.append((policies, layouts, seeds, kwargs["env_id"]))
        raise _Stop

    monkeypatch.setattr(robustness, "evaluate", record)
    with pytest.raises(_Stop):
        robustness.main(["--agents", "frontier", "--episodes", "2", "--out", str(tmp_path)])
    with pytest.warns(FutureWarning) as warned, pytest.raises(_Stop):
        robustness.main(["--policies", "frontier", "--seeds", "2", "--env", "SeifExploreLoop", "--layouts", "loop",
                         "--out", str(tmp_path)])  # fmt: skip
    assert {str(w.message) for w in warned} == {"--policies is deprecated: use --agents",
                                                "--seeds is deprecated: use --episodes"}  # fmt: skip
    assert seen == [(["frontier"], None, [0, 1], seif_gym.LATEST_ID),
                    (["frontier"], ["loop"], [0, 1], f"SeifExploreLoop-v{seif_gym.LATEST_VERSION}")]  # fmt: skip


def test_robustness_records_the_tasks_own_layout_by_default():
    rows, _ = robustness.evaluate(["frontier"], None, [0], 3, ["ekf"], env_id="SeifExploreLoop-v2")
    assert [(row["policy"], row["layout"], row["filter"]) for row in rows] == [("frontier", "loop", "ekf")]


def test_showcase_takes_a_shipped_policy_by_name(capsys):
    from agents.showcase import main as showcase_main

    with pytest.raises(SystemExit):
        showcase_main(["--policy", "nobody", "--episodes", "1"])
    assert "--policy: 'nobody' is neither a shipped policy (ppo," in capsys.readouterr().err


def test_showcase_spreads_its_episodes_like_evaluate(capsys):
    from agents.showcase import main as showcase_main

    with pytest.raises(SystemExit):
        showcase_main(["--help"])
    out = capsys.readouterr().out
    assert "--workers" in out and "--ray" in out
    with pytest.raises(SystemExit):
        showcase_main(["--workers", "0", "--episodes", "1"])
    assert "--workers" in capsys.readouterr().err


def test_every_long_command_takes_resume_and_checks_its_input_first(capsys):
    """``--resume OUT`` on each comparison; the shared checks of ``agents.cli`` behind them."""
    import argparse

    from agents import cli, showcase

    helps = {"evaluate": evaluate_parser().format_help(), "benchmark": benchmark._parser().format_help(),
             "robustness": robustness._parser().format_help()}  # fmt: skip
    with pytest.raises(SystemExit):
        showcase.main(["--help"])
    helps["showcase"] = capsys.readouterr().out
    for command, text in helps.items():
        assert "--resume OUT" in text, command
    assert cli.seed("0") == 0 and cli.positive_int("3") == 3 and cli.non_negative_int("0") == 0
    for convert, text in ((cli.seed, "-1"), (cli.positive_int, "0"), (cli.non_negative_int, "-1"), (cli.seed, "1.5")):
        with pytest.raises(argparse.ArgumentTypeError):
            convert(text)
    assert cli.check_seeds(3, 2) == [3, 4]
    with pytest.raises(ValueError, match="--seed: the seeds"):
        cli.check_seeds(cli.MAX_SEED, 2)
