"""oodmon check weighs an alarm rate's change by its episodes: unchanged code passes, a regression fails."""

from __future__ import annotations

import json

import numpy as np
import pytest

from oodmon.errors import ConfigError
from oodmon.replay.check import CHANCE, compare_metrics, load_baseline

# Rows as a check of logs has them: three variants' alarm rates over 20 episodes each
RATES = {"cartpole/m/cartpole:length=2.0": {"early_alarm_rate": 0.15, "detection_rate": 0.9},
         "cartpole/m/cartpole:gravity=78.4": {"early_alarm_rate": 0.05, "detection_rate": 0.6},
         "cartpole/m/cartpole": {"false_alarm_rate": 0.1}}
EPISODES = 20


def _draw(rng: np.random.Generator) -> dict[str, dict[str, float]]:
    """One run's rows: each rate a count of EPISODES episodes drawn at its true value."""
    return {key: {name: rng.binomial(EPISODES, p) / EPISODES for name, p in row.items()} | {"alarm_episodes": EPISODES}
            for key, row in RATES.items()}


def test_a_check_of_unchanged_code_fails_at_most_as_often_as_chance_allows():
    """2,000 pairs of runs of the same code (each rate re-drawn): with the episodes counted, a check
    fails in at most CHANCE = 1% of them (the test allows 2%: at a true 1%, 40 or more of 2,000 has
    probability below 1e-5); on the tolerance alone most fail (the bug: 0.15 -> 0.25 was a fall)."""
    rng = np.random.default_rng(0)
    counted = alone = 0
    for _ in range(2000):
        baseline, now = _draw(rng), _draw(rng)
        counted += bool(compare_metrics(now, baseline, 0.02, chance=CHANCE))
        alone += bool(compare_metrics(now, baseline, 0.02))
    assert counted <= 40
    assert alone >= 1000


@pytest.mark.parametrize("name, was, now", [("detection_rate", 19, 8), ("early_alarm_rate", 1, 9),
                                            ("false_alarm_rate", 0, 8)])
def test_a_real_regression_still_fails_with_its_counts_and_p_value(name, was, now):
    key = "cartpole/m/cartpole:length=2.0"
    baseline = {key: {name: was / EPISODES, "alarm_episodes": EPISODES}}
    falls = compare_metrics({key: {name: now / EPISODES, "alarm_episodes": EPISODES}}, baseline, 0.02, chance=CHANCE)
    assert len(falls) == 1 and f"({was}/20 to {now}/20 episodes, one-sided p = " in falls[0]
    # the same move within chance: one episode more or less is not a fall
    within: list[str] = []
    moved = was + (1 if name != "detection_rate" else -1)
    nudged = compare_metrics({key: {name: moved / EPISODES, "alarm_episodes": EPISODES}}, baseline, 0.02,
                             chance=CHANCE, within=within)
    assert nudged == []
    # ... and is said to be within chance, as `oodmon check` prints it ("within chance: ...")
    assert len(within) == 1 and f"({was}/20 to {moved}/20 episodes, one-sided p = " in within[0]


def test_rates_that_are_not_counts_keep_the_tolerance_alone():
    """A baseline without counts (written before 2026-11-29), or a rate edited by hand, is judged
    as before."""
    key = "cartpole/m/cartpole"
    now = {key: {"false_alarm_rate": 0.25, "alarm_episodes": EPISODES}}
    assert compare_metrics(now, {key: {"false_alarm_rate": 0.15}}, 0.02, chance=CHANCE) != []  # no count kept
    hand = {key: {"false_alarm_rate": 0.123, "alarm_episodes": EPISODES}}  # 2.46 of 20 episodes
    assert compare_metrics(now, hand, 0.02, chance=CHANCE) != []


def test_a_baselines_episode_count_must_be_a_whole_number(tmp_path):
    path = tmp_path / "baseline.json"
    for bad in (0, 2.5, 20.0, "20", None):  # 20.0 was read, then ignored as no count
        path.write_text(json.dumps({"metrics": {"a/b/c": {"detection_rate": 1.0, "alarm_episodes": bad}}}))
        with pytest.raises(ConfigError, match="alarm_episodes.*is not allowed; give the whole number >= 1"):
            load_baseline(path)
    path.write_text(json.dumps({"metrics": {"a/b/c": {"detection_rate": 1.0, "alarm_episodes": 20}}}))
    assert load_baseline(path)["metrics"]["a/b/c"]["alarm_episodes"] == 20
    # so too the detection rate's own count, kept where some episodes ended before their onset
    for bad in (0, 2.5, "18"):
        path.write_text(json.dumps({"metrics": {"a/b/c": {"detection_rate": 1.0, "alarm_episodes": 20,
                                                          "shifted_episodes": bad}}}))
        with pytest.raises(ConfigError, match="shifted_episodes.*is not allowed; give the whole number >= 1 of episodes "
                                              "the row's detection rate counts"):
            load_baseline(path)
    path.write_text(json.dumps({"metrics": {"a/b/c": {"detection_rate": 1.0, "alarm_episodes": 20, "shifted_episodes": 18}}}))
    assert load_baseline(path)["metrics"]["a/b/c"]["shifted_episodes"] == 18


def test_a_mean_delay_is_weighed_by_its_delays():
    """One run's delays [1]*19 + [2] (mean 1.05) and another's with two at 3 (1.15): the check of the
    same code called it a fall; with the delays kept it is within chance, and delays ten times as
    long still fail. 2,000 re-drawn pairs of 20 delays (1 to 3 steps, mostly 1): at most 2% fail
    (the promise: 1%; 16 when written), against 898 on the tolerance alone."""
    key = "cartpole/m/cartpole:gravity=78.4@combined"

    def row(delays):
        return {key: {"delay_mean": float(np.mean(delays)), "delays": list(delays)}}

    before = [1] * 19 + [2]
    assert compare_metrics(row([1] * 17 + [3, 3, 1]), row(before), 0.02, chance=CHANCE) == []
    assert compare_metrics(row([1] * 17 + [3, 3, 1]), {key: {"delay_mean": 1.05}}, 0.02, chance=CHANCE) != []  # no delays kept
    (fell,) = compare_metrics(row([10] * 5 + [9] * 15), row(before), 0.02, chance=CHANCE)
    assert fell.startswith(f"{key}: delay_mean rose from 1.05 to 9.25 (20 to 20 delays, one-sided p = ")
    rng = np.random.default_rng(1)
    counted = alone = 0
    for _ in range(2000):
        a, b = (rng.choice([1, 2, 3], size=20, p=[0.85, 0.1, 0.05]).tolist() for _ in range(2))
        counted += bool(compare_metrics(row(b), row(a), 0.02, chance=CHANCE))
        alone += bool(compare_metrics(row(b), row(a), 0.02))
    assert counted <= 40 and alone >= 800



def test_the_delays_test_is_scipy_stats_mannwhitneyu_to_the_bit_without_importing_it():
    """mann_whitney_greater gives scipy.stats.mannwhitneyu(x, y, alternative="greater")'s p-value
    bit for bit on 2,000 seeded pairs: continuous and tied values, samples of 1-13 and some of
    20-200 (exact when one sample has <= 8 values and none tie, asymptotic otherwise), and an exact
    one whose counts of U pass 64 bits (SciPy then counts in floats); and a check weighing delays
    leaves scipy.stats unimported (0.4 s of `oodmon check`'s start before 2026-12-04)."""
    import subprocess
    import sys

    from scipy.stats import mannwhitneyu

    from oodmon.replay.check import mann_whitney_greater

    rng = np.random.default_rng(5)
    draws = [lambda n: rng.normal(size=n), lambda n: rng.integers(0, 6, n).astype(float),
             lambda n: rng.exponential(size=n), lambda n: rng.integers(1, 400, n).astype(float)]
    pairs = [(draws[i % 4](int(rng.integers(1, 14))), draws[i % 4](int(rng.integers(20, 201) if i % 7 == 0 else
                                                                    rng.integers(1, 14)))) for i in range(2000)]
    y = rng.normal(size=20000)  # and U = 9,603 at 8 values against 20,000: its counts past 64 bits (from U = 8,675)
    pairs += [(np.quantile(y, 0.06) + rng.normal(scale=1e-3, size=8), y), (rng.normal(size=1), rng.normal(size=1))]
    exact = sum(min(x.size, y.size) <= 8 and np.unique(np.r_[x, y]).size == x.size + y.size for x, y in pairs)
    assert 600 <= exact <= 1500  # both methods are exercised
    for x, y in pairs:
        assert mann_whitney_greater(list(x), list(y)) == mannwhitneyu(x, y, alternative="greater").pvalue, (x, y)
    code = ("import sys; from oodmon.replay.check import CHANCE, compare_metrics\n"
            "row = lambda d: {'k': {'delay_mean': sum(d) / len(d), 'delays': d}}\n"
            "(fell,) = compare_metrics(row([10] * 5 + [9] * 15), row([1] * 19 + [2]), 0.02, chance=CHANCE)\n"
            "print('scipy.stats' in sys.modules, fell)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("False k: delay_mean rose from 1.05 to 9.25 (20 to 20 delays, one-sided p = "), out


def test_figures_that_could_not_have_moved_do_not_dilute_the_level():
    """60 variants detected in 10 of 10 episodes before and after (no table of those margins could
    be a fall) and one falling to 2 of 10 (p = 3.6e-4): counted among 61 the fall would need p below
    1.6e-4; Tarone's count leaves it alone among them, and it fails."""
    steady = {f"c/m/v{i}": {"detection_rate": 1.0, "alarm_episodes": 10} for i in range(60)}
    baseline = steady | {"c/m/fallen": {"detection_rate": 1.0, "alarm_episodes": 10}}
    now = steady | {"c/m/fallen": {"detection_rate": 0.2, "alarm_episodes": 10}}
    (fell,) = compare_metrics(now, baseline, 0.02, chance=CHANCE)
    assert fell.startswith("c/m/fallen: detection_rate fell from 1 to 0.2 (10/10 to 2/10 episodes, one-sided p = 0.00036")


def test_a_count_of_more_episodes_than_can_be_weighed_keeps_the_tolerance_alone():
    """A baseline's alarm_episodes of 10**30 (hand-edited) ended check in an OverflowError traceback
    from the exact test; past MOST_EPISODES a rate is not weighed and falls on the tolerance alone."""
    key = "cartpole/m/cartpole"
    falls = compare_metrics({key: {"false_alarm_rate": 0.5, "alarm_episodes": 10**30}},
                            {key: {"false_alarm_rate": 0.0, "alarm_episodes": 10**30}}, 0.02, chance=CHANCE)
    assert falls == [f"{key}: false_alarm_rate rose from 0 to 0.5 (tolerance 0.02)"]
