"""Regression checks over recorded logs: metrics against a baseline file.

The baseline is JSON: ``{"tolerance": 0.02, "metrics": {"task/method/variant": {name: value}}}``.
A metric *falls* when it moves the wrong way by more than the tolerance: AUROC, AUPR and the
detection rate going down; the FPR at 95% TPR, the false-alarm rates and the mean delay going
up (delays by more than the tolerance times their baseline, since they count steps).

The alarm rates count episodes, and a run of an MC agent draws its decisions anew: the same
command run twice alarmed early in 3 and in 5 of 20 CartPole DropConnect episodes (0.15, 0.25),
and the check said the second had got worse. So a baseline written since 2026-11-29 keeps each
row's ``alarm_episodes`` (the rates' denominator), and a rate whose baseline and new value are
counts of their episodes falls only when it also moved more than chance allows: a one-sided
Fisher exact test of the two counts, at :data:`CHANCE` divided among the figures so compared that
could reach it (Tarone's Bonferroni: 10 of 10 episodes before and after cannot), so that a check
of unchanged code fails on them with probability at most :data:`CHANCE`. So too the mean delay,
whose baseline row keeps the ``delays`` it is the mean of (one run's 1.05 steps and another's 1.15
were a fall): a one-sided Mann-Whitney U test of the two runs' delays. Older baselines, and
figures edited by hand, keep the tolerance alone. The price: with many figures compared, a fall
must be large to count (``bench --baseline``, with 246 figures of 10 episodes each in the CartPole
monitor bench, shares the level otherwise and pools the variants: :mod:`oodmon.bench.baseline`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json
from oodmon.replay.metrics import VariantMetrics
from oodmon.replay.reader import RunLog
from oodmon.validation import is_finite_real, is_whole

__all__ = ["CHANCE", "HIGHER_IS_BETTER", "LOWER_IS_BETTER", "Odds", "baseline_of", "check_tolerance", "compare_metrics",
           "MOST_EPISODES", "find_falls", "load_baseline", "mann_whitney_greater", "mid_ranks", "noise_differences",
           "noise_of_logs", "stratified_exact", "u_variance"]

HIGHER_IS_BETTER = ("auroc", "aupr", "detection_rate")
LOWER_IS_BETTER = ("fpr_at_95_tpr", "false_alarm_rate", "early_alarm_rate", "delay_mean")
#: The rates that count episodes (of ``alarm_episodes``), weighed by chance as well.
EPISODE_RATES = ("false_alarm_rate", "early_alarm_rate", "detection_rate")
#: The chance that a check of unchanged code finds an episode rate fallen (see the module docstring).
CHANCE = 0.01
COUNT, DELAYS = "alarm_episodes", "delays"
#: A baseline's sensor noises by task/method (:func:`noise_of_logs`), since 2026-12-05.
NOISE = "obs_noise"
#: The episodes the detection rate counts where fewer than ``alarm_episodes``: those in which the
#: shift began (the others ended before their onset); a row without it counts ``alarm_episodes``.
SHIFTED = "shifted_episodes"
_NOT_FIGURES = (COUNT, DELAYS, SHIFTED)  # what a row keeps to weigh its figures by, not figures


def baseline_of(metrics: Sequence[VariantMetrics], tolerance: float,
                noise: dict[str, list[float]] | None = None) -> dict:
    """The baseline that ``metrics`` would write (``oodmon check --update``); ``noise``: the sensor
    noises their episodes were played at, by ``task/method`` (:func:`noise_of_logs`), kept as
    ``obs_noise`` (since 2026-12-05) so that a check of logs played at others says so."""
    return {
        "tolerance": tolerance,
        "metrics": {m.key: _row(m, keep_none=False) for m in metrics},
    } | ({NOISE: noise} if noise else {})


def noise_of_logs(logs: Iterable[RunLog]) -> dict[str, list[float]]:
    """The sensor noises the logs' complete episodes were played at (each episode's ``obs_noise``;
    0 in logs older than format 8), by ``task/method``, each list sorted."""
    found: dict[str, set[float]] = {}
    for log in logs:
        found.setdefault(f"{log.task}/{log.method}", set()).update(log.noises)
    return {group: sorted(noises) for group, noises in found.items() if noises}


def noise_differences(noise: dict[str, list[float]], baseline: dict) -> list[str]:
    """One line per ``task/method`` whose episodes were played at other sensor noises than the
    baseline's (a baseline written before 2026-12-05 records none: nothing to compare): a noisy
    sensor moves every detector's scores, so a fall there may be the world's, not the code's."""
    before = baseline.get(NOISE, {})

    def said(noises: list[float]) -> str:
        return ", ".join(f"{n:g}" for n in noises)

    return [f"the {group} logs were played at sensor noise {said(noises)}, the baseline's at {said(before[group])}"
            for group, noises in noise.items() if group in before and sorted(before[group]) != noises]


def _row(m: VariantMetrics, *, keep_none: bool) -> dict:
    """A row's compared figures and what weighs them (``keep_none``: its figures that are ``None`` too):
    ``shifted_episodes`` only where fewer than ``alarm_episodes``, the delays where there are any."""
    row = {name: getattr(m, name) for name in HIGHER_IS_BETTER + LOWER_IS_BETTER + (COUNT,)
           if keep_none or getattr(m, name) is not None}
    if m.shifted_episodes is not None and m.shifted_episodes != m.alarm_episodes:
        row[SHIFTED] = m.shifted_episodes
    return row | ({DELAYS: list(m.delays)} if m.delays or keep_none else {})


def _episodes_of(row: dict, name: str) -> object:
    """The episodes a row's rate ``name`` counts (see :data:`SHIFTED`)."""
    return row[SHIFTED] if name == "detection_rate" and SHIFTED in row else row.get(COUNT)


def load_baseline(path: str | Path) -> dict:
    """Read and check a baseline file (see the module docstring).

    Raises:
        ConfigError: the file is missing, not JSON, or not a baseline: every metric must be a known
            name with a finite number, the tolerance a number >= 0.
    """
    path = Path(path)
    data = read_json(path, name="baseline", missing=f"write one with `oodmon check LOGS --baseline {path} --update`",
                     folder="give the JSON file `oodmon check --update` wrote")
    if isinstance(data, dict) and "metrics" not in data and {"config", "rows"} <= set(data):  # results/bench/*.json
        raise ConfigError(f"{path} is the results of `oodmon bench`, not a baseline of logs: compare a bench with it "
                          f"(oodmon bench ... --baseline {path}), or logs with a baseline `oodmon check LOGS --baseline "
                          "FILE --update` writes")
    if not isinstance(data, dict) or not isinstance(data.get("metrics"), dict):
        got = data.get("metrics") if isinstance(data, dict) else data
        raise ConfigError(f"{path} is not an oodmon baseline: 'metrics' must be an object of rows, not {got!r:.40}")
    known = HIGHER_IS_BETTER + LOWER_IS_BETTER
    for key, row in data["metrics"].items():
        if not isinstance(row, dict):
            raise ConfigError(f"{path}: metrics[{key!r}]={row!r:.40} is not allowed; each row maps metric names to numbers")
        for name, value in row.items():
            if name in (COUNT, SHIFTED):
                if not is_whole(value, 1):
                    counts = "alarm rates count" if name == COUNT else "detection rate counts"
                    raise ConfigError(f"{path}: metrics[{key!r}][{name!r}]={value!r:.40} is not allowed; give the "
                                      f"whole number >= 1 of episodes the row's {counts}")
                continue
            if name == DELAYS:
                if not (isinstance(value, list) and value and all(is_whole(d, 0) for d in value)):
                    raise ConfigError(f"{path}: metrics[{key!r}][{DELAYS!r}]={value!r:.40} is not allowed; give the "
                                      "list of the detected episodes' delays in steps (whole numbers >= 0)")
                continue
            if name not in known:
                raise ConfigError(f"{path}: metrics[{key!r}] has unknown metric {name!r}; known: {', '.join(known)}")
            if not is_finite_real(value):
                raise ConfigError(f"{path}: metrics[{key!r}][{name!r}]={value!r:.40} is not allowed; give a finite number")
    if "tolerance" in data:
        check_tolerance(data["tolerance"], f"{path}: tolerance")
    noise = data.get(NOISE, {})
    if not isinstance(noise, dict) or not all(
            isinstance(v, list) and all(is_finite_real(n) and n >= 0 for n in v) for v in noise.values()):
        raise ConfigError(f"{path}: {NOISE}={noise!r:.60} is not allowed; give the sensor noises each task/method's "
                          "episodes were played at, as lists of numbers >= 0 by task/method")
    return data


def check_tolerance(value: object, name: str = "tolerance") -> float:
    """``value`` as a float if it is a finite number >= 0, else :class:`ConfigError`."""
    if not is_finite_real(value) or value < 0:
        raise ConfigError(f"{name}={value!r} is not allowed; give a finite number >= 0 (the allowed fall)")
    return float(value)


def find_falls(metrics: Sequence[VariantMetrics], baseline: dict, tolerance: float | None = None, *,
               within: list[str] | None = None) -> list[str]:
    """One line per metric that fell below its baseline by more than the tolerance (an episode rate
    of counted episodes: and by more than chance, see the module docstring), or went missing;
    ``within``: a list that gets the moves beyond the tolerance within chance (see :func:`compare_metrics`)."""
    tolerance = baseline.get("tolerance", 0.02) if tolerance is None else tolerance
    current = {m.key: _row(m, keep_none=True) for m in metrics}
    return compare_metrics(current, baseline["metrics"], tolerance, what="the logs", chance=CHANCE, within=within)


#: The most episodes a rate may count to be weighed by chance (the exact test's work grows with them;
#: a hand-edited count of 10**30 would not end): more keep the tolerance alone.
MOST_EPISODES = 100_000


def _count(rate: float, episodes: object) -> int | None:
    """``rate`` as a count of ``episodes``, or ``None`` when it is not one (no count kept, a rate
    edited by hand, or more than :data:`MOST_EPISODES`)."""
    if not is_whole(episodes, 1) or episodes > MOST_EPISODES:
        return None
    count = round(rate * episodes)
    return count if abs(count - rate * episodes) < 1e-6 else None


def _beyond_chance(higher: bool, was: float, now: float, before: object, after: object
                   ) -> tuple[float, float, str] | None:
    """The one-sided Fisher exact p-value of an episode rate's move the wrong way (down where
    ``higher`` is better), the least one its margins allow, and its counts' words; ``None`` when
    either value is not a count of its episodes."""
    k0, k1 = _count(was, before), _count(now, after)
    if k0 is None or k1 is None:
        return None
    return *stratified_exact([(k0, before, k1, after)], higher), f"{k0}/{before} to {k1}/{after} episodes"


def stratified_exact(tables: list[tuple[int, int, int, int]], higher: bool) -> tuple[float, float]:
    """The one-sided exact p-value that the new rows' hits are as few (``higher``: a rate that may
    not fall) or as many as observed, given each stratum's margins, over strata ``(hits before,
    episodes before, hits after, episodes after)``; and the least p-value those margins allow.
    Conditional on its margins a stratum's new hits are hypergeometric, independent of the other
    strata's: their sum's distribution is the convolution. One stratum: Fisher's exact test.

    Example:
        >>> p, least = stratified_exact([(10, 10, 2, 10)], higher=True)  # 10 of 10, then 2 of 10
        >>> round(p, 6), round(least, 6)
        (0.000357, 0.000357)
    """
    distribution, offset, observed = np.ones(1), 0, 0
    for k0, n0, k1, n1 in tables:
        hits = k0 + k1
        low, high = max(0, hits - n0), min(n1, hits)
        ways = math.comb(n0 + n1, n1)
        pmf = [math.comb(hits, a) * math.comb(n0 + n1 - hits, n1 - a) / ways for a in range(low, high + 1)]
        distribution = np.convolve(distribution, pmf)
        offset, observed = offset + low, observed + k1
    at = observed - offset
    if higher:
        return min(1.0, float(distribution[:at + 1].sum())), float(distribution[0])
    return min(1.0, float(distribution[at:].sum())), float(distribution[-1])


def _delays_beyond_chance(was: float, now: float, before: object, after: object) -> tuple[float, float, str] | None:
    """The one-sided Mann-Whitney U p-value of the delays ``after`` being longer than ``before``,
    the least one their pooled values allow, and their words; ``None`` when either list is not the
    delays whose mean is given."""
    if not (isinstance(before, list) and before and isinstance(after, list) and after
            and abs(float(np.mean(before)) - was) <= 1e-9 and abs(float(np.mean(after)) - now) <= 1e-9):
        return None
    p = mann_whitney_greater(after, before)
    # the least p-value any split of the pooled delays gives (Tarone): the new ones the longest
    pooled = sorted(before + after)
    least = mann_whitney_greater(pooled[len(before):], pooled[:len(before)])
    return (1.0 if math.isnan(p) else p), (1.0 if math.isnan(least) else least), f"{len(before)} to {len(after)} delays"


def mid_ranks(values: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """The ranks of ``values`` from 1, tied ones sharing their mean rank, and the sizes of the runs
    of equal values (the Mann-Whitney U's tie correction, :func:`u_variance`).

    Example:
        >>> ranks, ties = mid_ranks([3.0, 1.0, 3.0, 2.0])
        >>> ranks.tolist(), ties.tolist()
        ([3.5, 1.0, 3.5, 2.0], [1, 1, 2])
    """
    _, inverse, ties = np.unique(np.asarray(values, dtype=float), return_inverse=True, return_counts=True)
    below = np.cumsum(ties) - ties  # how many values lie below each distinct one
    return (below + (ties + 1) / 2.0)[inverse], ties


def u_variance(n0: int, n1: int, ties: np.ndarray) -> float:
    """The variance of the Mann-Whitney U of samples of ``n0`` and ``n1`` values under no
    difference, corrected for the runs of tied values of sizes ``ties`` (:func:`mid_ranks`)."""
    total = n0 + n1
    return n0 * n1 / 12.0 * ((total + 1) - float((ties ** 3 - ties).sum()) / (total * (total - 1)))


def mann_whitney_greater(x: Sequence[float], y: Sequence[float]) -> float:
    """The one-sided Mann-Whitney U p-value that ``x`` tends to be greater than ``y``: what
    ``scipy.stats.mannwhitneyu(x, y, alternative="greater").pvalue`` gives (SciPy 1.17's method
    "auto", to the bit), without importing ``scipy.stats`` (0.4 s of the start of every ``oodmon
    check`` of logs whose alarms have delays, before 2026-12-04). Exact (:func:`_u_survival`) when
    a sample has at most 8 values and none are tied; otherwise the normal approximation with the
    tie and continuity corrections.

    Example:
        >>> mann_whitney_greater([4.0, 5.0, 6.0], [1.0, 2.0, 3.0])  # 1 of the 20 splits is as extreme
        0.05
    """
    from scipy.special import ndtr

    n1, n2 = len(x), len(y)
    ranks, ties = mid_ranks([*x, *y])
    u = float(ranks[:n1].sum()) - n1 * (n1 + 1) / 2
    if (n1 <= 8 or n2 <= 8) and not np.any(ties > 1):
        return float(np.clip(_u_survival(n1, n2, int(u)), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.float64(u - n1 * n2 / 2 - 0.5) / math.sqrt(u_variance(n1, n2, ties))
    return float(np.clip(ndtr(-z), 0.0, 1.0))


def _u_survival(n1: int, n2: int, u: int) -> float:
    """P(U >= u) under no difference, for samples of ``n1`` and ``n2`` untied values: SciPy's
    ``_MWU.sf``, the frequencies of U by the recurrence of Löffler (1983) as SciPy computes them
    (whole counts while they fit in 64 bits, floats beyond), summed from the nearer tail."""
    from scipy.special import binom

    n1, n2 = min(n1, n2), max(n1, n2)
    complement = n1 * n2 - u
    nearer = min(u, complement)
    # sigma(k): the sum of k's divisors d <= n1, less those with n2 < d <= n1 + n2 (the recurrence's weights)
    sigma = np.zeros(nearer + 1, dtype=int)
    for d in np.arange(1, n1 + 1):
        sigma[np.arange(d, nearer + 1, d)] += d
    for d in np.arange(n2 + 1, n2 + n1 + 1):
        sigma[np.arange(d, nearer + 1, d)] -= d
    sigma = sigma[1:]
    counts = np.zeros(nearer + 1, dtype=np.uint64)
    counts[0] = 1
    whole, most = True, np.iinfo(np.uint64).max
    for k in np.arange(1, nearer + 1):
        value = np.dot(counts[:k], sigma[k - 1::-1]) / k
        if whole and value > most:
            counts, whole = counts.astype(float), False
        counts[k] = value
    pmf = counts / binom(n1 + n2, n1)
    below = np.cumsum(pmf)[nearer]
    return float(1.0 - below + pmf[nearer]) if u < complement else float(below)


def _tarone_level(least: Sequence[float], chance: float) -> float:
    """The level each of the tests whose least attainable p-values are ``least`` is held to, so that
    together they reject a true null with probability at most ``chance`` (Tarone's Bonferroni: a
    test that cannot reach the level, e.g. 10 of 10 episodes alarmed before and after, is not
    counted; Tarone, Biometrics 1990).

    Example:
        >>> _tarone_level([1.0, 1.0, 1.0, 1e-4], 0.01)  # three tests that cannot reject: one counted
        0.01
    """
    for k in range(1, len(least) + 1):
        if sum(p <= chance / k for p in least) <= k:
            return chance / k
    return chance / max(len(least), 1)


Odds = tuple[float, float, str]  # a figure's one-sided p-value, the least its margins allow, and its counts' words


def compare_metrics(current: dict[str, dict[str, float | None]], expected: dict[str, dict[str, float]],
                    tolerance: float, *, what: str = "the new results", relative: Sequence[str] = ("delay_mean",),
                    higher: Sequence[str] = HIGHER_IS_BETTER, chance: float | None = None,
                    odds: dict[tuple[str, str], Odds] | None = None,
                    pools: dict[tuple[str, str], tuple[str, Odds]] | None = None,
                    within: list[str] | None = None) -> list[str]:
    """One line per metric of ``expected`` (rows of ``{name: value}`` by key) that ``current``
    lacks or that moved the wrong way by more than ``tolerance``: names in ``higher`` may not fall,
    every other name may not rise, those in ``relative`` (delays and leads, counted in steps) by
    more than ``tolerance`` times their baseline value. ``chance``: an episode rate whose both rows
    count their episodes (``alarm_episodes``), and a mean delay whose both rows keep their
    ``delays``, fall only if their move is also beyond chance at this level, shared among the
    figures so compared that could reach it (see the module docstring; ``oodmon check``).
    ``odds``: those p-values by (key, name), computed by the caller instead (``bench --baseline``);
    ``pools``: a (key, name)'s pool of figures (a name of the pool, and the pooled test's odds):
    ``chance`` is then shared alike by the pools and by the figures of each name, each family held
    to its share by Tarone's rule, and a figure beyond the tolerance falls when its own test or its
    pool's is beyond chance (:mod:`oodmon.bench.baseline`). ``within``: a list that gets a line
    for each figure beyond the tolerance but within chance (no fall; the tolerance alone would have
    called it one), with its p-values. Shared by ``oodmon check`` (logs) and ``bench --baseline``."""
    falls: list[str] = []
    # each figure weighed by chance that moved beyond the tolerance: (where its line goes, p, line, family, pool)
    weighed: list[tuple[int, float, str, str | None, tuple[str, Odds] | None]] = []
    # the least attainable p-value of each figure so compared, moved or not, by family: one family
    # (oodmon check), or with pools one per figure name and one of the pools (bench --baseline)
    least: dict[str | None, list[float]] = {}
    for key, row in sorted(expected.items()):
        if key not in current:
            falls.append(f"{key}: missing from {what} (the baseline has it)")
            continue
        for name, was in row.items():
            if name in _NOT_FIGURES:
                continue
            now = current[key].get(name)
            if now is None:
                falls.append(f"{key}: {name} is missing (baseline {was:.4g})")
                continue
            worse = (now < (was * (1 - tolerance) if name in relative else was - tolerance) if name in higher
                     else now > (was * (1 + tolerance) if name in relative else was + tolerance))
            moved = f"{key}: {name} {'fell' if name in higher else 'rose'} from {was:.4g} to {now:.4g}"
            figure = None
            if chance is not None and odds is not None:
                figure = odds.get((key, name))
            elif chance is not None and name in EPISODE_RATES:
                figure = _beyond_chance(name in higher, was, now, _episodes_of(row, name), _episodes_of(current[key], name))
            elif chance is not None and name == "delay_mean":
                figure = _delays_beyond_chance(was, now, row.get(DELAYS), current[key].get(DELAYS))
            if figure is not None:
                least.setdefault(name if pools else None, []).append(figure[1])
                if worse:
                    weighed.append((len(falls), figure[0], f"{moved} ({figure[2]}, one-sided p = {figure[0]:.2g}",
                                    name if pools else None, (pools or {}).get((key, name))))
            elif worse:
                falls.append(f"{moved} (tolerance {tolerance})")
    if not weighed:
        return falls
    share = chance / (len(least) + (1 if pools else 0))
    level = {family: _tarone_level(values, share) for family, values in least.items()}
    pool_level = _tarone_level([odds[1] for odds in dict(pools.values()).values()], share) if pools else 0.0
    kept = []
    for at, p, line, family, pool in weighed:
        pooled = "" if pool is None else f"; {pool[1][2]}, one-sided p = {pool[1][0]:.2g}"
        if p <= level[family]:
            kept.append((at, f"{line}; tolerance {tolerance})"))
        elif pool is not None and pool[1][0] <= pool_level:
            kept.append((at, f"{line}, within chance alone{pooled}; tolerance {tolerance})"))
        elif within is not None:
            within.append(f"{line}{pooled}; tolerance {tolerance})")
    for offset, (at, line) in enumerate(kept):
        falls.insert(at + offset, line)
    return falls
