"""The filter robustness harness (``agents.robustness`` records, ``seif_gym.harness`` replays and scores) and the
adversarial reward (``agents.adversary``)."""

from __future__ import annotations

import csv

import gymnasium as gym
import numpy as np
import pytest

import seif_gym  # noqa: F401
from agents.robustness import evaluate, main
from seif_gym import harness
from seif_gym.episodes import Episode, EpisodeRecorder, replay
from seif_gym.harness import RESULT_COLUMNS, TIMESERIES_KEYS, FilterSpec, parse_filter
from seif_gym.metrics import map_nees
from seif_gym.slam import FILTERS

STEPS = 20


@pytest.fixture(scope="module")
def harness_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("robustness")
    argv = ["--agents", "random", "--layouts", "uniform", "--episodes", "1", "--seed", "3", "--steps", str(STEPS),
            "--filters", "seif-k2,seif-k8,ekf", "--out", str(out)]  # fmt: skip
    assert main([*argv, "--quiet"]) == 0
    return out


def test_harness_writes_the_documented_files_and_csv_schema(harness_run):
    out = harness_run
    for name in ("results.csv", "timeseries.npz", "map_rmse.png", "pose_rmse.png", "nees.png", "time_per_step.png",
                 "summary.md", "config.json", "episodes/random_uniform_3.npz"):  # fmt: skip
        assert (out / name).is_file(), name
    with (out / "results.csv").open() as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == RESULT_COLUMNS
        rows = list(reader)
    assert [row["filter"] for row in rows] == ["seif-k2", "seif-k8", "ekf"]
    assert {(row["policy"], row["layout"], row["seed"]) for row in rows} == {("random", "uniform", "3")}
    for row in rows:
        assert int(row["steps"]) == STEPS
        assert row["diverged"] in ("0", "1")
        for column in ("final_map_error", "pose_rmse", "anees_pose", "us_per_step_median"):
            assert np.isfinite(float(row[column])), column
    with np.load(out / "timeseries.npz", allow_pickle=False) as data:
        assert set(data.files) == set(TIMESERIES_KEYS)
        assert data["pose_nees"].shape == (3, STEPS + 1)
        assert data["step_seconds"].shape == (3, STEPS)
        assert list(data["filter"]) == ["seif-k2", "seif-k8", "ekf"]
    # the env's own filter (seif-k8) replayed reproduces the recorded map error exactly
    episode = Episode.load(out / "episodes/random_uniform_3.npz")
    assert float(rows[1]["final_map_error"]) == float(episode.map_errors[-1])
    summary = (out / "summary.md").read_text()
    assert "| seif-k2 |" in summary and "| random | ekf |" in summary


def _logging(cls, logs):
    """A subclass of ``cls`` that logs the inputs of every predict and update (one log per instance)."""

    class Logged(cls):
        def __init__(self, *args, **kwargs):
            self.log = []
            logs.append(self.log)
            super().__init__(*args, **kwargs)

        def predict(self, control, dt):
            self.log.append(("predict", np.array(control, dtype=float), float(dt)))
            super().predict(control, dt)

        def update(self, ranges, bearings, ids):
            self.log.append(("update", np.array(ranges, dtype=float), np.array(bearings, dtype=float), np.array(ids)))
            super().update(ranges, bearings, ids)

    return Logged


def test_replayed_filters_see_exactly_the_recorded_data(tmp_path):
    logs = {name: [] for name in ("seif-k2", "seif-exact", "eif", "ekf")}
    specs = [
        FilterSpec("seif-k2", "seif", {"max_active": 2}, _logging(FILTERS["seif"], logs["seif-k2"])),
        FilterSpec(
            "seif-exact",
            "seif",
            {"max_active": 8, "mean_recovery": "exact"},
            _logging(FILTERS["seif"], logs["seif-exact"]),
        ),
        FilterSpec("eif", "eif", {}, _logging(FILTERS["eif"], logs["eif"])),
        FilterSpec("ekf", "ekf", {}, _logging(FILTERS["ekf"], logs["ekf"])),
    ]
    rows, series = evaluate(["random"], ["loop"], [5], 15, specs, episode_dir=tmp_path)
    assert [row["filter"] for row in rows] == [spec.label for spec in specs]
    episode = Episode.load(tmp_path / "random_loop_5.npz")
    expected = [("update", *episode.measurements(0))]
    for t in range(episode.steps):
        expected.append(("predict", episode.executed_controls[t], episode.dt))
        expected.append(("update", *episode.measurements(t + 1)))
    assert sum(len(episode.measurements(t)[0]) for t in range(episode.steps + 1)) > 0
    for name, instances in logs.items():
        log = instances[-1]  # the last instance replayed the recorded episode (earlier ones: warm-up)
        assert len(log) == len(expected), name
        for got, want in zip(log, expected):
            assert got[0] == want[0]
            for a, b in zip(got[1:], want[1:]):
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
    assert len(series) == len(specs)


def test_relative_nees_is_anchor_free():
    rng = np.random.default_rng(1)
    m = 5
    basis = rng.normal(size=(2 * m, 2 * m))
    cov = basis @ basis.T + np.eye(2 * m)
    truth, estimate = rng.normal(size=(m, 2)), rng.normal(size=(m, 2))
    global_nees, relative_nees = map_nees(truth, estimate, cov)
    error = (truth - estimate).reshape(-1)
    assert global_nees == pytest.approx(error @ np.linalg.solve(cov, error))
    chain = np.zeros((2 * (m - 1), 2 * m))  # consecutive pairs instead of the anchor 0
    for i in range(1, m):
        chain[2 * i - 2 : 2 * i, 2 * i - 2 : 2 * i] = -np.eye(2)
        chain[2 * i - 2 : 2 * i, 2 * i : 2 * i + 2] = np.eye(2)
    d = chain @ error
    assert relative_nees == pytest.approx(d @ np.linalg.solve(chain @ cov @ chain.T, d))


def test_saved_episodes_score_as_when_recorded(harness_run, tmp_path, capsys):
    """``python -m seif_gym.harness --episodes-dir DIR`` (no agents) gives the recording run's rows, timings aside."""
    out = tmp_path / "rescored"
    assert harness.main(["--episodes-dir", str(harness_run / "episodes"), "--filters", "seif-k2,seif-k8,ekf",
                         "--out", str(out), "--quiet"]) == 0  # fmt: skip
    assert capsys.readouterr().err == ""  # --quiet: nothing on stderr

    def table(path):
        with path.open() as handle:
            return [{k: v for k, v in row.items() if not k.startswith("us_per_step")} for row in csv.DictReader(handle)]

    assert table(out / "results.csv") == table(harness_run / "results.csv")
    labelled = harness.load_episodes([harness_run / "episodes" / "random_uniform_3.npz"])
    assert [label for label, _ in labelled] == ["random"]


def test_the_recording_options_moved_to_agents_robustness(capsys):
    with pytest.raises(SystemExit):
        harness.main(["--policies", "random", "--seeds", "2"])
    assert "python -m agents.robustness" in capsys.readouterr().err
    try:  # a data error: exit status 2 and one line (returned, or through SystemExit)
        status = harness.main(["--episodes-dir", "/no/such/folder"])
    except SystemExit as exit_:
        status = exit_.code
    assert status == 2
    assert "episodes: no file or folder /no/such/folder" in capsys.readouterr().err


def test_parse_filter():
    assert parse_filter("seif-k4").options == {"max_active": 4}
    assert parse_filter("seif-exact").options == {"max_active": 8, "mean_recovery": "exact"}
    assert parse_filter("ekf").filter == "ekf"
    assert parse_filter("cseif").filter == "cseif" and parse_filter("cseif").options == {"max_active": 8}
    assert parse_filter("cseif-k4-exact").options == {"max_active": 4, "mean_recovery": "exact"}
    with pytest.raises(ValueError):
        parse_filter("seif")
    with pytest.raises(ValueError, match="distinct"):
        harness.parse_filters(["ekf", "ekf"])


def test_adversary_return_is_the_final_gap():
    from agents.adversary import SeifVsEkfReward

    env = EpisodeRecorder(SeifVsEkfReward(gym.make("SeifExplore-v0", max_episode_steps=40)))
    _, info = env.reset(seed=11)
    rng = np.random.default_rng(11)
    total, done = 0.0, False
    while not done:
        _, reward, terminated, truncated, info = env.step(rng.uniform([0.3, -1.0], [1.0, 1.0]))
        total += reward
        done = terminated or truncated
    episode = env.episode
    ekf = replay(episode, "ekf").map_errors  # the shadow EKF is the replayed EKF, bit for bit
    assert info["ekf_map_error"] == ekf[-1]
    expected = (episode.map_errors[-1] - ekf[-1]) - (episode.map_errors[0] - ekf[0])
    assert total == pytest.approx(expected, abs=1e-12)
    assert info["map_error_gap"] == episode.map_errors[-1] - ekf[-1]


def _paired_rows(values: dict[str, list[float]], metric: str = "anees_pose") -> list[dict]:
    return [{"policy": policy, "layout": layout, "seed": seed, "filter": "seif-k8", metric: value}
            for policy, per_seed in values.items() for seed, value in enumerate(per_seed)
            for layout in ("loop",)]  # fmt: skip


def test_paired_policies_pairs_by_layout_and_seed():
    import doctest

    import agents.robustness

    assert doctest.testmod(agents.robustness).failed == 0
    from agents.robustness import paired_policies

    reference = [3.0, 4.0, 5.0, 30.0, 3.5]
    other = [4.0, 4.5, 6.0, 45.0, 3.0]
    rows = _paired_rows({"ppo": reference, "adversary": other})
    # rows of episodes the reference lacks are left out, in any order
    rows.append({"policy": "adversary", "layout": "uniform", "seed": 0, "filter": "seif-k8", "anees_pose": 1e6})
    (row,) = paired_policies(list(reversed(rows)), "ppo", ["anees_pose"], bootstrap=500)
    d = np.subtract(other, reference)
    half = 2.7764451051977987 * d.std(ddof=1) / np.sqrt(5)  # t_{0.975, 4}
    assert row["n"] == 5 and row["difference"] == pytest.approx(d.mean())
    assert (row["ci95_low"], row["ci95_high"]) == pytest.approx((d.mean() - half, d.mean() + half))
    assert row["bootstrap_ci95_low"] <= d.mean() <= row["bootstrap_ci95_high"]
    logs = np.log(other) - np.log(reference)
    assert row["ratio"] == pytest.approx(np.exp(logs.mean()))
    assert row["verdict"] == ("higher" if d.mean() - half > 0 else "tie")
    # a clearly lower policy, and a metric that is not a NEES has no ratio
    (row,) = paired_policies(_paired_rows({"a": [1.0, 2, 3, 4], "b": [0.5, 1.4, 2.6, 3.3]}, "pose_rmse"), "a",
                             ["pose_rmse"], bootstrap=0)  # fmt: skip
    assert row["verdict"] == "lower" and row["ratio"] is None and row["bootstrap_ci95_low"] is None
    # relative_to: each filter's value minus another filter's on the same episode
    gap_rows = [{**row, "filter": "ekf", "anees_pose": 1.0 + row["seed"]} for row in rows] + rows
    (row,) = paired_policies(gap_rows, "ppo", ["anees_pose"], bootstrap=0, relative_to="ekf")
    assert row["filter"] == "seif-k8 − ekf" and row["ratio"] is None
    assert row["difference"] == pytest.approx(d.mean())  # the same offset on both sides cancels
    assert row["policy_mean"] == pytest.approx(np.mean(other) - np.mean(1.0 + np.arange(5)))
    with pytest.raises(ValueError, match="relative_to"):
        paired_policies(rows, "ppo", ["anees_pose"], relative_to="eif")
    with pytest.raises(ValueError, match="reference"):
        paired_policies(rows, "frontier", ["anees_pose"])
    with pytest.raises(ValueError, match="metrics"):
        paired_policies(rows, "ppo", ["no_such_metric"])


def test_paired_against_writes_paired_tables(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["--agents", "random,still=frontier", "--layouts", "uniform", "--episodes", "2", "--steps", "8",
            "--filters", "seif-k8,ekf", "--out", str(out), "--quiet", "--no-save-episodes",
            "--paired-against", "random", "--paired-metrics", "anees_pose,final_map_error",
            "--paired-relative-to", "ekf"]  # fmt: skip
    assert main(argv) == 0
    with (out / "paired.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["filter"], r["metric"], r["policy"]) for r in rows] == [
        ("seif-k8", "anees_pose", "still"), ("seif-k8", "final_map_error", "still"),
        ("ekf", "anees_pose", "still"), ("ekf", "final_map_error", "still"),
        ("seif-k8 − ekf", "anees_pose", "still"), ("seif-k8 − ekf", "final_map_error", "still"),
    ]  # fmt: skip
    assert all(r["n"] == "2" and r["reference"] == "random" for r in rows)
    assert "### anees_pose: policy − random" in (out / "paired.md").read_text()
    with pytest.raises(SystemExit):
        main([*argv[:-6], "--paired-against", "nobody"])
    assert "--paired-against" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*argv[:-2], "--paired-relative-to", "eif"])
    assert "--paired-relative-to" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*argv[:-6], "--paired-relative-to", "ekf"])
    assert "needs --paired-against" in capsys.readouterr().err
