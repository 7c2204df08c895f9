"""What a bench result says: the best AUROCs, the paper's variants we have no AUROC for, the
alarms per variant."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence

import numpy as np
from rich.console import Console
from rich.table import Table

from oodmon.agents.evaluation import SOLVED_RETURN
from oodmon.bench.config import PAPER_METHOD, BenchConfig, BenchResult, paper_label
from oodmon.names import TASKS
from oodmon.paper import paper_auc_per_trial

def best_per_method(result: BenchResult, task: str, top: int = 3,
                    detector: str = "spread") -> list[tuple[str, str, float, float | None]]:
    """Per method, the variants with the best single-trial AUROC of ``detector`` (the paper's main
    tables: the spread), with the paper's best trial for the same variant where it reports one."""
    best = []
    for method in sorted({r.method for r in result.rows}):
        rows = sorted((r for r in result.rows if r.method == method and r.detector == detector),
                      key=lambda r: -max(r.aurocs.values()))
        for row in rows[:top]:
            best.append((method, row.variant, max(row.aurocs.values()), max(row.paper) if row.paper else None))
    return best


def paper_only_variants(result: BenchResult, task: str, methods: Iterable[str],
                        ran: Iterable[str] | None = None) -> list[tuple[str, str, float]]:
    """Variants the paper reports for a method that our agents did not fail on (so no AUROC).

    ``ran`` (spec strings) limits this to the variants the bench ran; a variant left out of the
    run is not "not failed"."""
    ours = {(r.method, r.variant) for r in result.rows}
    ran_specs = None if ran is None else list(ran)
    missing = []
    table = paper_auc_per_trial().get(task, {})
    for method in methods:
        for label, values in table.get(PAPER_METHOD.get(method, ""), {}).items():
            if ran_specs is not None and not any(paper_label(task, method, spec) == label for spec in ran_specs):
                continue
            if not any(paper_label(task, method, v) == label for (m, v) in ours if m == method):
                missing.append((method, label, max(values)))
    return missing


def unfailed_variants(config: BenchConfig, result: BenchResult) -> dict[str, list[str]]:
    """Per method, the variants of the run that no trial failed on (their mean return over the
    evaluation episodes stayed above the failure line, ``oodmon.agents.evaluation``): the bench
    scores no episode of them, unless ``all_variants``, where this is empty."""
    if config.all_variants:
        return {}
    specs = [v.spec for v in config.variant_list()]
    unfailed = {}
    for method, trials in result.failing.items():
        failed = {spec for specs_failed in trials.values() for spec in specs_failed}
        left = [spec for spec in specs if spec not in failed]
        if left:
            unfailed[method] = left
    return unfailed


def print_unfailed(config: BenchConfig, result: BenchResult, console: Console) -> None:
    """One line on the variants the run left out because no trial failed on them: their specs when
    the command named the variants, their count for the paper's grid (the paper's own variants
    among them have a line of their own)."""
    unfailed = unfailed_variants(config, result)
    if not unfailed:
        return
    total = len(config.variant_list())
    named = config.variants != "paper"
    what = ", ".join(f"{method} {', '.join(specs)}" if named else f"{method} {len(specs)} of {total}"
                     for method, specs in unfailed.items())
    console.print(f"Variants no trial failed on, so not {'monitored' if config.protocol == 'monitor' else 'scored'} "
                  f"(mean return over {config.eval_episodes} episodes above the failure line; --all-variants "
                  f"runs every variant): {what}")


def alarms_per_variant(result: BenchResult) -> list[tuple[str, str, float | None, float | None, float | None]]:
    """What the monitor's alarm rule did, per method and variant, averaged over the trials that have
    a value: ``(method, variant, false_alarm_rate, detection_rate, delay_mean)``. The ID variant has
    the false-alarm rate (alarmed ID episodes), the failing ones the detection rate (alarmed
    episodes) and the mean delay in steps to the first alarm of those detected."""
    grouped: dict[tuple[str, str], list[dict[str, float | None]]] = {}
    for key, values in result.detection.items():
        method, _, variant = key.split("/", 2)
        grouped.setdefault((method, variant), []).append(values)

    def mean(values: list[dict[str, float | None]], name: str) -> float | None:
        present = [v[name] for v in values if v[name] is not None]
        return float(np.mean(present)) if present else None

    return [(method, variant, mean(v, "false_alarm_rate"), mean(v, "detection_rate"), mean(v, "delay_mean"))
            for (method, variant), v in sorted(grouped.items(), key=lambda item: (item[0][0], ":" in item[0][1],
                                                                                     item[0][1]))]


def episodes_failing(detection: dict, method: str, variant: str, trials: Iterable) -> tuple[int, int] | None:
    """Of the shifted episodes of ``variant`` that ``trials`` of ``method`` played, how many failed and
    how many there were, from :attr:`BenchResult.detection` or its JSON (``monitor``); ``None`` where
    a cell has no count (the bench counts CartPole's only, since 2026-11-26). The paper's protocol
    scores every step of the episodes the agent coped with as shifted too.

    Example:
        >>> cells = {"dropconnect/trial0/cartpole:masscart=9.0": {"episodes": 5, "failed": 5},
        ...          "dropconnect/trial1/cartpole:masscart=9.0": {"episodes": 5, "failed": 3}}
        >>> episodes_failing(cells, "dropconnect", "cartpole:masscart=9.0", [0, 1])
        (8, 10)
    """
    cells = [detection.get(f"{method}/trial{trial}/{variant}", {}) for trial in trials]
    if any(cell.get("failed") is None for cell in cells):
        return None
    return sum(cell["failed"] for cell in cells), sum(cell["episodes"] for cell in cells)


def trials_failing(failing: dict, method: str, variant: str, trials: Iterable) -> int:
    """How many of ``trials`` of ``method`` fail on ``variant``, from :attr:`BenchResult.failing` or its
    JSON (string keys): under ``--all-variants`` a row scores every trial, failing or not.

    Example:
        >>> trials_failing({"ensemble": {"0": ["cartpole:length=2.0"], "1": []}}, "ensemble", "cartpole:length=2.0",
        ...                ["0", "1"])
        1
    """
    by_trial = {str(trial): specs for trial, specs in failing.get(method, {}).items()}
    return sum(variant in by_trial.get(str(trial), ()) for trial in trials)


def trials_said(failing: dict, method: str, variant: str, trials: Iterable, all_variants: bool) -> str:
    """A row's trials as the tables say them: the failing trials it averages ("4"); where every trial
    was scored (``--all-variants``), their number and how many of them fail.

    Example:
        >>> failing = {"ensemble": {"0": ["cartpole:length=2.0"], "1": []}}
        >>> trials_said(failing, "ensemble", "cartpole:length=2.0", ["0", "1"], all_variants=True)
        '2 scored, 1 fails'
        >>> trials_said(failing, "ensemble", "cartpole:length=2.0", ["0"], all_variants=False)
        '1'
    """
    trials = list(trials)
    if not all_variants:
        return str(len(trials))
    return f"{len(trials)} scored, {fail_words(trials_failing(failing, method, variant, trials))}"


def fail_words(failed: int) -> str:
    """``"none fail"``, ``"1 fails"``, ``"3 fail"``."""
    return f"{failed or 'none'} fail{'s' if failed == 1 else ''}"


def unsolved_trials(id_returns: dict, task: str) -> list[tuple[str, int, float]]:
    """The trials whose model does not solve ``task`` (ID return below :data:`SOLVED_RETURN`), as
    ``(method, trial, ID return)``: their failing variants and AUROCs come from an agent that fails
    in its own world too. ``id_returns`` is :attr:`BenchResult.id_returns` or its JSON (string keys).

    Example:
        >>> unsolved_trials({"dropconnect": {"0": 500.0, "1": 297.45, "2": None}}, "cartpole")
        [('dropconnect', 1, 297.45)]
    """
    bar = SOLVED_RETURN.get(task)
    if bar is None:
        return []
    return [(method, int(trial), value) for method, trials in id_returns.items() for trial, value in trials.items()
            if value is not None and value < bar]


def _without_task(variant: str, task: str) -> str:
    """A variant's name in a table whose title names ``task``: without the task (``length=2.0``),
    the task's own env as itself (``cartpole``)."""
    return variant.removeprefix(f"{task}:")


def _add_columns(table: Table, columns: Sequence[str]) -> None:
    """The columns of a bench table: names on the left, the variant folded rather than cut in a
    narrow terminal, every other cell kept whole."""
    for column in columns:
        variant = column == "variant"
        table.add_column(column, justify="left" if column in ("method", "detector", "variant") else "right",
                         overflow="fold" if variant else "ellipsis", no_wrap=not variant, ratio=1 if variant else None)


def print_paper_report(config: BenchConfig, result: BenchResult, console: Console) -> None:
    """The paper's protocol: our AUROC per failing variant beside the paper's, the best per method,
    per detector where there are several, and what the alarm rule did."""
    several = len(config.detectors) > 1
    with_paper = any(row.paper for row in result.rows)  # (not for your own policy's method: the paper has none)
    which = "variant, every trial scored (--all-variants)" if config.all_variants else "failing variant"
    table = Table(title=f"{config.task}: per-step AUROC per {which}, ours (mean ± std over trials)"
                        + (" beside the paper's" if with_paper else ""))
    counts = {(r.method, r.variant): episodes_failing(result.detection, r.method, r.variant, r.aurocs) for r in result.rows}
    counted = any(count is not None for count in counts.values())
    columns = ("method", *(("detector",) if several else ()), "variant", "trials",
               *(("episodes failed",) if counted else ()), "ours", *(("paper", "difference") if with_paper else ()))
    _add_columns(table, columns)
    for row in sorted(result.rows, key=lambda r: (r.method, r.variant, config.detectors.index(r.detector))):
        paper = f"{np.mean(row.paper):.3f} ± {np.std(row.paper):.3f}" if row.paper else ""
        difference = f"{row.mean - np.mean(row.paper):+.3f}" if row.paper else ""
        count = counts[(row.method, row.variant)]
        table.add_row(row.method, *((row.detector,) if several else ()), _without_task(row.variant, config.task),
                      trials_said(result.failing, row.method, row.variant, row.aurocs, config.all_variants),
                      *(("" if count is None else f"{count[0]} of {count[1]}",) if counted else ()),
                      f"{row.mean:.3f} ± {row.std:.3f}", *((paper, difference) if with_paper else ()))
    console.print(table)
    # the paper's main tables rank the spread; a bench without it (your own policy, which gives no
    # samples: the dynamics detector) ranks its first detector's, and says so
    ranked = "spread" if "spread" in config.detectors else config.detectors[0]
    bests = best_per_method(result, config.task, detector=ranked)
    if bests:
        which = " (the paper's main tables)" if ranked == "spread" else \
            f", {ranked} detector (the paper's main tables rank the spread)"
        best = Table(title=f"{config.task}: best single-trial AUROC per method{which}")
        _add_columns(best, ("method", "variant", "ours", *(("paper", "difference") if with_paper else ())))
        for method, variant, ours, paper in bests:
            beside = ("", "") if paper is None else (f"{paper:.3f}", f"{ours - paper:+.3f}")
            best.add_row(method, _without_task(variant, config.task), f"{ours:.3f}", *(beside if with_paper else ()))
        console.print(best)
    if several:
        summary = Table(title=f"{config.task}: per-step AUROC per detector over the "
                              f"{'' if config.all_variants else 'failing '}variants (mean over "
                              "variants and trials)")
        for column in ("method", "detector", "mean", "min", "variants"):
            summary.add_column(column, justify="left" if column in ("method", "detector") else "right")
        for method in config.methods:
            for detector in config.detectors:
                means = [r.mean for r in result.rows if r.method == method and r.detector == detector]
                if means:
                    summary.add_row(method, detector, f"{np.mean(means):.3f}", f"{np.min(means):.3f}", str(len(means)))
        console.print(summary)
    rule = f"the mean score of the last {config.window} steps" if config.window > 1 else "each step's score"
    rule += f" from step {config.warmup} of each episode" if config.warmup else ""
    alarms = Table(title=f"{config.task}: the monitor's alarms ({config.alarm_detector} detector, {rule} against the "
                         "calibrated threshold), "
                         "mean over trials")
    _add_columns(alarms, ("method", "variant", "false alarms (ID)", "detected", "delay (steps)"))
    for method, variant, false_alarms, detected, delay in alarms_per_variant(result):
        alarms.add_row(method, _without_task(variant, config.task), "" if false_alarms is None else f"{false_alarms:.0%}",
                       "" if detected is None else f"{detected:.0%}", "" if delay is None else f"{delay:.0f}")
    console.print(alarms)
    unsolved = unsolved_trials(result.id_returns, config.task)
    if unsolved:
        console.print(f"Trials whose model does not solve the task (ID return below {SOLVED_RETURN[config.task]:g}; "
                      "their rows mix in an agent that fails in its own world): "
                      + ", ".join(f"{m} trial {t} ({value:g})" for m, t, value in unsolved))
    missing = paper_only_variants(result, config.task, config.methods, ran=[v.spec for v in config.variant_list()])
    if missing:
        console.print("Variants the paper reports where our agents did not fail (no AUROC of ours): "
                      + ", ".join(f"{m} {label} ({best:.3f})" for m, label, best in missing))
    print_unfailed(config, result, console)


def _early_words(row) -> str:
    """How many of a pooled row's episodes alarmed before their onset, and from how many ID starts
    where fewer: the variants play the same seeds, so one start's false alarm is in every variant.

    Example:
        >>> from oodmon.replay.metrics import monitor_row
        >>> _early_words(monitor_row("pendulum", "dropout", "all shifted", 160, 16, 110, 110, [1] * 120,
        ...                          early_starts=["500004@51"] * 16))
        '16 before it, from 1 ID start the variants share: the same seeds before the onset'
        >>> _early_words(monitor_row("cartpole", "ensemble", "all shifted", 20, 2, 0, 0, [1] * 18,
        ...                          early_starts=["7@3", "9@12"]))
        '2 before it'
    """
    from oodmon.replay.report import shared_starts_words

    if (words := shared_starts_words(row)) is None:
        return f"{row.early} before it"
    return f"{row.early} before it, from {words} the variants share: the same seeds before the onset"


def print_monitor_report(config: BenchConfig, result: BenchResult, console: Console) -> None:
    """The monitor's benchmark: the alarm's figures per variant, and each method's summary against the goals."""
    from oodmon.replay import monitor_summary, monitor_table
    from oodmon.replay.failures import failure_definition

    low, high = config.onset_range()
    console.print(monitor_table(result.alarms, title=(
        f"{config.task}: the monitor's benchmark ({config.alarm_detector} detector; shifted episodes shift at a random "
        f"step in [{low}, {high}); far {config.far:g}"
        + ("" if config.confidence is None else f" with confidence {config.confidence:g}")
        + (f"; no alarm in an episode's first {config.warmup} steps" if config.warmup else "") + ")"),
        width=console.width))
    for row in monitor_summary(result.alarms):
        ids = [m for m in result.alarms if m.is_id and m.method == row.method]
        far = (f"false alarms {ids[0].false_alarms}/{ids[0].episodes} ID episodes (95% interval {ids[0].far_low:.1%}-"
               f"{ids[0].far_high:.1%}, target {config.far:g})" if ids else "")
        if ids and ids[0].failed:  # the policy fails in its own world too: a shifted episode's failure is not the shift's alone
            far += (f"; {ids[0].failed}/{ids[0].episodes} ID episodes failed too (the env ended them): a shifted "
                    "episode's failure is not the shift's doing alone")
        why = "a lost point is part of an ID game" if config.task in TASKS else "an env oodmon has no variants of"
        before = (f"no failure told for {config.task} ({why})" if row.failed is None
                  else f"{row.before_failure}/{row.failed} failing episodes alarmed before the failure"
                  + ("" if row.lead_median is None else f" (lead median {row.lead_median:.3g} steps)") if row.failed
                  else "no episode failed after its onset")
        delays = ("no alarm after an onset" if row.delay_median is None
                  else f"delay median {row.delay_median:.3g} p90 {row.delay_p90:.3g} steps")
        never = f"; {row.never_shifted} more ended before their onset (never shifted)" if row.never_shifted else ""
        console.print(f"{row.method}: {far}; {row.alarmed}/{row.shifted_episodes} shifted episodes alarmed after the onset "
                      f"({_early_words(row)}){never}; {before}; {delays}")
    print_unfailed(config, result, console)
    if config.users_own:  # (your own env is benched with your own policy only)
        print_unfelt(config, result, console)
    print(failure_definition([config.task], config.failure), file=sys.stderr)


def print_unfelt(config: BenchConfig, result: BenchResult, console: Console, *, agent=None, steps: int = 500) -> None:
    """For each shift of your own env, and each CartPole or Pendulum variant, that no episode alarmed
    on: whether the env felt it at all where your policy acts (:func:`~oodmon.envs.probe.probe_shift`
    with ``agent``'s actions, by default the bench's own policy, from the first onset drawn), said when
    nothing it returned differed: an attribute the env reads only when made or reset, or in states your
    policy never reaches, not the detectors, is then why no alarm came. A variant's physics moves some
    reading a little wherever it acts: how much, for the reading's range in the ID episode, is said
    (gravity hardly acts on a pendulum held upright)."""
    import shlex

    from oodmon.bench.cache import own_policy_agent
    from oodmon.envs.grid import Variant
    from oodmon.envs.probe import probe_shift
    from oodmon.envs.shift import parse_any_variant
    from oodmon.errors import OodmonError

    first, high = config.onset_range()
    unalarmed = []
    for row in result.alarms:
        if row.is_id or row.alarmed or not row.shifted_episodes:
            continue
        try:
            unalarmed.append((row, parse_any_variant(row.variant)))
        except OodmonError:  # another env than the policy's (OtherEnv): no shift of it to probe
            continue
    unalarmed = [(row, shift) for row, shift in unalarmed
                 if not (isinstance(shift, Variant) and shift.task == "pong")]  # (Pong's frames: nothing to probe)
    if unalarmed and agent is None:
        agent = own_policy_agent(config)
    for row, shift in unalarmed:
        # a shift of your env's attributes from step 0 resets the env shifted (ShiftAttributes), from
        # a later step after its reset: probed as most episodes shifted, where not all onsets are 0
        low = first if isinstance(shift, Variant) or high <= first + 1 else max(first, 1)
        probe = probe_shift(shift, onset=low, steps=steps, policy=agent.act, wrap=agent.wrap)
        moved = probe.largest_share() if probe.changed and isinstance(shift, Variant) else None
        if not probe.changed and not probe.reached_onset:
            console.print(f"{row.variant}: no episode alarmed; your policy's episode in the env ends after {probe.steps} "
                          f"steps, before step {low}, the first onset, so whether the env feels the shift was not seen "
                          "(earlier --onsets shift the episodes while your policy still runs them)",
                          markup=False)
        elif not probe.changed:
            console.print(f"{row.variant}: no episode alarmed, and nothing the env returned differed from its own over "
                          f"{probe.steps} steps of your policy's actions, shifted from step {low}: does the env read it "
                          "only at a reset (a shift from onset 0 resets the env shifted: --onsets 0,1), or where your "
                          "policy never goes (a bound it keeps well within)?",
                          markup=False)
        elif moved is not None:
            console.print(f"{row.variant}: no episode alarmed; where your policy goes, over {probe.steps} steps shifted "
                          f"from step {low}, it moved reading {moved[0]} by at most {moved[1]:.2%} of that reading's "
                          f"range in the ID episode, the most of any reading (`oodmon envs show {shlex.quote(row.variant)} "
                          f"--onset {low}` with your policy's --sb3 or --policy pictures it)", markup=False)
