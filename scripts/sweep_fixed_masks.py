"""Fixed masks on MC agents of any recipe: the spread of sampled masks, of fixed ones, and the
fixed sub-networks read whitened (``scaled_spread``), per variant the paper reports for the method.

Run (seconds to a minute per agent; one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sweep_fixed_masks.py --label LABEL MODEL_DIR [MODEL_DIR ...]
    .venv/bin/python scripts/sweep_fixed_masks.py --table
    .venv/bin/python scripts/sweep_fixed_masks.py --survival cartpole:masscart=9.0

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
under the shift? Runs nothing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from oodmon.agents import load_agent
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
    """Per label and measure, mean ± std over the label's agents per variant."""
    lines = ["| agents | measure | per variant: AUROC mean ± std (each agent) |", "|---|---|---|"]
    for label in dict.fromkeys(r["label"] for r in rows):
        mine = [r for r in rows if r["label"] == label]
        for name in mine[0]["auroc"]:
            cells = []
            for spec in mine[0]["auroc"][name]:
                values = [r["auroc"][name][spec] for r in mine]
                cells.append(f"{spec.split(':')[1]} {np.mean(values):.3f} ± {np.std(values):.3f} "
                             f"({' '.join(f'{v:.2f}' for v in values)})")
            lines.append(f"| {label} ({len(mine)}) | {name} | {'; '.join(cells)} |")
    return "\n".join(lines)


def survival(rows: list[dict], spec: str, measure: str = "fixed scaled_spread") -> str:
    """The agents of the fixed-mask ``rows`` measured on ``spec``: each one's mean episode length
    there beside its ``measure`` AUROC, shortest first, and Spearman's rank correlation of the two."""
    from scipy.stats import spearmanr

    points = sorted((r["length_mean"][spec], r["auroc"][measure][spec], r["label"], r["folder"]) for r in rows
                    if "masks" not in r and spec in r["auroc"].get(measure, {}) and spec in r.get("length_mean", {}))
    if len(points) < 3:
        raise SystemExit(f"{len(points)} agents with fixed masks measured on {spec} in {OUT}; a correlation needs 3 or more")
    lines = [f"| mean length on {spec} | {measure} AUROC | agents | model folder |", "|---:|---:|---|---|"]
    lines += [f"| {length:.1f} | {auroc:.3f} | {label} | `{folder}` |" for length, auroc, label, folder in points]
    rho, p_value = spearmanr([p[0] for p in points], [p[1] for p in points])
    lines.append(f"\nSpearman's rank correlation of length and AUROC over {len(points)} agents: {rho:.3f} "
                 f"(p = {p_value:.2g})")
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
    args = parser.parse_args()
    rows = read_rows(OUT)
    if args.table:
        print(table(rows))
        return
    if args.survival:
        print(survival(rows, args.survival))
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
