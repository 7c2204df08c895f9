"""docs/bench.md's five-trial tables beside the paper's, from the committed bench results in results/bench/.

Run: .venv/bin/python scripts/bench_table.py [results/bench/<file>.json ...] [--plots]   (default: every file there)
     .venv/bin/python scripts/bench_table.py --goals [<file>.json ...]   (docs/bench.md's table of the goals
                                              at a glance; with files, over those files instead)

``--plots`` also draws each file as results/bench/<file>.png: per method and variant of the paper,
our mean ± std over the trials that failed on the variant beside the paper's, with their number
beside a point where fewer than all did (a file of ``--all-variants``: over every trial, with how
many of them fail under each variant).

Each file is what `oodmon bench ... --results FILE` wrote (its command is inside, and in
results/bench/README.md). One row per variant the paper's appendix reports for a method: our
per-step AUROC, mean ± std over the trials where the agent failed on that variant (the bench scores
a trial on a variant only where it fails, unless ``--all-variants``: below), beside the paper's five
trials; "does not fail" where none of our trials failed on it. CartPole files that count them also
give how many of those trials' shifted episodes failed ("23 of 25 episodes fail"): the protocol
scores every step of the others as shifted too, though the agent coped. Then the best mean per task
against the paper's best mean, and per method how many of the paper's variants we meet (mean >= the
paper's, and std <= the paper's; a row over one failing trial has no std to compare: "one trial: no
std", neither met nor missed).
A file of ``oodmon bench --all-variants`` scores every trial on every variant it names, whether or not
the trial fails there, as the paper scored its five trials on the variants where its trained model
failed: its rows say how many trials they average and how many of them fail ("5 scored, 1 fails";
"none fail": the agent copes there).

``--goals``: one row per variant the paper reports, with the best of every committed file and
detector for it (both goals met first, then the mean alone, then the highest mean), and where it
comes from; docs/bench.md keeps it between ``<!-- bench_goals -->`` markers. Given files, the same
table over those files alone: e.g. ``results/sweeps/*-avx512-bench.json``, another draw of trials
1-4 (trained on another CPU kind), beside the committed one.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from oodmon.agents.evaluation import SOLVED_RETURN  # noqa: E402
from oodmon.bench.config import PAPER_METHOD, BenchConfig, paper_label  # noqa: E402
from oodmon.bench.report import (episodes_failing, fail_words, trials_failing, trials_said,  # noqa: E402
                                  unsolved_trials)
from oodmon.paper import paper_auc_per_trial  # noqa: E402

RESULTS = ROOT / "results" / "bench"


def _rows(data: dict, detector: str = "spread") -> dict[tuple[str, str | None], dict]:
    """A result's rows of ``detector`` by (method, the paper's label of the variant)."""
    task = data["config"]["task"]
    return {(r["method"], paper_label(task, r["method"], r["variant"])): r for r in data["rows"]
            if r["detector"] == detector}


def _detectors(config: dict) -> list[str]:
    """The detectors a result scored, ``spread`` first (a result before learned detectors: spread)."""
    named = config.get("detectors") or ["spread"]
    return ["spread", *(d for d in named if d != "spread")]


def table(path: Path) -> str:
    data = json.loads(path.read_text())
    config = data["config"]
    samples = f", {config['samples']} MC samples per decision" if config.get("samples") else ""
    samples += f", ensembles of {config['members']} members" if config.get("members") else ""
    samples += f", hidden widths {config['net_arch']}" if config.get("net_arch") else ""
    samples += {"fixed": ", fixed MC masks", "fixed-decisions": ", fixed MC masks that decide"}.get(config.get("masks"), "")
    defaults = (BenchConfig.id_episodes, BenchConfig.episodes)  # the paper protocol's episodes per trial
    if (config.get("id_episodes", defaults[0]), config.get("episodes", defaults[1])) != defaults:
        samples += f", {config['id_episodes']} ID episodes and {config['episodes']} per variant for each trial"
    lines = [f"`{data['command']}` ({config['trials']} trials, score `{config['score']}`{samples}):", ""]
    for index, detector in enumerate(_detectors(config)):
        if index:
            lines += ["", f"The `{detector}` detector on the same episodes (fitted per trial on ID episodes of its own):",
                      ""]
        lines += _detector_table(data, detector)
    if data.get("id_returns"):
        lines += ["", _id_return_line(data["id_returns"], config["task"])]
    return "\n".join(lines)


#: The std column of a row whose variant one trial alone failed on: its "std" of 0 is no spread over
#: trials, so the paper's std goal is neither met nor missed there.
ONE_TRIAL = "one trial: no std"


def _std_goal(row: dict, trials: list[float]) -> bool | None:
    """Whether ``row``'s std over the trials that failed is at most the paper's; ``None`` where one
    trial alone failed (:data:`ONE_TRIAL`)."""
    return None if len(row["aurocs"]) < 2 else bool(row["std"] <= np.std(trials))


def _said(goal: bool | None) -> str:
    return ONE_TRIAL if goal is None else "yes" if goal else "no"


def _detector_table(data: dict, detector: str) -> list[str]:
    """One detector's rows beside the paper's, and the best means and the variants met under it."""
    rows = _rows(data, detector)
    config = data["config"]
    paper = paper_auc_per_trial()[config["task"]]
    lines = ["| method | variant | ours: AUROC mean ± std (trials failing) | paper: mean ± std | AUPR / FPR@95 (ours) "
             "| mean >= paper | std <= paper |",
             "|---|---|---|---|---|---|---|"]
    met: dict[str, list[int]] = {}
    best_ours: tuple[float, str] = (-1.0, "")
    best_paper: tuple[float, str] = (-1.0, "")
    for method in config["methods"]:
        for label, trials in paper.get(PAPER_METHOD[method], {}).items():
            theirs = f"{np.mean(trials):.3f} ± {np.std(trials):.3f}"
            best_paper = max(best_paper, (float(np.mean(trials)), f"{method} {label}"))
            counts = met.setdefault(method, [0, 0, 0])
            counts[2] += 1
            row = rows.get((method, label))
            if row is None:
                lines.append(f"| {method} | {label} | does not fail (0/{config['trials']}) | {theirs} | | no | |")
                continue
            mean_ok, std_ok = row["mean"] >= np.mean(trials), _std_goal(row, trials)
            counts[0] += mean_ok
            counts[1] += bool(mean_ok and std_ok)
            best_ours = max(best_ours, (row["mean"], f"{method} {label}"))
            lines.append(f"| {method} | {label} | {row['mean']:.3f} ± {row['std']:.3f} ({_trials(data, row)}"
                         f"{_episodes_failing(data, row)}) | "
                         f"{theirs} | {row['aupr_mean']:.3f} / {row['fpr95_mean']:.3f} | "
                         f"{'yes' if mean_ok else 'no'} | {_said(std_ok)} |")
    lines += ["", f"Best mean AUROC: ours {best_ours[0]:.3f} ({best_ours[1]}), the paper's {best_paper[0]:.3f} "
                  f"({best_paper[1]}). Variants of the paper where our mean reaches the paper's (and our std is at most "
                  "the paper's): " + ", ".join(f"{m} {c[0]}/{c[2]} ({c[1]}/{c[2]})" for m, c in met.items()) + "."]
    return lines


class Candidate(NamedTuple):
    """One file's row (of one detector) for a variant the paper reports, as :func:`goals` weighs it:
    by ``rank`` (both goals met, then the mean's, then the mean)."""

    both: bool  # mean >= the paper's and std <= the paper's
    mean_ok: bool
    mean: float
    trials: str  # as the tables say them: "4", "5 scored, 1 fails"
    source: str  # "`file`, `detector`"
    std: float
    std_ok: bool | None  # None: one trial, no std

    @property
    def rank(self) -> tuple[bool, bool, float]:
        return self.both, self.mean_ok, self.mean


def goals(paths: list[Path]) -> str:
    """Per variant the paper reports, the best of ``paths``' rows (any file, any detector) beside the
    paper's: the one meeting both goals (mean >= the paper's, std <= the paper's) with the highest
    mean, else the one meeting the mean with the highest mean, else the highest mean; "does not
    fail" where no file has a row for it. Then the best mean per task against the paper's best.
    Files of agents the zoo does not ship (other hidden widths, ensembles of other sizes) are left out."""
    papers = paper_auc_per_trial()
    best: dict[tuple[str, str, str], Candidate | None] = {}
    for path in paths:
        data = json.loads(path.read_text())
        config = data["config"]
        if config.get("net_arch") or config.get("members"):
            continue
        task = config["task"]
        paper = papers[task]
        for detector in _detectors(config):
            rows = _rows(data, detector)
            for method in config["methods"]:
                for label, trials in paper.get(PAPER_METHOD[method], {}).items():
                    key = (task, method, label)
                    row = rows.get((method, label))
                    if row is None:
                        best.setdefault(key, None)
                        continue
                    mean_ok, std_ok = row["mean"] >= np.mean(trials), _std_goal(row, trials)
                    candidate = Candidate(bool(mean_ok and std_ok), bool(mean_ok), row["mean"], _trials(data, row),
                                          f"`{path.stem}`, `{detector}`", row["std"], std_ok)
                    if best.get(key) is None or candidate.rank > best[key].rank:
                        best[key] = candidate
    lines = ["| task | method | variant | paper: mean ± std | ours, the best: mean ± std (trials failing) | from "
             "(file, detector) | mean >= paper | std <= paper |", "|---|---|---|---|---|---|---|---|"]
    tops: dict[str, list[tuple[float, str]]] = {}
    order = [(task, method, label) for task, by_method in sorted(papers.items())
             for method in ("dropout", "dropconnect", "ensemble") for label in by_method.get(PAPER_METHOD[method], {})]
    for task, method, label in (key for key in order if key in best):
        found = best[(task, method, label)]
        trials = papers[task][PAPER_METHOD[method]][label]
        theirs = f"{np.mean(trials):.3f} ± {np.std(trials):.3f}"
        tops.setdefault(task, [(-1.0, ""), (-1.0, "")])
        tops[task][1] = max(tops[task][1], (float(np.mean(trials)), f"{method} {label}"))
        if found is None:
            lines.append(f"| {task} | {method} | {label} | {theirs} | does not fail (in any file) | | no | |")
            continue
        tops[task][0] = max(tops[task][0], (found.mean, f"{method} {label}, {found.source}"))
        lines.append(f"| {task} | {method} | {label} | {theirs} | {found.mean:.3f} ± {found.std:.3f} ({found.trials}) "
                     f"| {found.source} | {'yes' if found.mean_ok else 'no'} | "
                     f"{_said(found.std_ok) if found.mean_ok else 'no'} |")
    lines.append("")
    lines += [f"Best mean AUROC, {task}: "
              + (f"ours {ours[0]:.3f} ({ours[1]})" if ours[1] else "ours none (no variant failed)")
              + f", the paper's {theirs[0]:.3f} ({theirs[1]})." for task, (ours, theirs) in tops.items()]
    return "\n".join(lines)


def _trials(data: dict, row: dict) -> str:
    """A row's trials: the failing ones it averages ("4"), or in a file of ``--all-variants``, which scores
    every trial, how many it scored and how many of them fail ("5 scored, 1 fails")."""
    return trials_said(data.get("failing", {}), row["method"], row["variant"], row["aurocs"],
                       bool(data["config"].get("all_variants")))


def _episodes_failing(data: dict, row: dict) -> str:
    """"; F of N episodes fail" over the row's trials (``episodes_failing``); empty for a file
    written before the bench counted them, and for Pendulum and Pong."""
    count = episodes_failing(data["monitor"], row["method"], row["variant"], row["aurocs"])
    return "" if count is None else f"; {count[0]} of {count[1]} episodes fail"


def _id_return_line(id_returns: dict, task: str) -> str:
    """Each trial's ID return, and which trials do not solve the task (their rows mix in an agent
    that fails in its own world)."""
    unsolved = unsolved_trials(id_returns, task)
    parts = []
    for method, trials in id_returns.items():
        shown = ", ".join("-" if v is None else f"{v:g}" for v in trials.values())
        bad = [t for m, t, _ in unsolved if m == method]
        parts.append(f"{method} {shown}" + (f" (trial{'s' if len(bad) > 1 else ''} "
                                            f"{', '.join(map(str, bad))} below it)" if bad else ""))
    bar = "" if task not in SOLVED_RETURN else f"; the task counts as solved at >= {SOLVED_RETURN[task]:g}"
    return (f"ID return of trials 0-{len(next(iter(id_returns.values()))) - 1} (their training's 20 episodes{bar}): "
            + "; ".join(parts) + ".")


def plot(path: Path) -> Path:
    """Our AUROC (mean ± std over trials) beside the paper's, per method and variant of the paper."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from oodmon.outputs import save_figure

    data = json.loads(path.read_text())
    config = data["config"]
    task = config["task"]
    detectors = _detectors(config)
    rows_of = {detector: _rows(data, detector) for detector in detectors}
    paper = paper_auc_per_trial()[task]
    methods = [m for m in config["methods"] if paper.get(PAPER_METHOD[m])]
    every = bool(config.get("all_variants"))  # --all-variants: every trial scored, failing or not
    fig, axes = plt.subplots(1, len(methods), figsize=(4.2 * len(methods), 3.6), sharey=True, squeeze=False)
    for ax, method in zip(axes[0], methods):
        labels = list(paper[PAPER_METHOD[method]])
        x = np.arange(len(labels))
        theirs = [paper[PAPER_METHOD[method]][label] for label in labels]
        ax.errorbar(x - 0.12, [np.mean(t) for t in theirs], [np.std(t) for t in theirs], fmt="s", color="grey",
                    capsize=3, label="paper (5 trials)")
        for index, (detector, color) in enumerate(zip(detectors, ("tab:blue", "tab:orange", "tab:green"))):
            ours = [rows_of[detector].get((method, label)) for label in labels]
            shown = [i for i, r in enumerate(ours) if r is not None]
            name = "ours" if len(detectors) == 1 else f"ours, {detector}"
            which = f"all {config['trials']} trials" if every else f"the failing of {config['trials']} trials"
            ax.errorbar(x[shown] + 0.12 * (1 + index), [ours[i]["mean"] for i in shown], [ours[i]["std"] for i in shown],
                        fmt="o", color=color, capsize=3, label=f"{name} ({which})")
            for i in shown:
                if every and index == 0:  # every trial scored: under the variant, how many of them fail
                    failed = trials_failing(data["failing"], method, ours[i]["variant"], ours[i]["aurocs"])
                    ax.annotate(f"of {len(ours[i]['aurocs'])}: {fail_words(failed)}", (x[i], 0.04), ha="center",
                                fontsize=7)
                elif not every and len(ours[i]["aurocs"]) < config["trials"]:  # over fewer trials: how many failed
                    ax.annotate(f"n={len(ours[i]['aurocs'])}", (x[i] + 0.12 * (1 + index), ours[i]["mean"]),
                                textcoords="offset points", xytext=(5, -2), fontsize=7, color=color, va="top")
            if index == 0:
                for i, r in enumerate(ours):
                    if r is None:
                        ax.annotate("ours: does\nnot fail", (x[i], 0.22), ha="center", fontsize=7, color=color)
        ax.axhline(0.5, color="black", lw=0.6, ls=":")
        ax.set_xticks(x, [label.split(" ")[0] for label in labels], rotation=45, ha="right", fontsize=8)
        ax.set_title(f"{task} {method}", fontsize=10)
        ax.set_ylim(0, 1.02)
        ax.set_xlim(-0.6, len(labels) - 0.4)
    axes[0][0].set_ylabel(f"per-step AUROC ({'spread: ' if len(detectors) > 1 else ''}{config['score']})")
    axes[0][-1].legend(fontsize=7, loc="center right" if every else "lower right")  # (every: counts at the foot)
    return save_figure(fig, path.with_suffix(".png"))


def main(argv: list[str]) -> None:
    """The command line (the module's docstring); a file not there, or --plots beside --goals, exits with its message."""
    if {"-h", "--help"} & set(argv):
        print(__doc__)
        sys.exit(0)  # as argparse ends a --help
    arguments = [a for a in argv if a not in ("--plots", "--goals")]
    paths = [Path(p) for p in arguments] or sorted(RESULTS.glob("*.json"))
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        sys.exit(f"bench_table: no such results file: {', '.join(missing)} (see --help)")
    if "--goals" in argv:
        if "--plots" in argv:
            sys.exit("bench_table: --plots draws each file's table; --goals draws nothing (give one or the other)")
        print(goals(paths))
        return
    for path in paths:
        print(f"{path.stem}:\n\n{table(path)}\n")
        if "--plots" in argv:
            print(f"wrote {plot(path)}", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1:])
