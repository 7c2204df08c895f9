"""bench --baseline weighs the monitor's alarm figures by their episodes: a rerun of unchanged code
(other draws: another CPU's fits) passes, a regression in one variant or in all of them fails."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.stats import fisher_exact, hypergeom, mannwhitneyu

from oodmon.bench.baseline import _ranks_beyond_chance, bench_falls, stratified_exact, stratified_ranks

METHODS = ("dropout", "ensemble")
#: Per shifted variant: the chance that a failing episode is alarmed before its failure (half of
#: them always, as most of the CartPole bench's), and the scale of its leads in steps.
VARIANTS = [(1.0, 40), (1.0, 90), (1.0, 20), (1.0, 60), (0.9, 30), (0.8, 15), (0.9, 50), (0.7, 25)]
EPISODES, ID_EPISODES = 10, 200


def _bench(rng: np.random.Generator, change=None) -> dict:
    """A monitor bench's result as `bench --json` writes it, its episodes drawn at the true values;
    ``change(method, index, row)`` may alter a shifted row's drawn figures."""
    alarms = []
    for method in METHODS:
        false_alarms = int(rng.binomial(ID_EPISODES, 0.02))
        alarms.append({"method": method, "variant": "cartpole", "episodes": ID_EPISODES, "false_alarms": false_alarms,
                       "false_alarm_rate": false_alarms / ID_EPISODES, "before_failure_rate": None,
                       "delay_median": None, "lead_median": None, "delays": [], "leads": []})
        for index, (alarmed, scale) in enumerate(VARIANTS):
            before = int(rng.binomial(EPISODES, alarmed))
            row = {"delays": [int(d) for d in rng.geometric(0.5, EPISODES)],
                   "leads": [int(v) for v in np.ceil(rng.exponential(scale, before))], "before_failure": before}
            if change is not None:
                change(method, index, row)
            alarms.append({"method": method, "variant": f"cartpole:v{index}", "episodes": EPISODES,
                           "failed": EPISODES, "before_failure": row["before_failure"],
                           "before_failure_rate": row["before_failure"] / EPISODES, "false_alarms": None,
                           "false_alarm_rate": None, "delays": row["delays"],
                           "delay_median": float(np.median(row["delays"])), "leads": row["leads"],
                           "lead_median": float(np.median(row["leads"])) if row["leads"] else None})
    return {"config": {"task": "cartpole", "protocol": "monitor"}, "rows": [], "alarms": alarms}


def _without_counts(result: dict) -> dict:
    """The same figures without what they count (results written before the counts were kept)."""
    kept = ("method", "variant", "false_alarm_rate", "before_failure_rate", "delay_median", "lead_median")
    return dict(result, alarms=[{k: a[k] for k in kept} for a in result["alarms"]])


def test_a_medians_test_is_scipys_mann_whitney_u_and_its_least_p_value_the_values_at_the_wrong_end():
    rng = np.random.default_rng(2)
    for _ in range(50):
        before = [float(v) for v in rng.integers(1, 8, rng.integers(1, 12))]
        after = [float(v) for v in rng.integers(1, 8, rng.integers(1, 12))]
        for higher, alternative in ((True, "less"), (False, "greater")):
            p, least = _ranks_beyond_chance(higher, before, after)
            if len(set(before + after)) == 1:
                assert (p, least) == (1.0, 1.0)
                continue
            assert np.isclose(p, mannwhitneyu(after, before, alternative=alternative, method="asymptotic").pvalue)
            pooled = sorted(before + after)
            wrong = (pooled[:len(after)], pooled[len(after):]) if higher else (pooled[len(before):], pooled[:len(before)])
            assert np.isclose(least, mannwhitneyu(*wrong, alternative=alternative, method="asymptotic").pvalue)


def test_one_stratum_is_fishers_exact_test_and_several_are_the_convolution_of_their_hypergeometrics():
    rng = np.random.default_rng(1)
    for _ in range(50):
        n0, n1 = rng.integers(1, 15, 2)
        k0, k1 = rng.integers(0, n0 + 1), rng.integers(0, n1 + 1)
        for higher, alternative in ((True, "less"), (False, "greater")):
            p, _ = stratified_exact([(k0, n0, k1, n1)], higher)
            assert np.isclose(p, fisher_exact([[k1, n1 - k1], [k0, n0 - k0]], alternative=alternative)[1])
    # two strata, summed by hand over every pair of their new rows' counts
    tables = [(9, 10, 6, 10), (3, 8, 1, 7)]
    supports = [range(max(0, k0 + k1 - n0), min(n1, k0 + k1) + 1) for k0, n0, k1, n1 in tables]
    brute = sum(np.prod([hypergeom.pmf(a, n0 + n1, k0 + k1, n1) for a, (k0, n0, k1, n1) in zip(pair, tables)])
                for pair in itertools.product(*supports) if sum(pair) <= 6 + 1)
    p, least = stratified_exact(tables, higher=True)
    assert np.isclose(p, brute) and np.isclose(least, hypergeom.pmf(5, 20, 15, 10) * hypergeom.pmf(0, 15, 4, 7))
    # a stratum whose counts cannot move (10 of 10 before and after) changes nothing
    assert np.allclose(stratified_exact(tables + [(10, 10, 10, 10)], True), (p, least))


def test_a_check_of_unchanged_code_fails_at_most_as_often_as_chance_allows():
    """1,000 pairs of benches of the same code (every episode drawn again, as a rerun on a CPU that
    fits its detectors otherwise draws them): the check fails in at most CHANCE = 1% of them (the
    test allows 2%: at a true 1%, 20 or more of 1,000 has probability 0.003); on the tolerance
    alone (results without the counts) nearly every one fails."""
    rng = np.random.default_rng(0)
    weighed = alone = 0
    for _ in range(1000):
        baseline, now = _bench(rng), _bench(rng)
        weighed += bool(bench_falls(now, baseline))
        alone += bool(bench_falls(_without_counts(now), _without_counts(baseline)))
    assert weighed <= 20
    assert alone >= 950


def test_one_variant_collapsing_fails():
    """10 of 10 alarmed before the failure falling to 2 of 10 in one variant among eight (p =
    3.6e-4; Tarone's level over all 64 figures, 0.01 / 55, would not count it): it falls on the
    rates' share, which goes to the few rates that could move."""
    def collapse(method, index, row):
        if method == "dropout" and index == 0:
            row["before_failure"], row["leads"] = 2, row["leads"][:2]

    def steady(method, index, row):  # every rate at its expected count: only the collapse moves
        row["before_failure"] = round(EPISODES * VARIANTS[index][0])

    rng = np.random.default_rng(3)
    baseline = _bench(rng, steady)
    falls = bench_falls(_bench(rng, lambda *a: (steady(*a), collapse(*a))), baseline)
    rate = [line for line in falls if "before_failure_rate" in line]
    assert rate == ["alarms/dropout/cartpole:v0: before_failure_rate fell from 1 to 0.2 (10/10 to 2/10 episodes, "
                    "one-sided p = 0.00036; tolerance 0.02)"]
    assert bench_falls(_bench(np.random.default_rng(3), steady), baseline) == []


def test_every_lead_halved_fails_and_one_variants_delays_ten_times_as_long_fail_alone():
    """Alarms that come later everywhere (each lead halved: p about 0.03 in each variant, within
    chance alone) fall through the pools of leads; one variant's delays ten times as long fall on
    their own test."""
    rng = np.random.default_rng(5)
    baseline = _bench(rng)

    def halved(method, index, row):
        row["leads"] = [max(1, v // 2) for v in row["leads"]]

    falls = bench_falls(_bench(np.random.default_rng(6), halved), baseline)
    leads = [line for line in falls if "lead_median fell" in line]
    assert len(leads) >= 12 and all("leads pooled, one-sided p = " in line for line in leads)

    def slower(method, index, row):
        if method == "ensemble" and index == 3:
            row["delays"] = [10 * d for d in row["delays"]]

    falls = bench_falls(_bench(np.random.default_rng(6), slower), _bench(np.random.default_rng(6)))
    assert len(falls) == 1 and falls[0].startswith("alarms/ensemble/cartpole:v3: delay_median rose from ")
    assert "(10 to 10 delays, one-sided p = " in falls[0] and "within chance alone" not in falls[0]


def test_the_pooled_ranks_keep_their_level_on_ten_values_a_stratum():
    """Stouffer's sum of Mann-Whitney z-scores is normal only approximately: on 2,000 pools of eight
    strata of ten tied-prone values (delays of 1-5 steps) drawn alike before and after, p <= 0.01 in
    at most 2% of them (at a true 1%, 40 or more of 2,000 has probability below 1e-5)."""
    rng = np.random.default_rng(7)
    hits = 0
    for _ in range(2000):
        strata = [([float(d) for d in rng.geometric(0.5, 10)], [float(d) for d in rng.geometric(0.5, 10)])
                  for _ in range(8)]
        hits += stratified_ranks(strata, higher=False)[0] <= 0.01
    assert hits <= 40
    assert stratified_ranks([([1.0] * 10, [1.0] * 10)], higher=False) == (1.0, 1.0)  # all tied: nothing to tell


def test_a_result_whose_figures_are_not_numbers_is_refused_naming_the_entry(tmp_path):
    """A hand-edited or damaged result (a figure written as text, a count of 2.5 episodes, a lead
    of NaN) gave a traceback (TypeError) when compared; now it is refused when read."""
    import json

    import pytest

    from oodmon.bench.baseline import load_bench_result
    from oodmon.errors import ConfigError

    result = _bench(np.random.default_rng(0))
    path = tmp_path / "r.json"
    path.write_text(json.dumps(result))
    assert load_bench_result(path)["alarms"] == result["alarms"]
    for name, value, words in (("lead_median", "45", "a finite number"), ("failed", 2.5, "a whole number >= 0"),
                               ("leads", [1, float("nan")], "a list of finite numbers")):
        damaged = json.loads(json.dumps(result))
        damaged["alarms"][1][name] = value
        path.write_text(json.dumps(damaged))
        with pytest.raises(ConfigError, match=f"alarms entry dropout/cartpole:v0 has {name}=.* it must be {words} or null"):
            load_bench_result(path)


def test_moves_within_chance_are_listed_with_their_p_values_and_do_not_fall():
    rng = np.random.default_rng(0)
    baseline, now = _bench(rng), _bench(rng)
    listed: list[str] = []
    assert bench_falls(now, baseline, within=listed) == []  # this pair: no fall
    alone = bench_falls(_without_counts(now), _without_counts(baseline))
    assert len(listed) == len(alone) > 0  # each move the tolerance alone called a fall, with its p-values
    assert all(line.count(" one-sided p = ") == 2 and " pooled" in line for line in listed)  # its own and its pool's
    assert [line.split(" (", 1)[0] for line in listed] == [line.split(" (", 1)[0] for line in alone]


def test_a_rate_of_more_episodes_than_can_be_weighed_keeps_the_tolerance_alone():
    """A count of 10**30 episodes (hand-edited) would keep the exact test working for ever: past
    100,000 episodes a rate is not weighed, and falls on the tolerance alone."""
    from oodmon.bench.baseline import _counted

    row = {"false_alarm_rate": 0.5, "false_alarms": 5 * 10**29, "episodes": 10**30}
    assert _counted(row, "false_alarm_rate", "false_alarms", "episodes") is None
    assert _counted(dict(row, false_alarms=50_000, episodes=100_000), "false_alarm_rate", "false_alarms",
                    "episodes") == (50_000, 100_000)
    result = _bench(np.random.default_rng(0))
    huge = dict(result, alarms=[dict(a, episodes=10**30, false_alarms=0, false_alarm_rate=0.0)
                                if a["variant"] == "cartpole" else a for a in result["alarms"]])
    risen = dict(huge, alarms=[dict(a, false_alarms=5 * 10**29, false_alarm_rate=0.5) if a["variant"] == "cartpole"
                               else a for a in huge["alarms"]])
    assert bench_falls(risen, huge) == [f"alarms/{m}/cartpole: false_alarm_rate rose from 0 to 0.5 (tolerance 0.02)"
                                        for m in METHODS]
