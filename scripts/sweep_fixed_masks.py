"""Fixed masks on MC agents of any recipe: the spread of sampled masks, of fixed ones, and the
fixed sub-networks read whitened (``scaled_spread``), per variant the paper reports for the method.

Run (seconds to a minute per agent; one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_fixed_masks.py --label LABEL MODEL_DIR [MODEL_DIR ...]
    .venv/bin/python scripts/sweep_fixed_masks.py --table
    .venv/bin/python scripts/sweep_fixed_masks.py --survival cartpole:masscart=9.0 [--plot PATH.png]
    .venv/bin/python scripts/sweep_fixed_masks.py --draws cartpole:masscart=9.0,cartpole:length=2.0 [--pool LABEL LABEL ...]

Each agent is measured as the sweeps measure (``scripts/sweep_full_depth.py``): 10 ID episodes
(seeds 200000+) against 5 of each variant (seeds 400000+), every step, whether or not the agent
fails, MC seed 0 (so sampled and fixed masks play the same episodes: the decision is sampled
either way). The score is ``margin_std`` for DQN agents and ``pre_squash_std`` for DDPG actors;
``scaled_spread`` is fitted on the agent with fixed masks by ``fit_agent_detectors`` (90 ID
episodes of the detectors' own seeds). One JSON line per (label, model folder) goes to
``results/sweeps/fixed_masks.jsonl``; one already there is not run again. ``--table`` prints mean ±
std over each label's agents per variant.

``--masks fixed-decisions``: the fixed sub-networks decide too (``load(..., masks="fixed-decisions")``:
another policy, so other episodes); the row holds the two measures of :data:`DECIDING` instead,
and ``"masks": "fixed-decisions"``.

``--survival VARIANT``: every agent of the rows with fixed masks that was measured on VARIANT, its
mean episode length there beside its whitened AUROC (``fixed scaled_spread``), shortest first, and
the rank correlation of the two over the agents: does an agent read lower where it holds out longer
under the shift? Runs nothing. With ``--plot PATH`` it also draws them (one colour per label, the
paper's mean ± std as a band, the bench's failure line as a line).

``--draws VARIANT[,VARIANT...]``: how often five trainings of one recipe would meet the paper's goals
on each VARIANT (mean AUROC >= the paper's, std <= the paper's) and on all of them at once, judged
from every recipe (label) with six or more agents measured there: over every set of five of its
agents, the share whose agents that fail (the bench's rule, ``evaluation.failure_line``, on the mean
episode length, which is CartPole's return: its only task here) read a mean and a std (numpy's, as
the bench's tables) that meet each goal. A set in which no agent fails meets neither. ``--pool``
counts the rows of the labels it names as one recipe (the zoo agent's and bench trials' rows beside
more seeds of the same recipe measured later). The share is an estimate from that many seeds and
these episodes (10 ID against 5 shifted, not the bench's), not a probability known to be right.
Runs nothing.
"""

from __future__ import annotations

import argparse
from itertools import combinations
from pathlib import Path

import numpy as np

from oodmon.agents import load_agent
from oodmon.agents.evaluation import failure_line
from oodmon.envs import parse_variant
from oodmon.monitor.detectors import DetectorSet, SpreadDetector, collect, fit_agent_detectors, trajectory_scores
from oodmon.threads import limit_threads
from sweep_full_depth import MC_SEED, VARIANTS, append_row, read_rows, step_auroc  # scripts/

OUT = Path("results/sweeps/fixed_masks.jsonl")
ID_SEED, SHIFTED_SEED = 200_000, 400_000  # the sweeps' episodes
ID_EPISODES, SHIFTED_EPISODES = 10, 5
MEASURES = ("sampled spread", "fixed spread", "fixed scaled_spread")
DECIDING = ("fixed-decisions spread", "fixed-decisions scaled_spread")


def measure(folder: Path, masks: str = "fixed") -> dict:
    """The agent's per-variant AUROC of each of :data:`MEASURES` (``masks="fixed-decisions"``:
    :data:`DECIDING`), and its mean episode length per variant (CartPole's return; the same with
    sampled and ``fixed`` masks, which decide alike)."""
    fixed = load_agent(folder, seed=MC_SEED, masks=masks)
    score = "margin_std" if fixed.estimator.kind == "q_values" else "pre_squash_std"
    fitted = fit_agent_detectors(fixed, detectors=("scaled_spread",), score=score)
    if masks == "fixed":
        plain = DetectorSet([SpreadDetector(score)])
        measures = MEASURES
        runs = ((load_agent(folder, seed=MC_SEED), plain, {"spread": "sampled spread"}),
                (fixed, fitted, {"spread": "fixed spread", "scaled_spread": "fixed scaled_spread"}))
    else:
        measures = DECIDING
        runs = ((fixed, fitted, {"spread": "fixed-decisions spread", "scaled_spread": "fixed-decisions scaled_spread"}),)

    def scores(spec: str, episodes: int, seed: int) -> tuple[dict[str, np.ndarray], float]:
        steps: dict[str, list[np.ndarray]] = {name: [] for name in measures}
        lengths = []
        for agent, detectors, names in runs:
            for trajectory in collect(agent, parse_variant(spec).make(), episodes, seed=seed):
                for name, values in trajectory_scores(detectors, trajectory, agent.estimator).items():
                    steps[names[name]].append(values)
                lengths.append(len(trajectory))
        return {name: np.concatenate(values) for name, values in steps.items()}, float(np.mean(lengths))

    task, method = fixed.task, fixed.method
    id_scores, id_length = scores(task, ID_EPISODES, ID_SEED)
    auroc, lengths = {name: {} for name in measures}, {task: id_length}
    for spec in VARIANTS[(task, method)]:
        shifted, lengths[spec] = scores(spec, SHIFTED_EPISODES, SHIFTED_SEED)
        for name in measures:
            auroc[name][spec] = round(step_auroc(id_scores[name], shifted[name]), 3)
    return {"task": task, "method": method, "score": score, "mc_seed": MC_SEED, "auroc": auroc,
            "length_mean": {k: round(v, 1) for k, v in lengths.items()}} | ({} if masks == "fixed" else {"masks": masks})


def table(rows: list[dict]) -> str:
    """Per label (and task, should one label name agents of two) and measure, mean ± std over the
    label's agents per variant."""
    lines = ["| agents | measure | per variant: AUROC mean ± std (each agent) |", "|---|---|---|"]
    for label, task in dict.fromkeys((r["label"], r["task"]) for r in rows):
        mine = [r for r in rows if r["label"] == label and r["task"] == task]
        for name in mine[0]["auroc"]:
            cells = []
            for spec in mine[0]["auroc"][name]:
                values = [r["auroc"][name][spec] for r in mine]
                cells.append(f"{spec.split(':')[1]} {np.mean(values):.3f} ± {np.std(values):.3f} "
                             f"({' '.join(f'{v:.2f}' for v in values)})")
            lines.append(f"| {label} ({len(mine)}) | {name} | {'; '.join(cells)} |")
    return "\n".join(lines)


def _measured(r: dict, specs: list[str], measure: str) -> bool:
    """Whether row ``r`` is an agent with fixed masks (not deciding by them) measured on every one of ``specs``."""
    return "masks" not in r and all(s in r["auroc"].get(measure, {}) and s in r.get("length_mean", {}) for s in specs)


def _fails(r: dict, spec: str) -> bool:
    """Whether the agent of CartPole row ``r`` fails on ``spec`` by the bench's rule (its return is its length)."""
    return r["length_mean"][spec] < failure_line(r["task"], r["length_mean"][r["task"]])


def _paper_goal(task: str, method: str, spec: str) -> tuple[float, float] | None:
    """The paper's mean and std (numpy's, as the bench's tables) over its trials on ``spec``, if it reports it."""
    from oodmon.bench.config import PAPER_METHOD, paper_label
    from oodmon.paper import paper_auc_per_trial

    label = paper_label(task, method, spec)
    if label is None:
        return None
    trials = paper_auc_per_trial()[task][PAPER_METHOD[method]][label]
    return float(np.mean(trials)), float(np.std(trials))


def survival(rows: list[dict], spec: str, measure: str = "fixed scaled_spread") -> str:
    """The agents of the fixed-mask ``rows`` measured on ``spec``: each one's mean episode length
    there beside its ``measure`` AUROC, shortest first, and Spearman's rank correlation of the two."""
    from scipy.stats import spearmanr

    points = sorted((r["length_mean"][spec], r["auroc"][measure][spec], r["label"], r["folder"]) for r in rows
                    if _measured(r, [spec], measure))
    if len(points) < 3:
        raise SystemExit(f"{len(points)} agents with fixed masks measured on {spec} in {OUT}; a correlation needs 3 or more")
    lines = [f"| mean length on {spec} | {measure} AUROC | agents | model folder |", "|---:|---:|---|---|"]
    lines += [f"| {length:.1f} | {auroc:.3f} | {label} | `{folder}` |" for length, auroc, label, folder in points]
    rho, p_value = spearmanr([p[0] for p in points], [p[1] for p in points])
    lines.append(f"\nSpearman's rank correlation of length and AUROC over {len(points)} agents: {rho:.3f} "
                 f"(p = {p_value:.2g})")
    return "\n".join(lines)


def survival_plot(rows: list[dict], spec: str, path: Path, measure: str = "fixed scaled_spread") -> Path:
    """The agents of :func:`survival` on ``spec``: mean episode length against ``measure`` AUROC,
    one colour per label; the paper's mean ± std there as a band where it reports the variant."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from oodmon.outputs import save_figure

    mine = [r for r in rows if _measured(r, [spec], measure)]
    if not mine:
        raise SystemExit(f"no agent with fixed masks measured on {spec} in {OUT}")
    fig, ax = plt.subplots(figsize=(10.5, 4.6))
    task, method = mine[0]["task"], mine[0]["method"]
    goal = _paper_goal(task, method, spec)
    if goal is not None:
        mean, std = goal
        ax.axhspan(mean - std, mean + std, color="grey", alpha=0.2, label=f"paper: {mean:.3f} ± {std:.3f}")
    if task == "cartpole":  # its return is its length
        ax.axvline(failure_line(task, float(np.median([r["length_mean"][task] for r in mine]))), color="grey",
                   linestyle=":", label="the bench's failure line (failing left of it)")
    for name in dict.fromkeys(r["label"] for r in mine):
        points = [(r["length_mean"][spec], r["auroc"][measure][spec]) for r in mine if r["label"] == name]
        ax.scatter(*zip(*points), s=28, label=f"{name} ({len(points)})")
    ax.set_xscale("log")
    ax.set_xticks([10, 20, 50, 100, 200, 500], ["10", "20", "50", "100", "200", "500"])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel(f"mean episode length on {spec} (log)")
    ax.set_ylabel(f"{measure} AUROC")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"{task} {method}: the agents that hold out read low")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)


def draws(rows: list[dict], specs: list[str], pool: list[str] | None = None, measure: str = "fixed scaled_spread",
          size: int = 5) -> str:
    """Per recipe with more than ``size`` agents measured on every one of ``specs`` (the labels of
    ``pool`` as one), per variant the share of its sets of ``size`` agents whose failing agents meet
    the paper's mean and std there; with several variants, the share of sets that meet both on all."""
    unknown = sorted(set(pool or ()) - {r["label"] for r in rows})
    if unknown:
        raise SystemExit(f"--pool names labels no row of {OUT} has: {', '.join(unknown)}")
    recipes: dict[str, list[dict]] = {}
    for r in rows:
        if _measured(r, specs, measure):
            recipes.setdefault(" + ".join(pool) if pool and r["label"] in pool else r["label"], []).append(r)
    recipes = {name: mine for name, mine in recipes.items() if len(mine) > size}
    if not recipes:
        raise SystemExit(f"no recipe has more than {size} agents measured on {', '.join(specs)} in {OUT}; "
                         f"--pool joins labels")
    methods = {r["method"] for mine in recipes.values() for r in mine}
    if len(methods) > 1:
        raise SystemExit(f"the recipes measured there are of several methods ({', '.join(sorted(methods))}); "
                         f"--pool or the variants should name one")
    task, method = next(iter(recipes.values()))[0]["task"], methods.pop()
    if task != "cartpole":
        raise SystemExit(f"--draws judges failing by episode length, which is the return on CartPole only, not {task}")
    goals = {spec: _paper_goal(task, method, spec) for spec in specs}
    for spec, goal in goals.items():
        if goal is None:
            raise SystemExit(f"the paper reports no {method} figure for {spec}")
    lines = [f"Paper ({method}): " + "; ".join(f"{s.split(':')[1]} {m:.3f} ± {d:.3f}" for s, (m, d) in goals.items())
             + f". Sets of {size} agents of each recipe:", "",
             "| recipe | variant | agents (failing) | sets | mean >= paper | std <= paper | both | AUROC of each failing agent |",
             "|---|---|---:|---:|---:|---:|---:|---|"]
    for name, mine in recipes.items():
        sets = list(combinations(range(len(mine)), size))
        every = np.ones(len(sets), bool)
        for spec, (goal_mean, goal_std) in goals.items():
            fails = [_fails(r, spec) for r in mine]
            aurocs = [r["auroc"][measure][spec] for r in mine]
            met = np.zeros((len(sets), 2), bool)
            for k, chosen in enumerate(sets):
                failing = [aurocs[i] for i in chosen if fails[i]]
                if failing:  # a set in which no agent fails has no figure: it meets neither
                    met[k] = np.mean(failing) >= goal_mean, np.std(failing) <= goal_std
            both = met.all(1)
            every &= both
            each = " ".join(f"{a:.2f}" for a, f in zip(aurocs, fails) if f)
            lines.append(f"| {name} | {spec.split(':')[1]} | {len(mine)} ({sum(fails)}) | {len(sets)} | "
                         f"{met[:, 0].mean():.0%} | {met[:, 1].mean():.0%} | {both.mean():.0%} | {each} |")
        if len(specs) > 1:
            lines.append(f"| {name} | all {len(specs)} | {len(mine)} | {len(sets)} | | | {every.mean():.0%} | |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="*", type=Path, help="model folders (model.json + model.safetensors)")
    parser.add_argument("--label", help="what the agents are (a recipe), the table's row name")
    parser.add_argument("--table", action="store_true", help="print the rows as a markdown table")
    parser.add_argument("--masks", choices=("fixed", "fixed-decisions"), default="fixed",
                        help="fixed-decisions: the fixed sub-networks decide too (their two measures only)")
    parser.add_argument("--survival", metavar="VARIANT",
                        help="print each agent's mean episode length on VARIANT beside its whitened AUROC there, run nothing")
    parser.add_argument("--plot", type=Path, metavar="PATH", help="with --survival: draw the agents to this PNG")
    parser.add_argument("--draws", metavar="VARIANTS",
                        help="print how often five agents of each recipe meet the paper's mean and std on these "
                             "comma-separated variants, run nothing")
    parser.add_argument("--pool", nargs="+", metavar="LABEL", help="with --draws: these labels' rows are one recipe")
    args = parser.parse_args()
    if args.plot and not args.survival:  # (a plot asked for and silently not drawn before)
        parser.error("--plot draws the agents of --survival VARIANT: give that too")
    if args.pool and not args.draws:
        parser.error("--pool joins recipes for --draws VARIANTS: give that too")
    rows = read_rows(OUT)
    if args.table:
        print(table(rows))
        return
    if args.survival:
        print(survival(rows, args.survival))
        if args.plot:
            print(f"plot: {survival_plot(rows, args.survival, args.plot)}")
        return
    if args.draws:
        print(draws(rows, args.draws.split(","), args.pool))
        return
    if not args.folders or not args.label:
        parser.error("give --label and model folders (or --table)")
    done = {(r["label"], r["folder"]) for r in rows}
    for folder in args.folders:
        if (args.label, str(folder)) not in done:
            append_row(OUT, {"label": args.label, "folder": str(folder), **measure(folder, args.masks)})


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
