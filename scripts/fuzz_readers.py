"""Damage each kind of file oodmon reads, and see that its reader answers with oodmon's own errors.

Run (a minute or two; one core):
    .venv/bin/python scripts/fuzz_readers.py                 # every reader
    .venv/bin/python scripts/fuzz_readers.py --only log,vecnorm --flips 1000

A killed run's log ends at whatever byte reached the disk, a copied model may be cut short, a disk
may flip a bit. For each reader this cuts its file(s) at evenly spaced offsets (about ``--cuts``
of them per file, every byte of a small file) and flips one random bit ``--flips`` times per file
(seeded), reads each damaged copy, and counts what came back: read, or refused with one of
oodmon's errors (a one-line message at the command line). Anything else, a traceback at the
command line, is printed with its file, offset and message, and makes the exit code 1.

On 2026-11-27 the first run found: torn logs crashing replay with the mcap library's ``OSError``
and ``struct.error`` (62 of a 14 KB log's 14,312 cuts) and damaged chunks with ``ZstdError``; a
damaged VecNormalize file raising ``MemoryError`` as its unpickler allocated a flipped length; a
damaged ``model.json`` or ``detectors.json`` raising ``KeyError``; a bench baseline's damaged row
raising ``KeyError`` only when the bench compared, after its work. All are refused or recovered
now; this prints no such line. The ``sb3`` reader, added on 2026-11-30 (``--only sb3 --seed 4
--flips 1000``, 85 s): 13,367 damaged copies, 8,562 refused, 4,805 read, nothing else.
``pong_detectors``, added on 2026-12-01 (``--only pong_detectors --seed 7``, about a minute): 3,850
damaged copies, 3,779 refused, 71 read and scored, nothing else. ``kept_fitting`` and
``kept_calibration``, added on 2026-12-05, found a torn or flipped file of kept episodes crashing
`calibrate` (session 77's) and `fit-detectors` with zipfile's ``BadZipFile`` (3,704 of 3,841
copies), ``NotImplementedError`` (a flipped compression method) and tokenize's ``TokenError`` (numpy's
header); the readers now say every such file is none and go on without it: ``--only
kept_fitting,kept_calibration --flips 2000 --seed 3``, 7,041 damaged copies, all read (none or
warned), nothing else. ``kept_detectors``, added on 2026-12-06 with the epochs a kept set holds
(``--only kept_detectors --seed 5``, 9 s): 4,681 damaged copies, all read, nothing else; of 300
flips per file, the set was read back where the flip left ``detectors.json`` (59) or ``kept.json``
(67) valid, never where it hit the tensors (their hash). ``steps``, added on 2026-12-06 with the
frames of a picture policy's log (``--only steps``): 2,504 damaged copies, 2,204 read (a cut
is a torn log: its whole episodes before the tear), 300 refused, nothing else. ``region``, added on
2026-12-08 with log format 12 (``--only region --seed 99``): 2,446 damaged copies, 2,335 read, 111
refused, nothing else.

The readers: ``log`` (replay's ``read_log`` of a small format-6 log, two CartPole episodes in
segments of 4 steps: a cut or flip is a torn or damaged log, recovered), ``steps`` (``read_steps``
of a Pong log's whole episodes, two games of 5 decisions: the actions and frames
``fit-detectors --from-logs`` fits on), ``compared`` (``read_compared`` of a CartPole log under a
rule with a window, format 9: what replay's traces draw of a sequential rule), ``vecnorm`` (SB3
VecNormalize statistics, read without unpickling), ``sb3`` (a user's SB3 model file, its parts
damaged one at a time and zipped again: its ``data`` read by oodmon's restricted unpickler),
``model`` (a zoo agent's folder), ``detectors``
(the zoo CartPole ensemble's fitted detectors), ``pong_detectors`` (the zoo Pong DropConnect's set,
read and then its picture detectors, ``frames``, ``stillness``, ``vanishing`` and ``combined``,
scoring three steps of random frames: a damaged setting that loads would show there),
``threshold`` (a calibrated threshold), ``kept_fitting`` and ``kept_calibration`` (the episodes an
interrupted fit or calibration keeps: a damaged file is read as none, with a warning),
``kept_detectors`` (the fitted set an interrupted calibration keeps, with its ``kept.json``),
``region`` (a log whose first alarms say where in the picture, format 12: the episode records'
``first_alarm_region`` and the raising steps' ``raised.region``, read and listed as ``replay
--episodes`` lists them), ``baseline`` (``oodmon check --update``'s baseline) and
``bench`` (a committed bench result read as ``--baseline`` and compared with itself).
"""

from __future__ import annotations

import argparse
import collections
import random
import shutil
import sys
import tempfile
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _make_log(folder: Path) -> dict[str, Path]:
    from oodmon.agents import load
    from oodmon.envs import parse_variant
    from oodmon.monitor import McapSink, Monitor

    path = folder / "log.mcap"
    spec = "cartpole:length=2.0"
    with Monitor(load("cartpole", "dropout", seed=0), threshold=0.5, sinks=[McapSink(path)], segment_steps=4) as monitor:
        for seed in range(2):
            monitor.run_episode(parse_variant(spec).make(onset_step=3), seed=seed, max_steps=10, variant=spec)
    return {"log.mcap": path}


def _make_region(folder: Path) -> dict[str, Path]:
    """A log of two episodes of 20x40 pictures in which a ball vanishes mid-field, under the
    vanishing detector fitted on its rally: each first alarm names a region of the picture (log
    format 12), 16 KB (a Pong game reaches its first such alarm after hundreds of decisions)."""
    import numpy as np

    from oodmon.monitor import McapSink, Monitor
    from oodmon.monitor.detectors import Trajectory, VanishingDetector

    def rally(hidden=range(0)) -> np.ndarray:
        frames = np.full((26, 20, 40), 50, np.uint8)
        frames[:, 0] = 200
        for frame, x in zip(frames, [*range(0, 38, 3), *range(37, -1, -3)]):
            if x not in hidden:
                frame[6:8, x:x + 2] = 255
        return frames

    detector = VanishingDetector(grid=4, reach=4).fit([Trajectory(np.concatenate([rally()] * 3), np.zeros(77))])
    path = folder / "region.mcap"
    with Monitor(None, threshold=0.5, detectors=[detector], detector="vanishing", sinks=[McapSink(path)]) as monitor:
        for _ in range(2):
            monitor.begin_episode(env_id="Balls-v0", variant="Balls-v0:hidden", onset=3)
            for frame in rally(hidden=range(15, 25)):
                monitor.step(frame, action=0, frame=frame)
            monitor.end_episode(terminated=False)
    return {"region.mcap": path}


def _read_region(folder: Path) -> object:
    """read_log, then its episodes as ``replay --episodes`` lists them (the region in words)."""
    from oodmon.replay import read_log
    from oodmon.replay.report import episode_rows

    return episode_rows([read_log(folder / "region.mcap")])


def _make_compared(folder: Path) -> dict[str, Path]:
    """A CartPole log of two episodes under a rule with a window: each step message holds what the
    alarm compares (``compared``, format 9), which replay's traces read of a sequential rule."""
    from oodmon.agents import load
    from oodmon.envs import parse_variant
    from oodmon.monitor import McapSink, Monitor

    path = folder / "log.mcap"
    with Monitor(load("cartpole", "dropout", seed=0), threshold=0.5, window=3, sinks=[McapSink(path)]) as monitor:
        for seed in range(2):
            monitor.run_episode(parse_variant("cartpole").make(), seed=seed, max_steps=10)
    return {"log.mcap": path}


def _make_steps(folder: Path) -> dict[str, Path]:
    """A Pong log of two games of 5 decisions: what fit-detectors --from-logs reads of each step
    (its action, and the frame a picture's observation is logged as)."""
    from oodmon.agents import load
    from oodmon.envs import parse_variant
    from oodmon.monitor import McapSink, Monitor

    path = folder / "pong.mcap"
    with Monitor(load("pong", "dropconnect"), sinks=[McapSink(path)]) as monitor:
        for seed in range(2):
            monitor.run_episode(parse_variant("pong").make(), seed=seed, max_steps=5)
    return {"pong.mcap": path}


def _read_steps(folder: Path) -> object:
    """read_log, then read_steps of every whole episode it read (as fit-detectors --from-logs)."""
    from oodmon.replay import read_log
    from oodmon.replay.reader import read_steps

    log = read_log(folder / "pong.mcap")
    return read_steps(log.path, [episode.episode for episode in log.episodes])


def _make_vecnorm(folder: Path) -> dict[str, Path]:
    import gymnasium
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: gymnasium.make("CartPole-v1")]))
    venv.reset()
    for _ in range(20):
        venv.step([0])
    venv.save(folder / "vecnormalize.pkl")
    return {"vecnormalize.pkl": folder / "vecnormalize.pkl"}


def _make_sb3(folder: Path) -> dict[str, Path]:
    """A user's SB3 DQN file taken apart (its ``data`` JSON, whose entries SB3 would unpickle, its
    ``policy.pth`` and the rest): :func:`_read_sb3` zips them again, fresh CRCs and all, so that the
    damage reaches the readers of the parts and not only the zip's checksum."""
    import zipfile

    import gymnasium
    from stable_baselines3 import DQN

    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), seed=0, policy_kwargs={"net_arch": [16]}).save(folder / "dqn.zip")
    with zipfile.ZipFile(folder / "dqn.zip") as archive:
        archive.extractall(folder / "parts")
    return _folder_files(folder / "parts")


def _read_sb3(folder: Path) -> object:
    import zipfile

    from oodmon.agents.sb3 import load_sb3

    parts = sorted(p for p in folder.iterdir() if p.name != "model.zip")
    with zipfile.ZipFile(folder / "model.zip", "w") as archive:
        for part in parts:
            archive.write(part, part.name)
    return load_sb3([folder / "model.zip"], "CartPole-v1")


def _make_threshold(folder: Path) -> dict[str, Path]:
    from oodmon.agents import load
    from oodmon.monitor.calibration import calibrate_agent

    calibrate_agent(load("cartpole", "ensemble"), episodes=5, far=0.5, confidence=None).save(folder / "threshold.json")
    return {"threshold.json": folder / "threshold.json"}


def _make_baseline(folder: Path) -> dict[str, Path]:
    from oodmon.cli import main

    main(["check", str(ROOT / "tests" / "data"), "--baseline", str(folder / "baseline.json"), "--update"])
    return {"baseline.json": folder / "baseline.json"}


def _score_pong_pictures(folder: Path) -> object:
    """A Pong detector set read and then used: its picture detectors (the ones that need no policy's
    samples) score three steps of random frames, so that a damaged state that loads but does not fit
    its detector's settings shows where it would show in a run."""
    import numpy as np

    from oodmon.monitor.detectors import Trajectory, trajectory_scores
    from oodmon.monitor.detectors.store import DetectorSet

    pictures = DetectorSet.load(folder).subset(["frames", "stillness", "vanishing", "combined"])
    frames = np.random.default_rng(0).integers(0, 256, (4, 4, 84, 84), dtype=np.uint8)  # three steps and the last frame
    trajectory_scores(pictures, Trajectory(frames, np.zeros(3, np.int64)))
    return pictures


_MADE_BY = {"policy": "sha256:0", "seed": 1}


def _make_kept_fitting(folder: Path) -> dict[str, Path]:
    """The fitting episodes an interrupted `fit-detectors` keeps: three of a CartPole Dropout agent
    (10 steps each), the last two with their estimates (samples, features), as the held-out third."""
    from oodmon.agents import load
    from oodmon.monitor.detectors.fitting import _keep_trajectories, collect

    agent = load("cartpole", "dropout", seed=0)
    _keep_trajectories(folder / "kept.npz", _MADE_BY, collect(agent, agent.make_env(), 3, max_steps=10,
                                                              estimates_from=1))
    return {"kept.npz": folder / "kept.npz"}


def _make_kept_calibration(folder: Path) -> dict[str, Path]:
    import numpy as np

    from oodmon.monitor.calibration import _keep_episodes

    _keep_episodes(folder / "kept.npz", _MADE_BY, [np.linspace(0, 1, 7), np.linspace(1, 2, 5)])
    return {"kept.npz": folder / "kept.npz"}


def _make_kept_detectors(folder: Path) -> dict[str, Path]:
    """The detectors an interrupted `calibrate` keeps after its fit: the zoo CartPole ensemble's set
    beside ``kept.json`` (its dynamics model marked as trained 40 epochs)."""
    from oodmon.agents import load
    from oodmon.kept import keep_detectors
    from oodmon.monitor.detectors import detectors_for

    detectors = detectors_for(load("cartpole", "ensemble"))
    detectors["dynamics"].epochs_trained = 40
    keep_detectors(folder, _MADE_BY, detectors, {"state": 7})
    return _folder_files(folder)


def _folder_files(folder: Path) -> dict[str, Path]:
    return {p.name: p for p in folder.iterdir() if p.is_file()}


def _readers() -> dict[str, tuple[Callable[[Path], dict[str, Path]], Callable[[Path], object]]]:
    """Per reader: what makes (or names) its undamaged files, and what reads a folder of them."""
    from oodmon.agents.agent import load_agent
    from oodmon.agents.vec_normalize import load_vec_normalize
    from oodmon.bench.baseline import bench_falls, load_bench_result
    from oodmon.kept import read_kept_detectors
    from oodmon.monitor.calibration import read_kept_episodes
    from oodmon.monitor.detectors.fitting import read_kept_trajectories
    from oodmon.monitor.detectors.store import DetectorSet
    from oodmon.monitor.threshold import Threshold
    from oodmon.replay import read_log
    from oodmon.replay.check import load_baseline
    from oodmon.replay.reader import read_compared

    zoo = ROOT / "oodmon" / "zoo"
    bench = ROOT / "results" / "bench" / "cartpole.json"
    return {
        "log": (_make_log, lambda d: read_log(d / "log.mcap")),
        "region": (_make_region, _read_region),
        "steps": (_make_steps, _read_steps),
        "compared": (_make_compared, lambda d: read_compared(d / "log.mcap", [0, 1])),
        "vecnorm": (_make_vecnorm, lambda d: load_vec_normalize(d / "vecnormalize.pkl")),
        "sb3": (_make_sb3, _read_sb3),
        "model": (lambda _: _folder_files(zoo / "cartpole-dropout"), load_agent),
        "detectors": (lambda _: _folder_files(zoo / "cartpole-ensemble" / "detectors"), DetectorSet.load),
        "pong_detectors": (lambda _: _folder_files(zoo / "pong-dropconnect" / "detectors"), _score_pong_pictures),
        "threshold": (_make_threshold, lambda d: Threshold.load(d / "threshold.json")),
        "baseline": (_make_baseline, lambda d: load_baseline(d / "baseline.json")),
        "kept_fitting": (_make_kept_fitting, lambda d: read_kept_trajectories(d / "kept.npz", _MADE_BY)),
        "kept_calibration": (_make_kept_calibration, lambda d: read_kept_episodes(d / "kept.npz", _MADE_BY)),
        "kept_detectors": (_make_kept_detectors, lambda d: read_kept_detectors(d, _MADE_BY)),
        "bench": (lambda _: {"cartpole.json": bench},
                  lambda d: bench_falls(load_bench_result(bench), load_bench_result(d / "cartpole.json"))),
    }


def fuzz(name: str, files: dict[str, Path], read: Callable[[Path], object], cuts: int, flips: int,
         seed: int = 0) -> list[str]:
    """Read every damaged copy; print the outcome counts; return a line per exception not oodmon's."""
    from oodmon.errors import OodmonError

    originals = {rel: path.read_bytes() for rel, path in files.items()}
    rng = random.Random(seed)
    cases = []
    for rel, data in originals.items():
        stride = max(1, len(data) // cuts)
        cases += [(rel, f"cut at {offset}", data[:offset]) for offset in range(0, len(data), stride)]
        for _ in range(flips):
            position, bit = rng.randrange(len(data)), rng.randrange(8)
            damaged = bytearray(data)
            damaged[position] ^= 1 << bit
            cases.append((rel, f"bit {bit} of byte {position} flipped", bytes(damaged)))
    outcomes: collections.Counter[str] = collections.Counter()
    others = []
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        for rel, what, data in cases:
            for other, original in originals.items():
                (work / other).write_bytes(data if other == rel else original)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    read(work)
                outcomes["read"] += 1
            except OodmonError as error:
                outcomes[f"refused ({type(error).__name__})"] += 1
            except Exception as error:  # noqa: BLE001  (what this script looks for)
                outcomes[f"OTHER ({type(error).__name__})"] += 1
                others.append(f"{name}: {rel}, {what}: {type(error).__name__}: {error}\n"
                              + "".join(traceback.format_exc(limit=-2).splitlines(keepends=True)[-3:]))
    counts = ", ".join(f"{n} {outcome}" for outcome, n in outcomes.most_common())
    print(f"{name}: {len(cases)} damaged copies of {', '.join(originals)}: {counts}", flush=True)
    return others


def main() -> int:
    readers = _readers()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help=f"comma-separated readers (default all: {', '.join(readers)})")
    parser.add_argument("--cuts", type=int, default=2000, help="about this many cuts per file (default 2000)")
    parser.add_argument("--flips", type=int, default=400, help="single-bit flips per file (default 400)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the flips (default 0)")
    args = parser.parse_args()
    names = args.only.split(",") if args.only else list(readers)
    unknown = sorted(set(names) - set(readers))
    if unknown:
        parser.error(f"unknown readers {unknown}; choose from {', '.join(readers)}")
    others = []
    folder = Path(tempfile.mkdtemp())
    try:
        for name in names:
            make, read = readers[name]
            (folder / name).mkdir()
            others += fuzz(name, make(folder / name), read, args.cuts, args.flips, args.seed)
    finally:
        shutil.rmtree(folder)
    for line in others[:20]:
        print(line)
    print(f"errors that are not oodmon's: {len(others)}")
    return 1 if others else 0


if __name__ == "__main__":
    sys.exit(main())
