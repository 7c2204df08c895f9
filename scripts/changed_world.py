"""A deployment whose world changed while its "ID" runs were logged, recalibrated with and without
the change: what `recalibrate`'s change warning (Pettitt's test) saves a user from.

Run (about a minute on one core):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/changed_world.py [--longer 0.6] \
        [--out results/deployment/changed-world.json]

Your own policy, as docs/your-policy.md's first example makes it: two small SB3 DQNs trained on
gymnasium's ``CartPole-v1`` (seeds 0 and 1), watched by ``oodmon.watch`` (its detectors fitted and
its threshold calibrated in that env). The deployment then logs 60 ID episodes, and 40 more after
its pole has grown from 0.5 to ``--longer`` (half-length, m) without anything saying so (the env's
``info`` has no ``shifted``): the 100 episodes are all "ID" to the logs. Recalibrated on both logs
(``calibrate_from_logs``: it warns of the change, and where it begins) and on the first alone, each
threshold (far 0.05, confidence 0.9) is then judged on fresh logged episodes of both worlds (100
with the first pole, 40 with the longer, other seeds): how many alarm. Writes the figures as JSON
and prints them.

Then a fault for a while (``burst``): 200 logged "ID" episodes, of which ``--burst`` (8) in their
middle (episodes 97-104) have the longer pole, unflagged, among 96 of the first pole before and 96
after (three logs, in that order). A threshold of far 0.05 on 200 episodes is their sixth highest
statistic: eight unlike the others set it. Recalibrated on all three logs (it warns of the crowd
of high statistics, :func:`oodmon.replay.burst`, and where) and on the two ID logs alone (the
burst's left out, as the warning says to), judged on the same fresh episodes.
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from pathlib import Path

import gymnasium

import oodmon
from oodmon.jsonfile import write_json
from oodmon.monitor import LongerThanCalibrationWarning, McapSink
from oodmon.monitor.alarms import episode_statistic
from oodmon.replay import ChangeInLogsWarning, calibrate_from_logs, change_in_logs, log_episodes
from oodmon.threads import limit_threads

LENGTH = 0.5  # CartPole-v1's pole half-length


def train(folder: Path) -> list[str]:
    """docs/your-policy.md's two DQNs (a few seconds each)."""
    from stable_baselines3 import DQN

    paths = []
    for seed in (0, 1):
        model = DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=seed, learning_starts=500, learning_rate=2.3e-3,
                    batch_size=64, train_freq=8, gradient_steps=2, target_update_interval=100,
                    exploration_fraction=0.3, exploration_final_eps=0.04, policy_kwargs={"net_arch": [64, 64]})
        model.learn(4000)
        paths.append(str(folder / f"dqn{seed}.zip"))
        model.save(paths[-1])
    return paths


def logged(models: list[str], threshold: Path, length: float, episodes: int, seed: int, path: Path) -> Path:
    """``episodes`` episodes of the watched policy in CartPole-v1 with pole half-length ``length``,
    unflagged, logged to ``path``."""
    env = gymnasium.make("CartPole-v1")
    env.unwrapped.length, env.unwrapped.polemass_length = length, env.unwrapped.masspole * length
    watched = oodmon.watch(models, "CartPole-v1", threshold=threshold, env=env, sinks=[McapSink(path)])
    for k in range(episodes):
        watched.reset(seed=seed + k)
        done = False
        while not done:
            _, _, terminated, truncated, _ = watched.step()
            done = terminated or truncated
    watched.close()
    return path


def alarmed(threshold, log: Path) -> int:
    """How many of ``log``'s episodes ``threshold``'s rule alarms in (its statistic above it)."""
    return sum(episode_statistic(episode.scores_of(threshold.detector), threshold.consecutive, threshold.window,
                                 warmup=threshold.warmup) > threshold.value
               for _, episode in log_episodes([log]).episodes)


def burst_case(models: list[str], folder: Path, longer: float, count: int, judged) -> dict:
    """The burst: 200 logged "ID" episodes, ``count`` of them in the middle with pole half-length
    ``longer``, unflagged (three logs); the warning, the two tests' figures, and the thresholds
    calibrated on all three logs and on the two ID logs alone, ``judged``."""
    ids = (200 - count) // 2
    around = [logged(models, folder / "sim.json", LENGTH, ids, 9000, folder / "burst" / "log-1.mcap"),
              logged(models, folder / "sim.json", longer, count, 9500, folder / "burst" / "log-2.mcap"),
              logged(models, folder / "sim.json", LENGTH, 200 - ids - count, 10000, folder / "burst" / "log-3.mcap")]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ChangeInLogsWarning)
        with_burst = calibrate_from_logs(around)
    statistics = change_in_logs(log_episodes(around), with_burst)
    crowd = statistics.burst
    return {"episodes": 200, "longer": count, "first_longer": ids,
            "warned": any(issubclass(w.category, ChangeInLogsWarning) for w in caught),
            "pettitt_p_value": statistics.change.p_value,
            "burst": {"p_value": crowd.p_value, "first": crowd.first, "last": crowd.last, "count": crowd.count,
                      "size": crowd.size},
            "thresholds": {"all three logs": judged(with_burst),
                           "the ID logs alone": judged(calibrate_from_logs([around[0], around[2]]))}}


def row_line(name: str, row: dict) -> str:
    """A threshold's row of the printed tables."""
    return (f"| {name} ({row['n_episodes']} episodes) | {row['detector']} > {row['value']:.6g} | "
            f"{row['fresh_id_alarmed']} of {row['fresh_id']} | {row['fresh_longer_alarmed']} of "
            f"{row['fresh_longer']} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--longer", type=float, default=0.6, help="the pole's half-length after the change")
    parser.add_argument("--burst", type=int, default=8, help="longer-pole episodes among 200 (the burst case, 1-100)")
    parser.add_argument("--out", default="results/deployment/changed-world.json")
    args = parser.parse_args()
    if not 1 <= args.burst <= 100:
        parser.error(f"--burst {args.burst}: give 1-100 longer-pole episodes among the 200")
    limit_threads()
    # the simulator's threshold, which the logged runs read, was calibrated on shorter episodes than
    # some of the policy's: its warning of each is beside the point here
    warnings.filterwarnings("ignore", category=LongerThanCalibrationWarning)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        models = train(folder)
        oodmon.watch(models, "CartPole-v1", save=folder / "sim.json", seed=0)
        first = logged(models, folder / "sim.json", LENGTH, 60, 5000, folder / "logs" / "log-1.mcap")
        second = logged(models, folder / "sim.json", args.longer, 40, 6000, folder / "logs" / "log-2.mcap")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ChangeInLogsWarning)
            both = calibrate_from_logs([first, second])
        said = [str(w.message) for w in caught if issubclass(w.category, ChangeInLogsWarning)]
        change = change_in_logs(log_episodes([first, second]), both).change
        alone = calibrate_from_logs([first])
        fresh_id = logged(models, folder / "sim.json", LENGTH, 100, 70000, folder / "fresh-id.mcap")
        fresh_longer = logged(models, folder / "sim.json", args.longer, 40, 80000, folder / "fresh-longer.mcap")

        def judged(threshold) -> dict:
            return {"detector": threshold.detector, "value": threshold.value, "n_episodes": threshold.n_episodes,
                    "fresh_id_alarmed": alarmed(threshold, fresh_id), "fresh_id": 100,
                    "fresh_longer_alarmed": alarmed(threshold, fresh_longer), "fresh_longer": 40}

        rows = {"both logs": judged(both), "the first log": judged(alone)}
        burst = burst_case(models, folder, args.longer, args.burst, judged)
    result = {"longer": args.longer, "change": {"p_value": change.p_value, "at": change.at, "before": change.before,
                                                "after": change.after, "warned": bool(said)}, "thresholds": rows,
              "burst": burst,
              "command": "OODMON_TORCH_THREADS=1 .venv/bin/python scripts/changed_world.py"
                         + (f" --longer {args.longer}" if args.longer != 0.6 else "")
                         + (f" --burst {args.burst}" if args.burst != 8 else "")}
    write_json(args.out, result)
    print(f"pole half-length {LENGTH} for 60 logged episodes, then {args.longer} for 40, unflagged")
    print(f"Pettitt's test on both logs: p = {change.p_value:.2g}, the change at episode {change.at + 1} of 100 "
          f"(medians {change.before:.4g} before, {change.after:.4g} after); warned: {bool(said)}")
    print("| calibrated on | threshold | fresh ID episodes alarmed | fresh longer-pole episodes alarmed |")
    print("|---|---|---|---|")
    for name, row in rows.items():
        print(row_line(name, row))
    crowd, ids = burst["burst"], burst["first_longer"]
    print(f"\na burst: {args.burst} longer-pole episodes among 200 (episodes {ids + 1}-{ids + args.burst}), unflagged")
    print(f"the burst scan: {crowd['count']} of the {crowd['size']} highest in episodes {crowd['first'] + 1}-"
          f"{crowd['last'] + 1}, p = {crowd['p_value']:.2g}; Pettitt's test p = {burst['pettitt_p_value']:.2g}; "
          f"warned: {burst['warned']}")
    for name, row in burst["thresholds"].items():
        print(row_line(name, row))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
