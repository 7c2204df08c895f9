"""Why DropConnect's Pong features miss mild motion blur: other fits and distances, measured.

Run: OODMON_TORCH_THREADS=1 .venv/bin/python scripts/pong_features_variants.py [METHOD] [CACHE.npz]

Plays the shipped Pong agent (default dropconnect; ~7 minutes on one core): 20 whole ID games
to fit on (seeds of the detectors' fit), 30 fresh ID games (the bench's ID seeds), 5 games each of
motion_blur@3 and @4 and 3 of gaussian_noise@3 shifting at the monitor protocol's onsets, and
keeps every decision's 512 features and action in CACHE (default /tmp/pong-features-METHOD.npz;
reused when it exists). Then, for each way of scoring (Mahalanobis from the chosen action's mean,
as shipped; from the nearest action's mean; from the pooled mean; the residual outside the top
50 or 200 principal components; the distance inside the top 50), prints the per-step AUROC of
shifted against ID steps and, for 50- and 200-decision means, the games alarmed with the
threshold set at the largest statistic of the first 15 ID games (false alarms in the other 15).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from sklearn.covariance import LedoitWolf
from sklearn.metrics import roc_auc_score

from oodmon import seeds
from oodmon.agents import load_agent, zoo_dir
from oodmon.bench import ONSETS, episode_onset
from oodmon.envs import parse_variant
from oodmon.names import METHODS
from oodmon.threads import limit_threads

RUNS = (("fit", "pong", 20, seeds.DETECTOR_FIT), ("id", "pong", 30, seeds.BENCH_ID),
        ("mb3", "pong:motion_blur@3", 5, seeds.BENCH_SHIFTED), ("mb4", "pong:motion_blur@4", 5, seeds.BENCH_SHIFTED),
        ("gn3", "pong:gaussian_noise@3", 3, seeds.BENCH_SHIFTED))
SHIFTED = ("mb3", "mb4", "gn3")


def collect(method: str, cache: Path) -> dict[str, np.ndarray]:
    agent = load_agent(zoo_dir() / f"pong-{method}", task="pong", seed=seeds.CALIBRATION)
    data: dict[str, np.ndarray] = {}
    for name, spec, games, seed in RUNS:
        variant, rows = parse_variant(spec), {"F": [], "A": [], "E": [], "SH": []}
        env = variant.make()
        for game in range(games):
            options = None if variant.is_id else {"onset_step": episode_onset(ONSETS["pong"], seed + game)}
            obs, info = env.reset(seed=seed + game, options=options)
            while True:
                estimate = agent.estimate(obs)
                action = int(np.asarray(estimate.action).reshape(-1)[0])
                for key, value in zip(("F", "A", "E", "SH"), (np.asarray(estimate.features, np.float16).reshape(-1),
                                                              action, game, bool(info.get("shifted", False)))):
                    rows[key].append(value)
                obs, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    break
            print(f"{spec}: game {game + 1}/{games}", file=sys.stderr, flush=True)
        data.update({f"{name}_{key}": np.array(values) for key, values in rows.items()})
    np.savez(cache, **data)
    return data


def scorers(fit: np.ndarray, actions: np.ndarray):
    pooled = fit.mean(axis=0)
    means = np.stack([fit[actions == a].mean(axis=0) if np.any(actions == a) else pooled for a in range(6)])
    precision = np.linalg.inv(LedoitWolf(assume_centered=True).fit(fit - means[actions]).covariance_)
    pooled_precision = np.linalg.inv(LedoitWolf().fit(fit).covariance_)
    _, singular, axes = np.linalg.svd(fit - pooled, full_matrices=False)

    def mahalanobis(x, mean, p):
        d = x - mean
        return np.einsum("ij,jk,ik->i", d, p, d)

    def residual(k):
        return lambda x, a: np.linalg.norm((x - pooled) - (x - pooled) @ axes[:k].T @ axes[:k], axis=1)

    return {
        "chosen action's mean (shipped)": lambda x, a: mahalanobis(x, means[a], precision),
        "nearest action's mean": lambda x, a: np.min([mahalanobis(x, m, precision) for m in means], axis=0),
        "pooled mean": lambda x, a: mahalanobis(x, pooled, pooled_precision),
        "residual outside top 50 PCs": residual(50),
        "residual outside top 200 PCs": residual(200),
        "inside top 50 PCs": lambda x, a: ((((x - pooled) @ axes[:50].T) / (singular[:50] / np.sqrt(len(fit)))) ** 2).sum(1),
    }


def window_means(scores: np.ndarray, w: int) -> np.ndarray:
    if len(scores) < w:
        return np.array([-np.inf])
    sums = np.cumsum(np.r_[0.0, scores])
    return (sums[w:] - sums[:-w]) / w


def main(method: str = "dropconnect", cache: str | None = None) -> None:
    limit_threads()
    path = Path(cache or f"/tmp/pong-features-{method}.npz")
    data = dict(np.load(path)) if path.exists() else collect(method, path)
    floats = {name: data[f"{name}_F"].astype(np.float64) for name, *_ in RUNS}
    for label, score in scorers(floats["fit"], data["fit_A"]).items():
        scores = {name: score(floats[name], data[f"{name}_A"]) for name in ("id", *SHIFTED)}
        games = {name: [(scores[name][data[f"{name}_E"] == g], data[f"{name}_SH"][data[f"{name}_E"] == g])
                        for g in np.unique(data[f"{name}_E"])] for name in ("id", *SHIFTED)}
        line = [label]
        for name in SHIFTED:
            shifted = scores[name][data[f"{name}_SH"]]
            labels = np.r_[np.zeros(len(scores["id"])), np.ones(len(shifted))]
            line.append(f"{name} AUROC {roc_auc_score(labels, np.r_[scores['id'], shifted]):.3f}")
        for w in (50, 200):
            stats = np.array([window_means(s, w).max() for s, _ in games["id"]])
            threshold = stats[:15].max()
            text = f"window {w}: false alarms {(stats[15:] > threshold).sum()}/{len(stats) - 15}"
            for name in SHIFTED:
                alarmed = 0
                for s, shifted in games[name]:
                    above = np.nonzero(window_means(s, w) > threshold)[0] + w - 1
                    alarmed += bool(np.any(above >= np.argmax(shifted)))
                text += f", {name} {alarmed}/{len(games[name])}"
            line.append(text)
        print(" | ".join(line), flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("method", nargs="?", default="dropconnect", choices=METHODS,
                        help="the shipped Pong agent (default dropconnect)")
    parser.add_argument("cache", nargs="?", help="the features' cache (default /tmp/pong-features-METHOD.npz)")
    args = parser.parse_args()
    main(args.method, args.cache)
