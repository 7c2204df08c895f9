"""How much of a five-trial row's std is the evaluation episodes' noise, not the trainings'?

Run (one thread; minutes per row on Pendulum, the bench's cached trial models):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/episode_noise.py results/bench/pendulum-pre_squash_std.json \\
        --rows ensemble:pendulum:l=0.1,dropconnect:pendulum:g=50.0 [--id-episodes 40] [--episodes 20]
    .venv/bin/python scripts/episode_noise.py --table

The bench scores each (method, trial) on 10 ID episodes and 5 of each failing variant (`--id-episodes`,
`--episodes`). This plays each trial of a row of a ``bench --results`` file again, as the bench's cells
play it (the same trial models, from ``--models``; the same episode seeds; the agent's MC samples seeded
as the cell's), but with more episodes: the first 10 and 5 are then the bench's own (their AUROC is
checked against the file's), and the rest tell

- the AUROC of each trial over all of them, and so the row's mean ± std over trials with less
  episode noise;
- the std of one trial's AUROC over the bench's number of episodes (``noise``: 400 draws of 10 of
  the ID and 5 of the shifted episodes, without replacement; the table's is the mean over the
  trials): how far another set of episodes would move each trial's figure, and so the row's std.

One JSON line per row goes to ``results/sweeps/episode_noise.jsonl``; a row already there is not run
again. ``--table`` prints them beside the paper's std.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from oodmon import seeds
from oodmon.bench.cache import _bench_agent
from oodmon.bench.config import PAPER_METHOD, paper_label
from oodmon.paper import paper_auc_per_trial
from oodmon.threads import limit_threads
from sweep_full_depth import append_row, bench_trial, episode_scores, parse_or_print_table, read_rows, step_auroc

OUT = Path("results/sweeps/episode_noise.jsonl")
DRAWS = 400


def cell_scores(model: Path, task: str, spec: str, episodes: int, seed: int, config: dict) -> list[np.ndarray]:
    """Per episode, the per-step scores of the model playing ``spec``, as a bench cell with this seed
    and the bench's ``config`` plays it (the agent's MC samples seeded by the cell's seed, as many as
    the bench's; its score and sensor noise; episodes ``seed``, ``seed`` + 1, ...)."""
    agent = _bench_agent(str(model), task, seed, config.get("samples"))
    return episode_scores(agent, spec, episodes, seed, config["score"], config.get("obs_noise", 0.0))[0]


def auroc(ids: list[np.ndarray], shifted: list[np.ndarray]) -> float:
    return step_auroc(np.concatenate(ids), np.concatenate(shifted))


def noise(ids: list[np.ndarray], shifted: list[np.ndarray], n_id: int, n_shifted: int,
          rng: np.random.Generator) -> float:
    """The std of the AUROC of ``n_id`` ID and ``n_shifted`` shifted episodes (the bench's numbers),
    drawn without replacement from these.

    Example (episodes that separate perfectly give the same AUROC in every draw):
        >>> ids, shifted = [np.zeros(5)] * 4, [np.ones(5)] * 4
        >>> noise(ids, shifted, 2, 2, np.random.default_rng(0))
        0.0
    """
    draws = [auroc([ids[i] for i in rng.choice(len(ids), n_id, replace=False)],
                   [shifted[i] for i in rng.choice(len(shifted), n_shifted, replace=False)]) for _ in range(DRAWS)]
    return float(np.std(draws))


def measure(results: Path, method: str, spec: str, models: Path, id_episodes: int, episodes: int) -> dict:
    """The row of ``results`` for ``method`` and ``spec``, each trial played again with ``id_episodes``
    and ``episodes``: its AUROC over the bench's first episodes (checked), over all, and the noise."""
    data = json.loads(results.read_text())
    config = data["config"]
    task, score = config["task"], config["score"]
    n_id, n_shifted = config["id_episodes"], config["episodes"]
    if id_episodes < 2 * n_id or episodes < 2 * n_shifted:
        raise SystemExit(f"--id-episodes and --episodes must be at least twice the bench's ({n_id}, {n_shifted})")
    row = next((r for r in data["rows"] if r["method"] == method and r["variant"] == spec and r["detector"] == "spread"),
               None)
    if row is None:
        raise SystemExit(f"{results} has no spread row for {method} {spec}")
    per_trial = {}
    for trial, bench_auroc in sorted(row["aurocs"].items(), key=lambda kv: int(kv[0])):
        model = bench_trial(task, method, int(trial), models)
        ids = cell_scores(model, task, task, id_episodes, seeds.BENCH_ID, config)
        shifted = cell_scores(model, task, spec, episodes, seeds.BENCH_SHIFTED, config)
        first = auroc(ids[:n_id], shifted[:n_shifted])
        if abs(first - bench_auroc) > 1e-9:
            raise SystemExit(f"trial {trial}: the first {n_id} + {n_shifted} episodes give {first:.6f}, the file "
                             f"{bench_auroc:.6f}: not the bench's models or episodes ({model})")
        per_trial[trial] = {"bench": round(first, 4), "all": round(auroc(ids, shifted), 4),
                            "noise": round(noise(ids, shifted, n_id, n_shifted, np.random.default_rng(int(trial))), 4)}
        print(f"{method} {spec} trial {trial}: {per_trial[trial]}", flush=True)
    label = paper_label(task, method, spec)
    paper = paper_auc_per_trial()[task][PAPER_METHOD[method]][label] if label else None
    return {"results": str(results), "score": score, "method": method, "variant": spec, "bench_episodes": [n_id, n_shifted],
            "id_episodes": id_episodes, "episodes": episodes, "trials": per_trial, "paper": paper}


def table() -> str:
    lines = ["| score | method | variant | trials | the bench: mean ± std (episodes ID + shifted) | "
             "more episodes: mean ± std | one trial's episode noise (std) | paper: mean ± std |",
             "|---|---|---|---:|---|---|---:|---|"]
    for r in read_rows(OUT):
        trials = r["trials"].values()
        bench = [t["bench"] for t in trials]
        more = [t["all"] for t in trials]
        paper = "" if r["paper"] is None else f"{np.mean(r['paper']):.3f} ± {np.std(r['paper']):.3f}"
        n_id, n_shifted = r["bench_episodes"]
        lines.append(f"| `{r['score']}` | {r['method']} | {r['variant'].split(':')[1]} | {len(bench)} | "
                     f"{np.mean(bench):.3f} ± {np.std(bench):.3f} ({n_id} + {n_shifted}) | {np.mean(more):.3f} ± "
                     f"{np.std(more):.3f} ({r['id_episodes']} + {r['episodes']}) | "
                     f"{np.mean([t['noise'] for t in trials]):.3f} | {paper} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", nargs="?", type=Path, help="a bench --results file (results/bench/*.json)")
    parser.add_argument("--rows", help="comma-separated method:variant, e.g. ensemble:pendulum:l=0.1")
    parser.add_argument("--models", type=Path, default=Path("runs/bench5/models"),
                        help="the bench's trial models (default runs/bench5/models)")
    parser.add_argument("--id-episodes", type=int, default=40)
    parser.add_argument("--episodes", type=int, default=20)
    args = parse_or_print_table(parser, table)
    if args is None:
        return
    if args.results is None or not args.rows:
        parser.error("give a results file and --rows (or --table)")
    done = {(r["results"], r["method"], r["variant"]) for r in read_rows(OUT)}
    for item in args.rows.split(","):
        method, spec = item.split(":", 1)
        if (str(args.results), method, spec) not in done:
            append_row(OUT, measure(args.results, method, spec, args.models, args.id_episodes, args.episodes))


if __name__ == "__main__":
    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    main()
