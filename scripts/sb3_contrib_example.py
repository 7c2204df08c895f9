"""sb3-contrib's policies watched by oodmon: docs/your-policy.md's figures for them, trained and measured.

Run (about 5 minutes on two cores on 2026-11-29; each model trains on one thread):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/sb3_contrib_example.py --out runs/contrib

Trains, in parallel, five models on one thread each (a model already in ``--out`` is kept):
three QR-DQNs on CartPole-v1 (seeds 0, 1, 2; 30,000 steps), a TQC on Pendulum-v1 (8,000 steps),
a RecurrentPPO on CartPole-v1 (8 envs, 60,000 steps) and a MaskablePPO on the masked CartPole of
``scripts/masked_cartpole.py`` (30,000 steps). Then, for the first QR-DQN alone, the three as an
ensemble, the TQC, the RecurrentPPO and the MaskablePPO, docs/your-policy.md's commands as a user runs them
(``oodmon calibrate`` with the defaults, ``validate`` on 200 fresh ID episodes (100 for the masked
env), ``run`` with a shift from step 50 for 20 episodes, ``replay --monitor``), each model's mean
return over 20 ID episodes first. ``--only NAME,...`` runs some of them (qrdqn, qrdqn3, tqc,
rppo, maskable).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # masked_cartpole, for --env masked_cartpole:...

from oodmon.threads import limit_threads  # noqa: E402

MASKED = "masked_cartpole:MaskedCartPole-v0"


def train(name: str, out: Path) -> Path:
    """One model, trained on one thread and saved as ``out/<name>.zip`` (kept if it is there)."""
    path = out / f"{name}.zip"
    if path.exists():
        return path
    limit_threads()
    import gymnasium
    import sb3_contrib
    from stable_baselines3.common.env_util import make_vec_env

    import masked_cartpole  # noqa: F401  (registers its env)

    if name.startswith("qrdqn"):
        model = sb3_contrib.QRDQN(
            "MlpPolicy", gymnasium.make("CartPole-v1"), seed=int(name[5:] or 0), learning_starts=1000,
            learning_rate=2.3e-3, batch_size=64, train_freq=8, gradient_steps=2, target_update_interval=100,
            exploration_fraction=0.16, exploration_final_eps=0.04, policy_kwargs={"net_arch": [64, 64], "n_quantiles": 10})
        model.learn(30_000)
    elif name == "tqc":
        model = sb3_contrib.TQC("MlpPolicy", gymnasium.make("Pendulum-v1"), seed=0, learning_starts=1000,
                                policy_kwargs={"net_arch": [64, 64], "n_critics": 2})
        model.learn(8_000)
    elif name == "rppo":
        model = sb3_contrib.RecurrentPPO(
            "MlpLstmPolicy", make_vec_env("CartPole-v1", n_envs=8, seed=0), seed=0, n_steps=128, batch_size=256,
            n_epochs=4, learning_rate=1e-3, policy_kwargs={"lstm_hidden_size": 32, "net_arch": [64]})
        model.learn(60_000)
    else:
        model = sb3_contrib.MaskablePPO("MlpPolicy", gymnasium.make(MASKED.split(":")[1]), seed=0)
        model.learn(30_000)
    model.save(path)
    return path


#: name -> (model files, env id, shift, validation episodes, replay's --failure)
CASES = {
    "qrdqn": (["qrdqn"], "CartPole-v1", "cartpole:length=2.0", 200, None),
    "qrdqn3": (["qrdqn", "qrdqn1", "qrdqn2"], "CartPole-v1", "cartpole:length=2.0", 200, None),
    "tqc": (["tqc"], "Pendulum-v1", "pendulum:m=5.0", 200, None),
    "rppo": (["rppo"], "CartPole-v1", "cartpole:length=2.0", 200, None),
    "maskable": (["maskable"], MASKED, f"{MASKED}:length=2.0", 100, "terminated"),
}


def measure(name: str, out: Path) -> None:
    """docs/your-policy.md's commands for one case, printed as a user sees them."""
    from oodmon.agents.sb3 import load_sb3
    from oodmon.cli import main as oodmon

    files, env_id, shift, validation, failure = CASES[name]
    models = [str(out / f"{file}.zip") for file in files]
    agent = load_sb3(models, env_id)
    env = agent.make_env()
    returns = []
    for seed in range(20):
        obs, _ = env.reset(seed=seed)
        done, total = False, 0.0
        while not done:
            obs, reward, terminated, truncated, _ = env.step(agent.act(obs))
            total, done = total + float(reward), terminated or truncated
        returns.append(total)
    print(f"\n== {name}: {' '.join(files)} in {env_id}: mean ID return over 20 episodes {np.mean(returns):.1f}", flush=True)
    common = ["--sb3", *models, "--env", env_id]
    threshold, log = str(out / f"{name}.json"), str(out / f"{name}.mcap")
    Path(log).unlink(missing_ok=True)
    if not Path(threshold).exists():
        oodmon(["calibrate", *common, "--out", threshold])
    oodmon(["validate", threshold, *common, "--episodes", str(validation)])
    oodmon(["run", *common, "--threshold", threshold, "--variant", shift, "--onset", "50", "--episodes", "20",
            "--mcap", log])
    oodmon(["replay", "--monitor", log, *(["--failure", failure] if failure else [])])
    if len(files) > 1:
        oodmon(["replay", log])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/contrib"))
    parser.add_argument("--only", default=",".join(CASES), help="cases, comma-separated: " + ", ".join(CASES))
    args = parser.parse_args()
    cases = [c for c in args.only.split(",") if c]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"unknown case(s) {', '.join(unknown)}; choose from {', '.join(CASES)}")
    args.out.mkdir(parents=True, exist_ok=True)
    names = sorted({file for case in cases for file in CASES[case][0]})
    with ProcessPoolExecutor(max_workers=2) as pool:
        list(pool.map(train, names, [args.out] * len(names)))
    for case in cases:
        measure(case, args.out)


if __name__ == "__main__":
    main()
