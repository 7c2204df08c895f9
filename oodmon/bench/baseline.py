"""``bench --baseline``: a new bench result against a committed one (``results/bench/*.json``).

A bench result (``bench --json``) is compared as data: per (method, variant, detector) the means
over trials of the per-step AUROC and AUPR (may not fall) and of the FPR at 95% TPR (may not rise);
under the monitor's protocol also, per (method, variant), the false-alarm rate (may not rise), the
share of failing episodes alarmed before the failure (may not fall) and the median delay (may not
rise by more than the tolerance times its value). Both results must come from the same settings
(task, protocol, score, detectors, calibration...): a baseline made otherwise is refused, not
compared. A row the baseline has and the new result lacks is a fall too. Where figures fell,
:func:`provenance_notes` says whether the baseline's numbers were made by the same weights and fitted
detectors.
"""

from __future__ import annotations

from pathlib import Path

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json
from oodmon.replay.check import compare_metrics

__all__ = ["BASELINE_TOLERANCE", "bench_falls", "bench_metrics", "check_same_settings", "load_bench_result",
           "provenance_notes"]

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
    if not isinstance(data, dict) or not isinstance(data.get("rows"), list) or not isinstance(data.get("config"), dict):
        raise ConfigError(f"{path} is not an oodmon bench result: it needs 'config' and 'rows' (`oodmon bench --json` "
                          "writes them; results from before the bench recorded its config need one run again)")
    for what, needed in (("rows", ("method", "variant")), ("alarms", ("method", "variant"))):
        entries = data.get(what, [])
        if not isinstance(entries, list) or not all(isinstance(e, dict) and all(k in e for k in needed) for e in entries):
            raise ConfigError(f"{path}: an entry of its {what!r} lacks {', '.join(needed)}: not a bench result as "
                              "`oodmon bench --json` writes it (or a damaged one)")
    return data


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
    differing = sorted(k for k in set(ours) | set(theirs) if k not in _FREE and ours.get(k) != theirs.get(k))
    if differing:
        raise ConfigError(f"{baseline_name} was made with other settings: "
                          + "; ".join(f"{k} {theirs.get(k)!r} there, {ours.get(k)!r} here" for k in differing)
                          + ". Run the bench as the baseline's command says, or compare with another baseline")


def bench_falls(result: dict, baseline: dict, tolerance: float = BASELINE_TOLERANCE, *,
                baseline_name: str = "the baseline") -> list[str]:
    """One line per figure of ``baseline`` that ``result`` lacks or that moved the wrong way by
    more than ``tolerance``.

    Raises:
        ConfigError: the two were made with different settings.
    """
    check_same_settings(result.get("config", {}), baseline, baseline_name)
    expected = {key: {name: value for name, value in row.items() if value is not None}
                for key, row in bench_metrics(baseline).items()}
    return compare_metrics(bench_metrics(result), expected, tolerance, what="this bench",
                           relative=("delay_median", "lead_median"), higher=_HIGHER)


def provenance_notes(result: dict, baseline: dict, baseline_name: str = "the baseline") -> list[str]:
    """Whether the baseline's numbers were made by the weights and the fitted detectors that made
    ``result``'s (``BenchResult.weights`` and ``.fitted``): a line naming each (method, trial) whose
    weights differ, a line naming each whose fits differ, or a line saying the baseline records
    neither; first, where both say it and it differs, the machine each ran on
    (:func:`~oodmon.versions.machine`); nothing where they are the same.

    The same command trains other weights, and fits other detectors, on a CPU whose float kernels
    round otherwise (an Intel one with AVX-512 beside the AMD EPYC one the committed results come
    from, 2026-11-29: the README's Acrobot PPO, and the bench's own fits for the shipped CartPole
    agents): its figures move with them, not only with oodmon's code.

    Example:
        >>> provenance_notes({"weights": {"sb3": {0: "ab12"}}}, {"weights": {"sb3": {"0": "cd34"}}})
        ["the baseline's numbers are of other weights: sb3 trial 0 (cd34 there, ab12 here); ..."]
    """
    notes = []
    if baseline.get("machine") and result.get("machine") and baseline["machine"] != result["machine"]:
        notes.append(f"{baseline_name} was made on {baseline['machine']}; this run on {result['machine']}")
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
