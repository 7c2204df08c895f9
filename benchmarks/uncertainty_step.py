"""Microseconds per decision with all K samples, beside one stable-baselines3 predict() call.

Run: .venv/bin/python benchmarks/uncertainty_step.py [--net-arch 64,64]

The estimators are built exactly as the shipped CartPole and Pendulum agents are (each task's
recipe: CartPole's [256, 256] DQN MLP, Pendulum's [400, 300] DDPG actor; Dropout at the output
layer, DropConnect at every layer, CartPole p = 0.02 and Pendulum p = 0.05): ensemble K=5, MC
Dropout and MC DropConnect with 20 samples; the baseline is ``model.predict()`` of one plain SB3
DQN (DDPG) of the same size. Batch of one observation, one thread for torch and numpy's BLAS, all in this process.

Each decision is timed in alternation with the plain predict(), 5 pairs of rounds, each order
once per pair (``timing.paired_us``): its figure is the median of its rounds, its ratio the median
of the pairs' ratios. The host's drifting speed moves that much less than the ratio of two
best-of-three figures taken a minute apart, which this script printed before 2026-11-27: three runs
of each, alternately, on a noisy afternoon read ``ratio_pendulum=`` 4.69, 9.07 and 11.61 the old way
and 8.43, 8.39 and 8.31 paired. Medians read higher than best rounds where a decision suffers more
from a busy host than predict() does (``ratio_cartpole=`` 2.30-2.45 the old way, 3.02-3.71 paired).
The last line is ratio=<worst decision's ratio to predict()>, over both tasks; the goal is <= 1.0,
which the
full-depth DropConnect agents do not meet (they drop weights of every layer of every sample: see
"Full depth" in oodmon/zoo/README.md, and ``benchmarks/dropconnect_floor.py`` for why numpy cannot
meet it on either task). ``ratio_<task>=`` is each task's worst; ``ratio_output_layer=`` the worst of
the agents whose sampling stops at the output layer; ``ratio_fixed_masks=`` the worst of the MC
agents loaded with ``masks="fixed"`` (their sampled decision and the fixed sub-networks' pass);
``ratio_fixed_decisions=`` the worst of them loaded with ``masks="fixed-decisions"`` (the fixed
sub-networks decide: one pass, no random draw), with ``ratio_fixed_decisions_<task>=`` per task.

``--net-arch 64,64``: every agent built with these hidden widths instead of its recipe's (a candidate
that would decide faster; the recipes' drop probabilities and K), beside the same plain predict() of
the recipes' size and, on a line of its own, a plain predict() of the candidate's size.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from statistics import median

import gymnasium
from stable_baselines3 import DDPG, DQN

import oodmon  # noqa: F401  (registers the envs)
from oodmon.agents.algorithms import architecture
from oodmon.agents.networks import build_modules, estimator_for
from oodmon.agents.recipes import parse_widths, recipe_for
from oodmon.envs.grid import ENV_IDS
from oodmon.threads import set_threads
from timing import paired_us, per_call_us  # benchmarks/timing.py, beside this script

REPEATS = {"cartpole": 2000, "pendulum": 500}
PLAIN = {"cartpole": DQN, "pendulum": DDPG}


def plain_predict(task: str, net_arch: list[int]):
    """A call of one plain SB3 model's predict() of these hidden widths, at the task's first observation."""
    env = gymnasium.make(ENV_IDS[task])
    obs, _ = env.reset(seed=0)
    plain = PLAIN[task]("MlpPolicy", env, policy_kwargs={"net_arch": net_arch}, seed=0, device="cpu")
    return lambda: plain.predict(obs, deterministic=True)


Figure = tuple[float, float]  # a decision's median us, and its median ratio to predict() in the same rounds


def task_figures(task: str, net_arch: list[int] | None = None
                 ) -> tuple[float, dict[str, Figure], set[str], dict[str, Figure], dict[str, Figure]]:
    """One plain predict()'s time (the median over every label's rounds), each method's decision by
    label, the full-depth labels, the MC methods' decisions with fixed masks (a second pass beside the
    sampled decision) and with fixed masks that decide (one pass); each decision as its time and its
    ratio to predict() timed beside it; ``net_arch``: the agents' hidden widths instead of their recipes'."""
    env = gymnasium.make(ENV_IDS[task])
    obs, _ = env.reset(seed=0)
    predict = plain_predict(task, list(recipe_for(task, "ensemble").net_arch))
    baselines = []

    def timed(call) -> Figure:
        us, baseline, ratio = paired_us(call, predict, REPEATS[task])
        baselines.append(baseline)
        return us, ratio

    figures, full_depth, fixed, deciding = {}, set(), {}, {}
    for method in ("ensemble", "dropout", "dropconnect"):
        recipe = recipe_for(task, method)
        if net_arch is not None:
            recipe = replace(recipe, net_arch=list(net_arch))
        arch = architecture(recipe, env)
        bounds = {} if task == "cartpole" else {"action_low": env.action_space.low, "action_high": env.action_space.high}
        modules = build_modules(arch)  # one network, timed with each kind of masks
        estimator = estimator_for(modules, arch, n_samples=recipe.n_samples, **bounds)
        depth = "" if method == "ensemble" else " (output layer)" if recipe.last_only else f" (full depth, p={recipe.drop_p:g})"
        size = "" if net_arch is None else f" {recipe.net_arch}"
        label = f"{task} {method}{size} K={estimator.n_samples}{depth}"
        if method != "ensemble" and not recipe.last_only:
            full_depth.add(label)
        figures[label] = timed(lambda: estimator.estimate(obs))
        if method != "ensemble":
            masked = estimator_for(modules, arch, n_samples=recipe.n_samples, masks="fixed", **bounds)
            fixed[f"{label}, fixed masks"] = timed(lambda: masked.estimate(obs))
            one_pass = estimator_for(modules, arch, n_samples=recipe.n_samples, masks="fixed-decisions", **bounds)
            deciding[f"{label}, fixed masks deciding"] = timed(lambda: one_pass.estimate(obs))
    return median(baselines), figures, full_depth, fixed, deciding


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--net-arch", type=parse_widths,
                        help="hidden widths of every agent instead of its recipe's, e.g. 64,64")
    args = parser.parse_args()
    set_threads(1)  # torch and numpy's BLAS, as every oodmon command
    ratios, output_layer, fixed_ratios, deciding_ratios = {}, [], [], {}
    for task in ("cartpole", "pendulum"):
        baseline, figures, full_depth, fixed, deciding = task_figures(task, args.net_arch)
        print(f"{task + ' sb3 predict (one plain model; median)':80s} {baseline:10.1f} us")
        if args.net_arch is not None:
            own = per_call_us(plain_predict(task, args.net_arch), REPEATS[task])
            print(f"{task + f' sb3 predict (one plain model, {args.net_arch})':80s} {own:10.1f} us")
        for label, (us, ratio) in (figures | fixed | deciding).items():
            print(f"{label:80s} {us:10.1f} us  ({ratio:.2f} predict())")
        ratios[task] = max(ratio for _, ratio in figures.values())
        output_layer += [ratio for label, (_, ratio) in figures.items() if label not in full_depth]
        fixed_ratios += [ratio for _, ratio in fixed.values()]
        deciding_ratios[task] = max(ratio for _, ratio in deciding.values())
    for task, ratio in ratios.items():
        print(f"ratio_{task}={ratio:.2f}")
    print(f"ratio_output_layer={max(output_layer):.2f}")
    print(f"ratio_fixed_masks={max(fixed_ratios):.2f}")
    for task, ratio in deciding_ratios.items():
        print(f"ratio_fixed_decisions_{task}={ratio:.2f}")
    print(f"ratio_fixed_decisions={max(deciding_ratios.values()):.2f}")
    print(f"ratio={max(ratios.values()):.2f}")


if __name__ == "__main__":
    main()
