"""Reading a torn log (what a killed run leaves) beside reading the same log finished.

Run: .venv/bin/python benchmarks/replay_torn.py

Writes one MCAP log of 200 CartPole-like episodes of 500 steps (100,000 steps, by the real
McapSink from synthetic step records, as ``replay_throughput.py`` writes them) and a copy taken
before the sink's close, in the middle of a 201st episode: the file a SIGKILL leaves, with no
summary or index, which replay streams through to recover. Each file is read by ``read_log`` in a
fresh process (best of 3), which prints its time and its peak resident memory.

The last line is ratio=<torn read time / finished read time>, lower is better. Recovering streams
through and decompresses every chunk, so it costs more than the indexed read. On 2026-11-27 the
recovery decoded and kept every step message: 1.51 s and 211 MB peak (ratio=42.73; the finished
log 0.04 s, 63 MB); since it keeps only the running episode's, undecoded until the end, 0.36 s and
63 MB (ratio=10.67). The same change on a real torn log (`oodmon run --task cartpole --method
ensemble --episodes 100000 --mcap big.mcap` SIGKILLed after 40 s: 43 MB, 467 episodes, 233,500
steps): 5.5 s and 619 MB peak before, 1.0 s and 89 MB after.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from oodmon.monitor import McapSink
from oodmon.monitor.records import EpisodeRecord, EpisodeStart, RunInfo, StepRecord

EPISODES, LENGTH, CUT_AT = 200, 500, 250

READ = """
import resource, sys, time, warnings
warnings.simplefilter("ignore")
from oodmon.replay import read_log
start = time.perf_counter()
log = read_log(sys.argv[1])
seconds = time.perf_counter() - start
print(seconds, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, len(log.episodes), len(log.interrupted))
"""


def write_log(folder: Path) -> tuple[Path, Path]:
    """The finished log and the torn copy (taken inside the episode after the last whole one)."""
    rng = np.random.default_rng(0)
    path, torn = folder / "run.mcap", folder / "torn.mcap"
    sink = McapSink(path)  # its chunks as a run writes them (the running episode's steps are not on disk yet)
    sink.open(RunInfo("cartpole", "ensemble", "chosen_std", 3.0, "score > 3 for 3 consecutive steps", "none", {}))
    for episode in range(EPISODES + 1):
        sink.begin_episode(EpisodeStart(episode, "oodmon/CartPole-v1", "cartpole", 0, episode))
        scores = rng.gamma(4.0, 0.5, LENGTH)
        for step, score in enumerate(scores):
            sink.write_step(StepRecord(episode, step, int(step % 2), [90.0, 91.0], [score, score * 0.9], float(score),
                                       3.0, bool(score > 3.0), False, [0.01, -0.02, 0.03, 0.0]))
            if episode == EPISODES and step == CUT_AT:
                shutil.copyfile(path, torn)
                break
        else:
            sink.end_episode(EpisodeRecord(episode, "oodmon/CartPole-v1", "cartpole", 0, episode, 500.0, LENGTH, 0, None))
    sink.close()
    return path, torn


def read(path: Path) -> tuple[float, float, int, int]:
    """(seconds, peak MB, whole episodes, interrupted ones) of the best of 3 fresh processes."""
    runs = []
    for _ in range(3):
        out = subprocess.run([sys.executable, "-c", READ, str(path)], capture_output=True, text=True, check=True)
        seconds, megabytes, whole, cut = out.stdout.split()
        runs.append((float(seconds), float(megabytes), int(whole), int(cut)))
    return min(runs)


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        finished, torn = write_log(Path(folder))
        sizes = finished.stat().st_size / 1e6, torn.stat().st_size / 1e6
        (finished_s, finished_mb, whole, _), (torn_s, torn_mb, recovered, cut) = read(finished), read(torn)
    print(f"finished log ({sizes[0]:.1f} MB, {whole} episodes)      read in {finished_s:.2f} s, peak {finished_mb:.0f} MB")
    print(f"torn copy ({sizes[1]:.1f} MB, {recovered} episodes + {cut} cut)  read in {torn_s:.2f} s, peak {torn_mb:.0f} MB")
    print(f"ratio={torn_s / finished_s:.2f}")


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
