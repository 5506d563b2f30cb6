"""A recipe judged over its training seeds: the crossed interval, its coverage, and ``python -m research.recipe``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from agents import evaluate
from research import recipe

TASK = {"episodes": 3, "seed": 5, "env_id": "SeifExplore-v1", "env_kwargs": {"max_episode_steps": 12}}


def test_recipe_difference_is_the_crossed_estimate_written_out() -> None:
    values = np.array([[0.30, 0.10, 0.55, 0.20], [0.25, 0.20, 0.40, 0.35], [0.50, 0.05, 0.45, 0.30]])
    reference = np.array([0.40, 0.15, 0.50, 0.30])
    d = values - reference
    seed_means = [sum(row) / 4 for row in d]
    episode_means = [sum(d[s][e] for s in range(3)) / 3 for e in range(4)]
    v_s = sum((m - np.mean(seed_means)) ** 2 for m in seed_means) / 2 / 3
    v_e = sum((m - np.mean(episode_means)) ** 2 for m in episode_means) / 3 / 4
    dof = (v_s + v_e) ** 2 / (v_s**2 / 2 + v_e**2 / 3)
    half = stats.t.ppf(0.975, dof) * np.sqrt(v_s + v_e)
    result = evaluate.recipe_difference(values, reference)
    assert tuple(result) == evaluate.RECIPE_STAT_KEYS
    assert result["mean"] == pytest.approx(d.mean(), abs=1e-15)
    assert result["seed_means"] == pytest.approx(seed_means, abs=1e-15)
    assert result["standard_error"] == pytest.approx(np.sqrt(v_s + v_e), rel=1e-12)
    assert result["dof"] == pytest.approx(dof, rel=1e-12)
    assert (result["ci95_low"], result["ci95_high"]) == pytest.approx((d.mean() - half, d.mean() + half), rel=1e-12)
    assert (result["n_seeds"], result["n_episodes"]) == (3, 4)


def test_recipe_difference_reduces_to_the_paired_interval_when_the_seeds_agree() -> None:
    rng = np.random.default_rng(0)
    model, reference = rng.normal(0.2, 0.1, 50), rng.normal(0.25, 0.1, 50)
    result = evaluate.recipe_difference(np.stack([model] * 4), reference)
    paired = evaluate.paired_difference(model, reference)
    assert result["std_seeds"] == pytest.approx(0.0, abs=1e-15)
    assert result["dof"] == pytest.approx(49.0)
    assert (result["ci95_low"], result["ci95_high"]) == pytest.approx((paired["ci95_low"], paired["ci95_high"]))


def test_recipe_difference_reduces_to_a_t_interval_over_seeds_when_the_episodes_agree() -> None:
    seed_means = np.array([-0.05, -0.01, -0.04, 0.02, -0.03])
    result = evaluate.recipe_difference(np.repeat(seed_means[:, None], 30, axis=1), np.zeros(30))
    over_seeds = evaluate.mean_ci(seed_means)
    assert result["std_episodes"] == pytest.approx(0.0, abs=1e-15) and result["dof"] == pytest.approx(4.0)
    assert (result["ci95_low"], result["ci95_high"]) == pytest.approx((over_seeds["ci95_low"], over_seeds["ci95_high"]))


def test_recipe_difference_without_spread_is_the_point_and_stays_valid_json() -> None:
    # every cell the same difference: nothing to estimate a spread or degrees of freedom from
    result = evaluate.recipe_difference(np.full((3, 5), 0.25), np.full(5, 0.30))
    assert result["mean"] == pytest.approx(-0.05) and result["standard_error"] == 0.0 and result["dof"] is None
    assert result["ci95_low"] == result["ci95_high"] == result["mean"]
    json.dumps(result, allow_nan=False)  # strict JSON: no Infinity for recipe.json
    table = recipe.recipe_table({"metric": "final_map_error", "reference": "info_gain", "confidence": 0.95,
                                 "members": {}, "recipe": {**result, "verdict": "beats"},
                                 "against": {"info_gain": {**result, "verdict": "beats"}},
                                 "spread": {"low": 0.25, "high": 0.25, "mean": 0.25, "members": {}}})  # fmt: skip
    assert "| n/a | beats |" in table


def _coverage(seed_sd: float, episode_sd: float, noise_sd: float, seeds: int, episodes: int, trials: int,
              interval: str) -> float:  # fmt: skip
    rng = np.random.default_rng(2026)
    covered = 0
    for _ in range(trials):
        d = (rng.normal(0.0, seed_sd, (seeds, 1)) + rng.normal(0.0, episode_sd, (1, episodes))
             + rng.normal(0.0, noise_sd, (seeds, episodes)))  # fmt: skip
        if interval == "recipe":
            found = evaluate.recipe_difference(d, np.zeros(episodes))
        else:  # the seeds pooled per episode: the episodes' interval alone
            found = evaluate.paired_difference(d.mean(axis=0), np.zeros(episodes))
        covered += found["ci95_low"] <= 0.0 <= found["ci95_high"]
    return covered / trials


@pytest.mark.parametrize("seed_sd, episode_sd", [(0.03, 0.15), (0.08, 0.05), (0.0, 0.2)])
def test_the_recipe_interval_covers_the_true_lead_over_new_seeds_and_episodes(seed_sd, episode_sd) -> None:
    # crossed random effects with a true difference of zero: about 95% of the intervals hold it (a little more:
    # the estimate counts the interaction twice); 1500 trials give a binomial sd of 0.006
    coverage = _coverage(seed_sd, episode_sd, 0.2, seeds=6, episodes=100, trials=1500, interval="recipe")
    assert 0.935 <= coverage <= 0.985


def test_an_interval_over_episodes_alone_misses_the_training_seeds_spread() -> None:
    # why the recipe needs its own interval: the seeds' spread is invisible to the episodes' interval
    assert _coverage(0.08, 0.05, 0.2, seeds=6, episodes=100, trials=600, interval="episodes") < 0.6


def test_recipe_difference_refuses_bad_input() -> None:
    good = np.zeros((3, 4))
    with pytest.raises(ValueError, match="values must be"):
        evaluate.recipe_difference(np.zeros((1, 4)), np.zeros(4))  # one seed: no spread over seeds
    with pytest.raises(ValueError, match="values must be"):
        evaluate.recipe_difference(np.zeros(4), np.zeros(4))
    with pytest.raises(ValueError, match="reference must hold one number per episode"):
        evaluate.recipe_difference(good, np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        evaluate.recipe_difference(np.where(np.eye(3, 4) > 0, np.nan, 0.0), np.zeros(4))
    with pytest.raises(ValueError, match="confidence"):
        evaluate.recipe_difference(good, np.zeros(4), confidence=1.0)
    with pytest.raises(ValueError, match="numbers"):
        evaluate.recipe_difference([["a", "b"], ["c", "d"]], [0.0, 0.0])
    flat = evaluate.recipe_difference(good + 0.1, np.zeros(4))  # no spread at all: a point, not a failure
    assert (flat["ci95_low"], flat["ci95_high"]) == pytest.approx((0.1, 0.1)) and flat["standard_error"] < 1e-12


def _rows() -> list[dict]:
    rng = np.random.default_rng(7)
    layout = rng.normal(0.3, 0.1, 40)  # what every agent shares on an episode
    offsets = {"frontier": 0.1, "revisit": 0.02, "info_gain": 0.0, "s1": -0.05, "s2": -0.04, "s3": -0.06}
    return [{"agent": label, "seed": 100 + e, "final_map_error": layout[e] + offset + rng.normal(0.0, 0.03)}
            for label, offset in offsets.items() for e in range(40)]  # fmt: skip


def test_recipe_comparison_pairs_each_model_and_the_recipe_with_the_best_baseline() -> None:
    rows = _rows()
    result = evaluate.recipe_comparison(rows, ["s1", "s2", "s3"], ["frontier", "revisit", "info_gain"])
    assert tuple(result) == evaluate.RECIPE_KEYS and result["reference"] == "info_gain"
    alone = evaluate.paired_comparison(rows, ["frontier", "revisit", "info_gain"])
    assert result["members"] == {label: alone["agents"][label] for label in ("s1", "s2", "s3")}
    assert result["recipe"]["verdict"] == "beats" and result["recipe"]["mean"] == pytest.approx(-0.05, abs=0.01)
    assert (
        set(result["against"]) == {"frontier", "revisit", "info_gain"}
        and result["against"]["info_gain"] is result["recipe"]
    )
    table = [[r["final_map_error"] for r in rows if r["agent"] == label] for label in ("s1", "s2", "s3")]
    for name in ("frontier", "revisit"):
        reference = [r["final_map_error"] for r in rows if r["agent"] == name]
        assert result["against"][name] == {**evaluate.recipe_difference(table, reference), "verdict": "beats"}
    assert result["spread"]["members"] == {
        label: pytest.approx(np.mean(row)) for label, row in zip(("s1", "s2", "s3"), table)
    }
    assert result["spread"]["low"] <= result["spread"]["mean"] <= result["spread"]["high"]
    for members, baselines, message in [
        (["s1"], ["info_gain"], "at least two"),
        (["s1", "s1"], ["info_gain"], "at least two distinct"),
        (["s1", "info_gain"], ["info_gain"], "share"),
        (["s1", "s9"], ["info_gain"], "no rows"),
        (["s1", "s2"], ["oracle"], "none of"),
    ]:
        with pytest.raises(ValueError, match=message):
            evaluate.recipe_comparison(rows, members, baselines)
    with pytest.raises(ValueError, match="different seeds"):
        evaluate.recipe_comparison([r for r in rows if not (r["agent"] == "s2" and r["seed"] == 100)],
                                   ["s1", "s2"], ["info_gain"])  # fmt: skip


def _write_runs(tmp_path) -> None:
    for name, specs in [("models", ["m1=random", "m2=revisit"]), ("baselines", ["frontier", "info_gain"])]:
        rows, summary = evaluate.evaluate_agents(specs, TASK["episodes"], TASK["seed"], TASK["env_id"],
                                                 TASK["env_kwargs"])  # fmt: skip
        evaluate.write_outputs(rows, summary, tmp_path / name)


def test_the_command_judges_a_recipe_from_stored_runs(tmp_path, capsys) -> None:
    _write_runs(tmp_path)
    status = recipe.main(["--runs", str(tmp_path / "models"), str(tmp_path / "baselines"), "--members", "m1,m2",
                          "--out", str(tmp_path / "judged")])  # fmt: skip
    assert status == 0
    printed = capsys.readouterr().out
    written = json.loads((tmp_path / "judged" / "recipe.json").read_text())
    rows, _ = recipe.load_runs([tmp_path / "models", tmp_path / "baselines"])
    expected = recipe.judge_recipe(rows, ["m1", "m2"])
    assert written["reference"] == expected["reference"] in ("frontier", "info_gain")
    assert written["recipe"] == expected["recipe"]  # floats survive JSON exactly
    assert set(written["against"]) == {"frontier", "info_gain"}
    assert written["env_id"] == TASK["env_id"] and len(written["seeds"]) == TASK["episodes"]
    assert "| m1 |" in printed and f"| {expected['reference']} (best) |" in printed
    assert (tmp_path / "judged" / "recipe.md").read_text().startswith('SeifExplore-v1 {"max_episode_steps": 12}')


def test_the_command_refuses_runs_of_other_episodes_or_repeated_labels(tmp_path, capsys) -> None:
    _write_runs(tmp_path)
    rows, summary = evaluate.evaluate_agents(["frontier"], 2, TASK["seed"], TASK["env_id"], TASK["env_kwargs"])
    evaluate.write_outputs(rows, summary, tmp_path / "fewer")
    for runs, message in [
        (["models", "fewer"], "was made with seeds"),
        (["models", "models"], "already has the agents"),
        (["models", "nothing"], "does not exist"),
    ]:
        with pytest.raises(SystemExit):
            recipe.main(["--runs", *(str(tmp_path / run) for run in runs), "--members", "m1,m2"])
        assert message in capsys.readouterr().err
    with pytest.raises(ValueError, match="at least one"):
        recipe.load_runs([])


def test_runs_of_the_previous_schema_are_read_and_unknown_ones_refused(tmp_path) -> None:
    rows, summary = evaluate.evaluate_agents(["frontier"], 2, TASK["seed"], TASK["env_id"], TASK["env_kwargs"])
    evaluate.write_outputs(rows, summary, tmp_path / "run")
    path = tmp_path / "run" / "summary.json"
    written = json.loads(path.read_text())
    del written["stored_run"]  # what schema 2 wrote
    path.write_text(json.dumps({**written, "schema_version": 2}))
    read, _ = evaluate.read_run(tmp_path / "run")
    assert read == [{key: row[key] for key in evaluate.RESULT_COLUMNS} for row in rows]
    stored, _ = evaluate.load_stored_run(tmp_path / "run", TASK["env_id"], TASK["env_kwargs"], [5, 6])
    assert stored == read
    for version in (1, 99):
        path.write_text(json.dumps({**written, "schema_version": version}))
        with pytest.raises(ValueError, match=f"schema_version {version}"):
            evaluate.read_run(tmp_path / "run", "runs")


def test_the_statistics_examples_hold() -> None:
    import doctest

    assert doctest.testmod(evaluate).failed == 0
