"""docs/detectors.md's detector table, from the committed results in results/detectors/.

Run: .venv/bin/python scripts/detector_table.py [--long]

The default is docs/detectors.md's table: one row per agent, "mean / lowest" per detector, the best mean
in bold. ``--long`` gives one row per agent and detector, with the variant where it is lowest.

cartpole.json and pendulum.json (and their -noise0.01 twins, with --obs-noise 0.01) are `oodmon bench
--trials 1 --detectors spread,dynamics,features,combined` results (each holds its command; see
results/detectors/README.md); pong-<method>.json come from
scripts/measure_pong_features.py. Per agent and detector: the mean and the smallest per-step AUROC
over the variants scored (the agent's failing variants of the paper's grid; Pong: the noises and
the blur at severity 3-5), and the variant where it is smallest.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "results" / "detectors"


def rows() -> list[tuple[str, str, str, int, float, float, str]]:
    out = []
    for name in ("cartpole", "pendulum", "cartpole-noise0.01", "pendulum-noise0.01"):
        path = RESULTS / f"{name}.json"
        if not path.exists() or not path.stat().st_size:
            continue
        task = name.replace("-noise0.01", "")
        label = "" if task == name else " (1% sensor noise)"
        grouped: dict[tuple[str, str], list[tuple[float, str]]] = {}
        for row in json.loads(path.read_text())["rows"]:
            grouped.setdefault((row["method"], row["detector"]), []).append((row["mean"], row["variant"]))
        for (method, detector), values in grouped.items():
            worst = min(values)
            out.append((task, method + label, detector, len(values), float(np.mean([v for v, _ in values])),
                        worst[0], worst[1].split(":", 1)[1]))
    for path in sorted(RESULTS.glob("pong-*.json")):
        data = json.loads(path.read_text())
        for detector, per_variant in data["auroc"].items():
            worst = min((v, k) for k, v in per_variant.items())
            out.append(("pong", data["method"], detector, len(per_variant), float(np.mean(list(per_variant.values()))),
                        worst[0], worst[1].split(":", 1)[1]))
    return out


DETECTORS = ("spread", "dynamics", "features", "frames", "combined")


def table() -> str:
    """docs/detectors.md's table (between its ``<!-- detector_table -->`` markers; a test keeps them equal)."""
    agents: dict[str, dict[str, tuple[int, float, float]]] = {}
    for task, method, detector, n, mean, low, _ in rows():
        agents.setdefault(f"{task}-{method}", {})[detector] = (n, mean, low)
    lines = ["| agent | variants | " + " | ".join(DETECTORS) + " |", "|---|---:|" + "---:|" * len(DETECTORS)]
    for agent, by_detector in agents.items():
        best = max(mean for name, (_, mean, _) in by_detector.items() if name in DETECTORS)
        cells = []
        for detector in DETECTORS:
            if detector not in by_detector:
                cells.append("-")
                continue
            _, mean, low = by_detector[detector]
            cell = f"{mean:.3f} / {low:.3f}"
            cells.append(f"**{cell}**" if mean == best else cell)
        n = next(iter(by_detector.values()))[0]
        lines.append(f"| {agent} | {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--long", action="store_true", help="one row per agent and detector (mean, lowest, where)")
    if parser.parse_args().long:
        print("| agent | detector | variants | mean AUROC | lowest | at |")
        print("|---|---|---|---|---|---|")
        for task, method, detector, n, mean, low, where in rows():
            print(f"| {task}-{method} | {detector} | {n} | {mean:.3f} | {low:.3f} | {where} |")
        return
    print(table())


if __name__ == "__main__":
    main()
