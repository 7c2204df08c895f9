"""What a full-depth MC DropConnect decision's middle layer costs in compiled code, beside one SB3 predict().

Run: .venv/bin/python benchmarks/dropconnect_compiled_floor.py   (needs gcc; compiles a small C
file into a temporary folder; nothing of it is part of oodmon)

``dropconnect_floor.py`` shows that numpy cannot give the shipped full-depth DropConnect agents a
decision within one ``predict()``: its seven calls over the dropped weights alone cost about that.
This asks whether compiled code could. A C loop does what the agents' sampling does for the middle
layer, exactly (each of the K x active inputs x out weights dropped with probability p): it draws
the geometric gaps between dropped weights (a 64-bit xoshiro256+ uniform and ``log1p``, as
``oodmon.agents.plan.bernoulli_positions``), walks to each one's sample, input and output without
a division, and subtracts its term from its sample's output. No numpy call, no temporaries: a
floor for any compiled implementation that draws the same distribution one dropped weight at a
time. Beside it: the K rows' product with every weight kept (numpy's BLAS, as the agents do), and
the predict() of one plain SB3 model of the recipe's size; one thread.

Each figure is the median of 9 rounds that time the three back to back; lines
``compiled_floor_ratio_<task>=`` are the median over the rounds of (C loop + K rows' product) /
predict(); the last, ``compiled_floor_ratio=``, the larger. The rest of a decision (the first and
last layers, the activations, the mean and std) comes on top.
"""

from __future__ import annotations

import argparse
import ctypes
import subprocess
import tempfile
from pathlib import Path

import gymnasium
import numpy as np

import oodmon  # noqa: F401  (registers the envs)
from dropconnect_floor import PLAIN, REPEATS, middle_layer  # benchmarks/, beside this script
from oodmon.agents import load
from oodmon.agents.recipes import recipe_for
from oodmon.envs.grid import ENV_IDS
from oodmon.threads import set_threads
from timing import per_call_us, print_figures, print_ratios

ROUNDS = 9

SOURCE = r"""
#include <math.h>
#include <stdint.h>

static inline uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static inline uint64_t next(uint64_t *s) {  /* xoshiro256+ */
    uint64_t result = s[0] + s[3], t = s[1] << 17;
    s[2] ^= s[0]; s[3] ^= s[1]; s[1] ^= s[2]; s[0] ^= s[3]; s[2] ^= t; s[3] = rotl(s[3], 45);
    return result;
}

/* y[k][j] -= x[k][i] * w[i][j] for each weight (k, i, j) of K x n_in x n_out dropped with
   probability p; returns how many were dropped. The gaps are drawn 256 at a time, in a loop the
   compiler vectorises (glibc's vector log, -ffast-math), then walked one by one. */
long subtract_dropped(const float *x, const float *w, float *y, long K, long n_in, long n_out, double p,
                      uint64_t *state) {
    const double scale = 1.0 / log1p(-p);
    double uniform[256];
    long gaps[256];
    long k = 0, i = 0, j = -1, count = 0;
    for (;;) {
        for (int n = 0; n < 256; n++) uniform[n] = 1.0 - (double)(next(state) >> 11) * 0x1.0p-53;  /* (0, 1] */
        for (int n = 0; n < 256; n++) gaps[n] = (long)(log(uniform[n]) * scale) + 1;
        for (int n = 0; n < 256; n++) {
            j += gaps[n];  /* the gap to the next dropped weight */
            while (j >= n_out) {
                j -= n_out;
                if (++i == n_in) {
                    i = 0;
                    if (++k == K) return count;
                }
            }
            y[k * n_out + j] -= x[k * n_in + i] * w[i * n_out + j];
            count++;
        }
    }
}
"""


def compile_kernel(folder: Path) -> ctypes.CDLL:
    source, library = folder / "dropped.c", folder / "dropped.so"
    source.write_text(SOURCE)
    subprocess.run(["gcc", "-O3", "-march=native", "-ffast-math", "-shared", "-fPIC", str(source), "-o", str(library),
                    "-lmvec", "-lm"],
                   check=True)
    kernel = ctypes.CDLL(str(library))
    kernel.subtract_dropped.restype = ctypes.c_long
    kernel.subtract_dropped.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long,
                                        ctypes.c_long, ctypes.c_long, ctypes.c_double, ctypes.c_void_p]
    return kernel


def task_figures(task: str, kernel: ctypes.CDLL) -> tuple[dict[str, float], float]:
    env = gymnasium.make(ENV_IDS[task])
    obs, _ = env.reset(seed=0)
    agent = load(task, "dropconnect")
    k = agent.estimator.n_samples
    active, n_out, drops = middle_layer(agent, obs)
    p = float(agent.estimator._suffix[2].p)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((k, active)).astype(np.float32)
    w = rng.standard_normal((active, n_out)).astype(np.float32)
    y = np.zeros((k, n_out), np.float32)
    state = np.array([0x9E3779B97F4A7C15, 0xBF58476D1CE4E5B9, 0x94D049BB133111EB, 0x2545F4914F6CDD1D], np.uint64)
    pointers = [a.ctypes.data for a in (x, w, y)]
    counts = [kernel.subtract_dropped(*pointers, k, active, n_out, p, state.ctypes.data) for _ in range(200)]
    net_arch = list(recipe_for(task, "dropconnect").net_arch)
    plain = PLAIN[task]("MlpPolicy", env, policy_kwargs={"net_arch": net_arch}, seed=0, device="cpu")
    calls = {
        f"{task} sb3 predict (one plain model)": lambda: plain.predict(obs, deterministic=True),
        f"{task} C loop: {np.mean(counts):.0f} dropped weights on average (expected {drops})":
            lambda: kernel.subtract_dropped(*pointers, k, active, n_out, p, state.ctypes.data),
        f"{task} K rows' product: ({k}, {active}) x ({active}, {n_out})": lambda: np.matmul(x, w),
    }
    # The machine's speed drifts by tens of percent within seconds: the three are timed back to back
    # in each of ROUNDS rounds, and the ratio is the median of the rounds' ratios.
    rounds = [{name: per_call_us(call, REPEATS[task], rounds=1) for name, call in calls.items()} for _ in range(ROUNDS)]
    predict, loop, product = calls
    ratios = [(r[loop] + r[product]) / r[predict] for r in rounds]
    figures = {name: float(np.median([r[name] for r in rounds])) for name in calls}
    return figures, float(np.median(ratios))


def main() -> None:
    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    ratios = {}
    with tempfile.TemporaryDirectory() as folder:
        kernel = compile_kernel(Path(folder))
        for task in ("cartpole", "pendulum"):
            figures, ratios[task] = task_figures(task, kernel)
            print_figures(figures, 72)
    print_ratios("compiled_floor_ratio", ratios)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    main()
