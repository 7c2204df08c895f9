"""Does the combined detector see more when it also ranks a member's mean since the episode began?

Run (a few minutes per agent; one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/combined_long_mean.py --task cartpole --method dropconnect
    .venv/bin/python scripts/combined_long_mean.py --table        # docs/detectors.md's table

For a shipped agent and its shipped spread, dynamics and features detectors, the combined
detector is rebuilt in several forms (``CombinedDetector(long_members=..., horizon=...)``), each
given its ID reference from the same 10 held-out ID episodes (the seeds of the last third of
``fit_detectors``' 30: ``DETECTOR_FIT + 20`` on), and scored on the bench's episodes: 10 ID
(``BENCH_ID`` on) against 5 of each variant where the agent fails (``BENCH_SHIFTED`` on, shifted
from step 0; the failing variants of ``results/detectors/<task>.json``). The agent's MC sampling
is seeded with ``CALIBRATION``, as the bench's. Per form: the per-step AUROC per variant. One
JSON line per (task, method, agent weights) goes to ``results/sweeps/combined_long_mean.jsonl``;
a line already there is not run again. Every form ranks ``features`` on its raw score, as the
combined detector did when the rows were made; "(shipped)" names the long mean it ships with,
which since then also ranks ``features`` by its logarithm (``LOG_MEMBERS``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from oodmon import seeds
from oodmon.agents import load
from oodmon.envs import parse_variant
from oodmon.monitor.detectors import DetectorSet
from oodmon.monitor.detectors.base import StepContext
from oodmon.monitor.detectors.combined import CombinedDetector
from oodmon.monitor.detectors.fitting import collect, trajectory_scores
from oodmon.threads import limit_threads
from sweep_full_depth import append_row, parse_or_print_table, read_rows

OUT = Path("results/sweeps/combined_long_mean.jsonl")
RESULTS = Path("results/detectors")

#: The forms compared: name -> (long members, horizon); "members" stands for every member.
FORMS = {"members only (before)": ([], 500), "+ dynamics mean, 500 steps (shipped)": (["dynamics"], 500),
         "+ dynamics mean, 100 steps": (["dynamics"], 100), "+ every member's mean, 500 steps": ("members", 500)}


def member_scores(agent, detectors: DetectorSet, spec: str, episodes: int, seed: int) -> list[dict[str, np.ndarray]]:
    """Per episode of ``spec`` (seeds ``seed`` on): every member's per-step scores, as the monitor gives them."""
    env = parse_variant(spec).make()
    try:
        trajectories = collect(agent, env, episodes, seed=seed)
    finally:
        env.close()
    return [trajectory_scores(detectors, t, agent.estimator) for t in trajectories]


def combined_scores(combined: CombinedDetector, episodes: list[dict[str, np.ndarray]]) -> np.ndarray:
    out = []
    for scores in episodes:
        combined.reset()
        for step in range(len(scores[combined.members[0]])):
            out.append(combined.score(StepContext(np.zeros(1), 0, scores={m: float(scores[m][step])
                                                                           for m in combined.members})))
    return np.asarray(out)


def measure(task: str, method: str) -> dict:
    agent = load(task, method, seed=seeds.CALIBRATION)
    shipped = DetectorSet.load(Path(agent.path) / "detectors")
    members = [name for name in shipped.names if name != "combined"]
    detectors = shipped.subset(members)
    failing = json.loads((RESULTS / f"{task}.json").read_text())["failing"][method]["0"]
    held_out = member_scores(agent, detectors, task, 10, seeds.DETECTOR_FIT + 20)
    id_scores = member_scores(agent, detectors, task, 10, seeds.BENCH_ID)
    shifted = {spec: member_scores(agent, detectors, spec, 5, seeds.BENCH_SHIFTED) for spec in failing}
    auroc: dict[str, dict[str, float]] = {}
    for form, (long_members, horizon) in FORMS.items():
        combined = CombinedDetector(members, long_members=members if long_members == "members" else long_members,
                                    horizon=horizon, log_members=[])  # features raw, as when the rows were made
        combined.fit_reference({m: [episode[m] for episode in held_out] for m in members})
        id_combined = combined_scores(combined, id_scores)
        auroc[form] = {}
        for spec, episodes in shifted.items():
            scores = combined_scores(combined, episodes)
            labels = np.r_[np.zeros(len(id_combined)), np.ones(len(scores))]
            auroc[form][spec] = float(roc_auc_score(labels, np.r_[id_combined, scores]))
        print(f"{form}: mean {np.mean(list(auroc[form].values())):.3f}, lowest {min(auroc[form].values()):.3f}", flush=True)
    return {"task": task, "method": method, "safetensors_sha256": agent.metadata["safetensors_sha256"],
            "failing": failing, "auroc": auroc}


def table() -> str:
    """Per agent and form: the mean and lowest per-step AUROC over its failing variants, and where it is lowest."""
    lines = ["| agent | combined detector | variants | mean | lowest | at |", "|---|---|---:|---:|---:|---|"]
    for row in read_rows(OUT):
        for form, per_variant in row["auroc"].items():
            low, where = min((v, k) for k, v in per_variant.items())
            lines.append(f"| {row['task']}-{row['method']} | {form} | {len(per_variant)} | "
                         f"{np.mean(list(per_variant.values())):.3f} | {low:.3f} | {where.split(':', 1)[1]} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", choices=["cartpole", "pendulum"])
    parser.add_argument("--method", choices=["dropout", "dropconnect", "ensemble"])
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    if not args.task or not args.method:
        parser.error("give --task and --method (or --table)")
    weights = load(args.task, args.method).metadata["safetensors_sha256"]
    if any(r["task"] == args.task and r["method"] == args.method and r["safetensors_sha256"] == weights
           for r in read_rows(OUT)):
        print(f"{args.task}-{args.method}: measured already ({OUT})")
        return
    append_row(OUT, measure(args.task, args.method))


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
