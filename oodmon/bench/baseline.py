"""``bench --baseline``: a new bench result against a committed one (``results/bench/*.json``).

A bench result (``bench --json``) is compared as data: per (method, variant, detector) the means
over trials of the per-step AUROC and AUPR (may not fall) and of the FPR at 95% TPR (may not rise);
under the monitor's protocol also, per (method, variant), the false-alarm rate (may not rise), the
share of failing episodes alarmed before the failure (may not fall) and the median delay (may not
rise by more than the tolerance times its value). Both results must come from the same settings
(task, protocol, score, detectors, calibration...): a baseline made otherwise is refused, not
compared. A row the baseline has and the new result lacks is a fall too. Where figures fell,
:func:`weights_notes` says whether the baseline's numbers were made by the same weights.
"""

from __future__ import annotations

from pathlib import Path

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json
from oodmon.replay.check import compare_metrics

__all__ = ["BASELINE_TOLERANCE", "bench_falls", "bench_metrics", "check_same_settings", "load_bench_result",
           "weights_notes"]

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


def weights_notes(result: dict, baseline: dict, baseline_name: str = "the baseline") -> list[str]:
    """Whether the baseline's numbers were made by the weights that made ``result``'s (each
    (method, trial)'s sha256, ``BenchResult.weights``): a line naming each (method, trial) whose
    weights differ, or a line saying the baseline records none; nothing where they are the same.

    The same command trains other weights on a CPU whose float kernels round otherwise (an AVX-512
    one beside an AVX2 one, 2026-11-29: the README's Acrobot PPO), and a retrained model is another
    policy: its figures move with its weights, not only with oodmon's code.

    Example:
        >>> weights_notes({"weights": {"sb3": {0: "ab12"}}}, {"weights": {"sb3": {"0": "cd34"}}})
        ["the baseline's numbers are of other weights: sb3 trial 0 (cd34 there, ab12 here); ..."]
    """
    theirs = baseline.get("weights")
    if not theirs:
        return [f"{baseline_name} records no weights' sha256 (bench results written before 2026-11-29): whether "
                "its numbers are of this run's models cannot be told; retrained ones are other policies"]
    ours = {method: {str(trial): sha for trial, sha in trials.items()} for method, trials in result.get("weights", {}).items()}
    differing = [f"{method} trial {trial} ({sha[:12]} there, {ours[method][trial][:12]} here)"
                 for method, trials in theirs.items() for trial, sha in trials.items()
                 if trial in ours.get(method, {}) and ours[method][trial] != sha]
    if not differing:
        return []
    return [f"{baseline_name}'s numbers are of other weights: {'; '.join(differing)}; a figure moves with the weights "
            "(a model retrained, or trained on a CPU whose float kernels round otherwise), not only with oodmon's code"]
