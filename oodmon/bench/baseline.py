"""``bench --baseline``: a new bench result against a committed one (``results/bench/*.json``).

A bench result (``bench --json``) is compared as data: per (method, variant, detector) the means
over trials of the per-step AUROC and AUPR (may not fall) and of the FPR at 95% TPR (may not rise);
under the monitor's protocol also, per (method, variant), the false-alarm rate (may not rise), the
share of failing episodes alarmed before the failure (may not fall), the median delay (may not
rise by more than the tolerance times its value) and the median lead (may not fall so). Both results
must come from the same settings (task, protocol, score, detectors, calibration...): a baseline made
otherwise is refused, not compared. A row the baseline has and the new result lacks is a fall too,
except the rows of methods the new run left out: a run of some of the baseline's methods
(``--methods dropout`` against a result of all three) is compared on their rows alone, as a bench's
cells of one method do not depend on which others it runs (:func:`methods_left_out`).
Where figures fell, :func:`provenance_notes` says whether the baseline's numbers were made by the
same weights and fitted detectors.

The alarm figures count episodes, ten per shifted variant, and move by chance wherever the
episodes do: the same command on a CPU whose float kernels round otherwise (its fitted detectors
differ) moved 7 figures of the CartPole monitor bench beyond the tolerance (2026-11-29,
``results/monitor/README.md``): one variant's episodes alarmed before the failure from 10 to 9 of
10, two lead medians (17.5 to 15 and 94 to 90 steps) and four median delays (2-3 to 3-7 steps),
and the tolerance alone called each a fall; weighed as below, none is one. So a
figure beyond the tolerance falls only when its move is also beyond chance, where both results
keep what it counts (``before_failure`` of ``failed``, ``false_alarms`` of ``episodes``,
``delays``, ``leads``): a rate by a one-sided Fisher exact test of its counts, a median by a
one-sided Mann-Whitney U test of its values. Held all together to :data:`~oodmon.replay.check.CHANCE`
(Tarone's Bonferroni over the figures that could reach it, as ``oodmon check``), the CartPole
bench's 246 figures would miss a collapse: 10 of 10 episodes alarmed before the failure falling to
2 of 10 (p = 3.6e-4) in one variant, or every lead halved (10 leads against 10: p = 0.027 each). So
``CHANCE`` is shared alike by the figures of each name (the rates' share then goes to the few that
could move: most variants alarm 10 of 10 before the failure, which no test can call a fall) and by
pools: each method's figures of one name pooled over its variants, a rate by the exact conditional
test of the strata's counts (the Mantel-Haenszel setting: a variant whose counts cannot move adds
nothing), a median by the strata's Mann-Whitney z-scores summed (Stouffer's rule; a variant whose
values are all tied adds nothing). Where a pool fell, each of its figures beyond the tolerance
falls. A check of unchanged code then fails with probability at most ``CHANCE``
(``tests/test_bench_baseline_chance.py`` simulates it). Results without the counts (written before
they were kept) and the AUROC rows (means over trials) keep the tolerance alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json
from oodmon.replay.check import (CHANCE, MOST_EPISODES, Odds, compare_metrics, mid_ranks,
                                 stratified_exact, u_variance)
from oodmon.validation import is_finite_real, is_whole

__all__ = ["BASELINE_TOLERANCE", "alarm_odds", "bench_falls", "bench_metrics", "check_same_settings", "load_bench_result",
           "methods_left_out", "provenance_notes", "stratified_ranks"]

#: The default allowed fall (AUROC, AUPR, rates) and relative rise (delays).
BASELINE_TOLERANCE = 0.02

_HIGHER = ("auroc", "aupr", "before_failure_rate", "lead_median")
#: Settings that may differ between a baseline and a new run without changing what is compared:
#: trials (rows are means over whatever trials each has) and where the run's logs live.
_FREE = ("trials",)


def load_bench_result(path: str | Path) -> dict:
    """Read a bench result written by ``oodmon bench --json`` (with its ``config``).

    Raises:
        ConfigError: missing, not JSON, or not a bench result.
    """
    data = read_json(path, name="bench result", missing="write one with `oodmon bench ... --json > FILE`",
                     folder="give the JSON file `oodmon bench --json` printed")
    if isinstance(data, dict) and isinstance(data.get("metrics"), dict) and "rows" not in data:
        raise ConfigError(f"{path} is a baseline of logs (`oodmon check --update` writes them), not a bench's results: "
                          f"check logs against it (oodmon check LOGS --baseline {path}), or a bench against the file "
                          "`oodmon bench --json` (or --results) wrote")
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list) or not isinstance(data.get("config"), dict):
        raise ConfigError(f"{path} is not an oodmon bench result: it needs 'config' and 'rows' (`oodmon bench --json` "
                          "writes them; results from before the bench recorded its config need one run again)")
    for what, needed in (("rows", ("method", "variant")), ("alarms", ("method", "variant"))):
        entries = data.get(what, [])
        if not isinstance(entries, list) or not all(isinstance(e, dict) and all(k in e for k in needed) for e in entries):
            raise ConfigError(f"{path}: an entry of its {what!r} lacks {', '.join(needed)}: not a bench result as "
                              "`oodmon bench --json` writes it (or a damaged one)")
    for what, figures in (("rows", _ROW_FIGURES), ("alarms", _ALARM_FIGURES)):
        for entry in data.get(what, []):
            for name, kind in figures.items():
                value = entry.get(name)
                if value is not None and not _is_kind(value, kind):
                    raise ConfigError(f"{path}: {what} entry {entry['method']}/{entry['variant']} has {name}={value!r:.40}: "
                                      f"it must be {_KINDS[kind]} or null (a damaged or hand-edited result?)")
    return data


#: The entries of a result's rows and alarm rows that bench_falls reads, and what each must be.
_ROW_FIGURES = {"mean": "number", "aupr_mean": "number", "fpr95_mean": "number"}
_ALARM_FIGURES = {"false_alarm_rate": "number", "before_failure_rate": "number", "delay_median": "number",
                  "lead_median": "number", "episodes": "count", "failed": "count", "before_failure": "count",
                  "false_alarms": "count", "delays": "numbers", "leads": "numbers"}
_KINDS = {"number": "a finite number", "count": "a whole number >= 0", "numbers": "a list of finite numbers"}


def _is_kind(value: object, kind: str) -> bool:
    if kind == "count":
        return is_whole(value, 0)
    if kind == "numbers":
        return isinstance(value, list) and all(is_finite_real(v) for v in value)
    return is_finite_real(value)


def bench_metrics(result: dict) -> dict[str, dict[str, float | None]]:
    """The compared figures of a bench result (as ``BenchResult.to_json`` gives it), by row key."""
    metrics: dict[str, dict[str, float | None]] = {}
    for row in result["rows"]:
        key = f"{row['method']}/{row['variant']}/{row.get('detector', 'spread')}"
        metrics[key] = {"auroc": row.get("mean"), "aupr": row.get("aupr_mean"), "fpr_at_95_tpr": row.get("fpr95_mean")}
    for alarm in result.get("alarms", []):
        key = f"alarms/{alarm['method']}/{alarm['variant']}"
        metrics[key] = {name: alarm.get(name)
                        for name in ("false_alarm_rate", "before_failure_rate", "delay_median", "lead_median")}
    return metrics


def check_same_settings(ours: dict, baseline: dict, baseline_name: str = "the baseline") -> None:
    """Refuse a baseline made with other settings than ``ours`` (a config's ``what_made_the_numbers``):
    before a bench starts, not after its hours of work.

    Raises:
        ConfigError: naming each setting that differs, with both values.
    """
    theirs = baseline["config"]
    differing = sorted(k for k in set(ours) | set(theirs) if k not in _FREE and ours.get(k) != theirs.get(k)
                       and not (k == "methods" and _some_of(ours.get(k), theirs.get(k))))
    if differing:
        raise ConfigError(f"{baseline_name} was made with other settings: "
                          + "; ".join(f"{k} {theirs.get(k)!r} there, {ours.get(k)!r} here" for k in differing)
                          + ". Run the bench as the baseline's command says, or compare with another baseline")


def _some_of(ours: object, theirs: object) -> bool:
    """Whether a run's methods are some of a baseline's (both lists of names, ours not empty)."""
    return (isinstance(ours, list) and isinstance(theirs, list) and bool(ours)
            and all(isinstance(m, str) for m in ours + theirs) and set(ours) <= set(theirs))


def methods_left_out(result: dict, baseline: dict) -> list[str]:
    """The baseline's methods (in its order) that ``result``'s run did not play: their rows are not
    compared (its settings otherwise the baseline's: :func:`check_same_settings`).

    Example:
        >>> methods_left_out({"config": {"methods": ["dropout"]}},
        ...                  {"config": {"methods": ["dropout", "dropconnect", "ensemble"]}})
        ['dropconnect', 'ensemble']
    """
    ours, theirs = result.get("config", {}).get("methods"), baseline["config"].get("methods")
    if not _some_of(ours, theirs):
        return []
    return [method for method in theirs if method not in ours]


def _without_methods(result: dict, methods: list[str]) -> dict:
    """``result`` without the rows and alarm rows of ``methods``."""
    if not methods:
        return result
    return dict(result, **{what: [entry for entry in result[what] if entry["method"] not in methods]
                           for what in ("rows", "alarms") if what in result})


def bench_falls(result: dict, baseline: dict, tolerance: float = BASELINE_TOLERANCE, *,
                baseline_name: str = "the baseline", weighed: bool = True, within: list[str] | None = None) -> list[str]:
    """One line per figure of ``baseline`` that ``result`` lacks or that moved the wrong way by
    more than ``tolerance`` (an alarm figure: and beyond chance, see the module docstring; the
    rows of the baseline's methods that ``result`` did not run are not compared, :func:`methods_left_out`;
    ``weighed=False``: the tolerance alone). ``within``: a list that gets a line for each alarm
    figure beyond the tolerance but within chance, with its p-values (what the tolerance alone would
    have called a fall).

    Raises:
        ConfigError: the two were made with different settings.
    """
    check_same_settings(result.get("config", {}), baseline, baseline_name)
    baseline = _without_methods(baseline, methods_left_out(result, baseline))
    expected = {key: {name: value for name, value in row.items() if value is not None}
                for key, row in bench_metrics(baseline).items()}
    odds, pools = alarm_odds(result, baseline) if weighed else (None, None)
    return compare_metrics(bench_metrics(result), expected, tolerance, what="this bench",
                           relative=("delay_median", "lead_median"), higher=_HIGHER, chance=CHANCE if weighed else None,
                           odds=odds, pools=pools, within=within)


def provenance_notes(result: dict, baseline: dict, baseline_name: str = "the baseline") -> list[str]:
    """Whether the baseline's numbers were made by the weights and the fitted detectors that made
    ``result``'s (``BenchResult.weights`` and ``.fitted``): a line naming each (method, trial) whose
    weights differ, a line naming each whose fits differ, or a line saying the baseline records
    neither; first, where both say it and it differs, the machine each ran on
    (:func:`~oodmon.versions.machine`); nothing where they are the same.

    The same command trains other weights, and fits other detectors, on a CPU whose float kernels
    round otherwise (an Intel one with AVX-512 beside the AMD EPYC one the committed results come
    from, 2026-11-29: docs/your-policy.md's Acrobot PPO, and the bench's own fits for the shipped CartPole
    agents): its figures move with them, not only with oodmon's code.

    Example:
        >>> provenance_notes({"weights": {"sb3": {0: "ab12"}}}, {"weights": {"sb3": {"0": "cd34"}}})
        ["the baseline's numbers are of other weights: sb3 trial 0 (cd34 there, ab12 here); ..."]
    """
    notes = []
    if baseline.get("machine") and result.get("machine") and baseline["machine"] != result["machine"]:
        older = "(family " in result["machine"] and "(family " not in baseline["machine"]
        notes.append(f"{baseline_name} was made on {baseline['machine']}; this run on {result['machine']}" + (
            " (the baseline's record names no CPU family and model, as before 2026-12-03: the same CPU or "
            "another)" if older else ""))
    if not baseline.get("weights"):
        return notes + [f"{baseline_name} records neither its weights' sha256 nor its fits' (bench results written before "
                "2026-11-29): whether its numbers are of this run's models and fitted detectors cannot be told; "
                "weights trained, or detectors fitted, on a CPU whose float kernels round otherwise differ"]
    for what, about in (("weights", "other weights"), ("fitted", "detectors fitted otherwise")):
        ours, theirs = _by_trial(result.get(what)), _by_trial(baseline.get(what))
        differing = [f"{method} trial {trial} {_difference(theirs[(method, trial)], ours[(method, trial)])}"
                     for method, trial in sorted(theirs.keys() & ours.keys())
                     if theirs[(method, trial)] != ours[(method, trial)]]
        if differing:
            notes.append(f"{baseline_name}'s numbers are of {about}: {'; '.join(differing)}; a figure moves with "
                         "them (a model retrained, or trained or fitted on a CPU whose float kernels round "
                         "otherwise), not only with oodmon's code")
    return notes


def _by_trial(table: dict | None) -> dict[tuple[str, str], object]:
    """A result's per (method, trial) table by (method, trial as text): JSON's keys and a result's own alike."""
    return {(method, str(trial)): value for method, trials in (table or {}).items() for trial, value in trials.items()}


def _difference(theirs: object, ours: object) -> str:
    """How a baseline's weights' sha256, or fits' fingerprints by detector, differ from ours."""
    if isinstance(theirs, dict) and isinstance(ours, dict):
        return "(" + ", ".join(sorted(d for d in theirs.keys() | ours.keys() if theirs.get(d) != ours.get(d))) + ")"
    return f"({str(theirs)[:12]} there, {str(ours)[:12]} here)"


#: The alarm rates weighed by chance, and the entries of an alarm row that count them (hits, of episodes).
_RATES = {"false_alarm_rate": ("false_alarms", "episodes"), "before_failure_rate": ("before_failure", "failed")}
#: The alarm medians weighed by chance, and the entry of an alarm row that holds their values.
_MEDIANS = {"delay_median": "delays", "lead_median": "leads"}


def alarm_odds(result: dict, baseline: dict) -> tuple[dict[tuple[str, str], Odds], dict[tuple[str, str], tuple[str, Odds]]]:
    """Each alarm figure's test of chance, by (row key, figure name), where both results keep what it
    counts; and each figure's pool, the method's variants of that figure together, by the same keys
    (see the module docstring)."""
    ours = {f"alarms/{a['method']}/{a['variant']}": a for a in result.get("alarms", [])}
    odds: dict[tuple[str, str], Odds] = {}
    strata: dict[tuple[str, str], list[tuple[str, tuple[int, int, int, int]]]] = {}
    for theirs in baseline.get("alarms", []):
        key = f"alarms/{theirs['method']}/{theirs['variant']}"
        now = ours.get(key)
        if now is None:
            continue
        for name, (hits, total) in _RATES.items():
            before, after = _counted(theirs, name, hits, total), _counted(now, name, hits, total)
            if before is not None and after is not None:
                table = (*before, *after)
                odds[(key, name)] = (*stratified_exact([table], name in _HIGHER),
                                     f"{before[0]}/{before[1]} to {after[0]}/{after[1]} episodes")
                strata.setdefault((theirs["method"], name), []).append((key, table))
        for name, field in _MEDIANS.items():
            values = _median_values(theirs, name, field), _median_values(now, name, field)
            if values[0] is not None and values[1] is not None:
                odds[(key, name)] = (*_ranks_beyond_chance(name in _HIGHER, *values), f"{len(values[0])} to "
                                     f"{len(values[1])} {field}")
                strata.setdefault((theirs["method"], name), []).append((key, values))
    pools: dict[tuple[str, str], tuple[str, Odds]] = {}
    for (method, name), members in strata.items():
        if len(members) < 2:  # a pool of one is its figure's own test
            continue
        higher = name in _HIGHER
        if name in _RATES:
            tables = [table for _, table in members]
            counts = [sum(table[i] for table in tables) for i in range(4)]
            pooled = (*stratified_exact(tables, higher), f"{method}'s {len(members)} variants pooled, "
                      f"{counts[0]}/{counts[1]} to {counts[2]}/{counts[3]} episodes")
        else:
            pooled = (*stratified_ranks([values for _, values in members], higher),
                      f"{method}'s {len(members)} variants' {_MEDIANS[name]} pooled")
        for key, _ in members:
            pools[(key, name)] = (f"{method}/{name}", pooled)
    return odds, pools


def _median_values(row: dict, name: str, field: str) -> list[float] | None:
    """The values whose median is the row's ``name``, or ``None`` (not kept, or not those values)."""
    median, values = row.get(name), row.get(field)
    if not (isinstance(values, list) and values and isinstance(median, (int, float))
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
            and abs(float(np.median(values)) - median) <= 1e-9):
        return None
    return [float(v) for v in values]


def _counted(row: dict, name: str, hits: str, total: str) -> tuple[int, int] | None:
    """``(hits, episodes)`` that the row's rate ``name`` is, or ``None`` (not kept, or not that rate)."""
    rate, k, n = row.get(name), row.get(hits), row.get(total)
    if (rate is None or not is_whole(n, 1) or not is_whole(k, 0) or k > n or n > MOST_EPISODES
            or abs(k / n - rate) > 1e-9):
        return None
    return int(k), int(n)


def _u_statistic(before: list[float], after: list[float], higher: bool) -> tuple[float, float, float] | None:
    """The new values' Mann-Whitney U, centred (its mean under no change subtracted) and signed so
    that a move the wrong way is positive (lower values where ``higher``); the same at the wrong end
    of the pooled values (the most it can be); and its tie-corrected standard deviation. ``None``
    where every value is tied (nothing to tell)."""
    n0, n1 = len(before), len(after)
    total = n0 + n1
    ranks, ties = mid_ranks(before + after)
    variance = u_variance(n0, n1, ties)
    if variance <= 0:
        return None
    mean = n1 * (total + 1) / 2.0  # of the new values' rank sum
    sorted_ranks = np.sort(ranks)
    worst = sorted_ranks[:n1].sum() if higher else sorted_ranks[-n1:].sum()
    sign = -1.0 if higher else 1.0
    return sign * (float(ranks[n0:].sum()) - mean), sign * (float(worst) - mean), math.sqrt(variance)


def _normal_tail(z: float) -> float:
    """P(Z >= z) for a standard normal Z."""
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def _ranks_beyond_chance(higher: bool, before: list[float], after: list[float]) -> tuple[float, float]:
    """The one-sided Mann-Whitney U p-value that the new values are lower (``higher``: a median that
    may not fall) or higher than the baseline's, and the least one their pooled values allow: the
    normal approximation with the tie correction and the continuity correction, as
    ``scipy.stats.mannwhitneyu(method="asymptotic")`` computes it, in a hundredth of its time."""
    u = _u_statistic(before, after, higher)
    if u is None:
        return 1.0, 1.0
    moved, most, std = u
    return _normal_tail((moved - 0.5) / std), _normal_tail((most - 0.5) / std)


def stratified_ranks(strata: list[tuple[list[float], list[float]]], higher: bool) -> tuple[float, float]:
    """The one-sided p-value that the new values (each stratum's ``(before, after)``) are lower
    (``higher``) or higher than the baseline's over all strata together, and the least one their
    values allow: each stratum's Mann-Whitney U as a z-score (its mean and tie-corrected variance
    under no change), summed over the strata and divided by the root of their number (Stouffer's
    rule, the strata weighed alike); a stratum whose values are all tied tells nothing and is left out.
    Normal, so approximate: ``tests/test_bench_baseline_chance.py`` checks its level on ten values a stratum.

    Example:
        >>> p, least = stratified_ranks([([40.0, 50, 60], [20.0, 25, 30])] * 4, higher=True)  # every lead halved
        >>> p < 1e-4, least == p
        (True, True)
    """
    z = extreme = 0.0
    count = 0
    for before, after in strata:
        u = _u_statistic(before, after, higher)
        if u is None:
            continue
        z, extreme, count = z + u[0] / u[2], extreme + u[1] / u[2], count + 1
    if count == 0:
        return 1.0, 1.0
    return _normal_tail(z / math.sqrt(count)), _normal_tail(extreme / math.sqrt(count))
