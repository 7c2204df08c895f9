"""Odd arguments to oodmon's public Python calls: does any answer other than with oodmon's own error?

Run (six to seven minutes on one core):
    OODMON_TORCH_THREADS=1 .venv/bin/python scripts/fuzz_api.py [--only calibrate_from_logs,pettitt]

For each call a user makes from Python (``oodmon.watch``, ``Monitor`` and a short episode under it,
``calibrate``, ``calibrate_agent``, ``validate_threshold``, ``fit_agent_detectors``, ``Threshold``,
the sinks, the shifted envs, ``load``, ``plain_agent``, ``read_log``, ``ShiftAttributes``), each argument in turn takes
each of a list of odd values (0, -1, nan, inf, text, None, a bool, an empty list or dict, numpy's
scalars, 10**30, ``/dev/zero``, a folder...), the others good ones, and the call's answer is sorted:

- ``ok`` (it ran), ``oodmon`` (oodmon's own error, which names the argument), ``slow`` (still
  working after ``--seconds``: real work began, the value was taken);
- ``python``: Python's ``TypeError`` or ``AttributeError`` for a value of the wrong kind (a float
  where a path goes), which is how Python's own calls answer it, listed with ``--all``;
- ``finding``: anything else (numpy's "could not convert string to float", gymnasium's "Seed
  must be a python integer", an ``OverflowError``...), printed; the exit code is then 1;
- ``leak``: a call that left torch's grad mode off, printed too (exit code 1).

On 2026-12-05 its first form found: a negative, float or numpy seed of ``calibrate_agent``,
``validate_threshold`` and ``id_episode_scores`` reaching gymnasium's reset (its own error; numpy's
integers, which every count takes, refused there); ``dynamics_updates`` of numpy's saved into a
detector's JSON config, which then failed to write; ``watch(episodes=nan)`` failing in numpy;
``validate_threshold(threshold=4.0)``; ``calibrate`` of text; callbacks or sinks that are no such
things, said at the first alarm or as a warning at every step; and, once a call stopped by the alarm
had left torch's grad mode off, that the dynamics model's fit failed inside a caller's
``torch.no_grad()``. All fixed; then
(2026-12-05, 362 s): 1,585 oodmon, 470 ok, 191 python, 64 slow of 2,310 calls, no finding, no leak.
With ``fit_agent_detectors`` among the calls it found the same seed there (fixed); then (379 s):
1,671 oodmon, 517 ok, 213 python, 63 slow of 2,464 calls, no finding, no leak. With 10**30 and 2**63
among the values (2026-12-05, those two alone): 12 findings, numpy's "Maximum allowed dimension
exceeded" and Python's OverflowError of a rule's window, consecutive steps or warm-up, of
``calibrate_agent``'s and ``watch``'s episodes, and torch's of ``fit_agent_detectors``' seed. Fixed:
the steps a count names and the seeds are bounded, and the episodes counted without an array of
them; then those two values: 125 oodmon, 57 ok, 22 python, 20 slow of 224 calls. Later that day,
with ``AlarmCommand`` among the calls (its odd commands, ``abc`` and ``/dev/zero``, fail in the shell,
which says so): 2 findings, ``obs_noise=''`` of ``calibrate_agent`` and ``validate_threshold``, no
noise to an ``if not`` and then not a float (fixed: a noise that is not a number is refused); then
1,804 oodmon, 543 ok, 224 python, 74 slow of 2,645 calls, no finding, no leak. The next session
the same, 1,803 oodmon and 72 slow; with ``max_steps`` of ``Threshold``, ``calibrate_agent``,
``validate_threshold``, ``id_episode_scores`` and ``watch``: 1,899 oodmon, 554 ok, 227 python, 80
slow of 2,760 calls, no finding, no leak. Later (the session after), 2 findings:
``fit_agent_detectors(max_steps=0)`` and ``max_steps=False`` reached gymnasium's ``TimeLimit`` (its
ValueError; fixed: refused by name, as the other calls do), of 1,899 oodmon, 545 ok, 236 python and
78 slow; after the fix: 1,918 oodmon, 543 ok, 221 python, 78 slow of 2,760 calls, no finding, no leak.
The next session (the same again), with step mode's calibration by episode and ``calibrate_agent``'s
``kept`` among the calls: 1 finding, ``calibrate(mode="step", confidence=0.5)``'s
ZeroDivisionError (both t quantiles of the clustered limit 0 at the median; fixed), of 1,968
oodmon, 550 ok, 255 python and 78 slow of 2,852 calls; after the fix: 1,968 oodmon, 550 ok, 255
python, 79 slow of 2,852 calls, no finding, no leak. With ``fit_agent_detectors``' ``kept`` among
them (2026-12-05, 7 minutes): 1,968 oodmon, 556 ok, 273 python, 78 slow of 2,875 calls, no finding,
no leak. On 2026-12-06, with ``calibrate_from_logs``, ``fit_detectors_from_logs`` and ``pettitt``
among the calls (``--only`` them): 4 findings, ``pettitt`` of text (numpy's "could not convert
string to float"; fixed: refused by name, as are a number alone and arrays of two dimensions);
then 232 oodmon, 41 python, 26 ok of 299 calls, no finding, no leak. With ``burst`` (``--only
burst,pettitt``, after its share, permutations and seed were checked by name): 106 oodmon, 9 ok of
115 calls, no finding. With ``Monitor``'s ``reading_names`` (2026-12-07, ``--only Monitor``, 7 s): 134
oodmon, 87 ok, 32 python of 253 calls, no finding, no leak. With ``reading_names`` of ``Threshold``,
``calibrate_agent`` and ``watch`` (2026-12-08, ``--only Threshold,calibrate_agent,watch``, 8 minutes):
852 oodmon, 88 ok, 79 slow, 62 python of 1,081 calls, no finding, no leak. With the calls of a
deployment oodmon cannot play (later that day, ``--only fit_on_episodes,calibrate_on_episodes,
validate_on_episodes,watch_recorded``, 9 s): 426 oodmon, 112 python, 106 ok of 644 calls, no finding;
among the python answers an error message of its own that took ``len()`` of a number, a detector
name that was a list, and ``threshold=`` not a path (each now oodmon's error); then 508 oodmon,
104 ok, 32 python (sinks and callbacks that are no lists, as for ``watch``) of 644. With
``save_records`` and ``load_records`` (``--only save_records,load_records``): 3 findings, a folder,
an empty name and /dev/zero given to ``save_records`` (Python's IsADirectoryError, numpy's "argument
out of range"); fixed (the path checked as every output is, the file written whole), then 67 oodmon,
2 ok of 69 calls.
"""

from __future__ import annotations

import argparse
import collections
import os
import tempfile
import warnings
from pathlib import Path

from fuzz_cli import StillWorking, limit_memory, time_limit  # (beside it in scripts/)

#: A log of oodmon's, the good path of ``read_log`` (found before main() moves to its own folder).
LOG = Path(__file__).resolve().parents[1] / "tests" / "data" / "cartpole-ensemble-id.mcap"



def odd_values() -> list:
    import numpy as np

    return [0, -1, 1, float("nan"), float("inf"), -float("inf"), "abc", "", None, True, False, 1e9, [], {}, 2.5, -0.0,
            object(), (1, 2), np.float32(0.5), np.int64(3), 10**30, "/dev/zero", "adir"]


def cases() -> list[tuple[str, object, dict, list[str]]]:
    """(name, call, good arguments, the arguments to vary) of each public call."""
    import gymnasium
    import numpy as np

    import oodmon
    from oodmon import agents, envs, monitor, replay
    from oodmon.monitor.detectors.fitting import fit_agent_detectors
    from oodmon.replay.recalibrate import burst, pettitt

    agent = agents.load("cartpole", "ensemble")
    threshold = monitor.Threshold(value=1.0, score="chosen_std", consecutive=3, mode="episode", far=0.05, n_episodes=50,
                                  n_steps=100)
    log = str(LOG)

    def monitored_episode(**arguments):
        with monitor.Monitor(agent, **arguments) as watching:
            watching.run_episode(gymnasium.make("oodmon/CartPole-v1"), seed=0, max_steps=5)

    def shifted_reset(**arguments):
        envs.ShiftAttributes(**arguments).reset(seed=0)

    # a deployment oodmon cannot play: recorded CartPole episodes of a controller, 60 steps each
    def recorded(count: int, seed: int) -> list:
        env, episodes = gymnasium.make("CartPole-v1", max_episode_steps=60), []
        for index in range(count):
            obs, _ = env.reset(seed=seed + index)
            observations, actions, done = [], [], False
            while not done:
                observations.append(obs)
                actions.append(int(obs[2] + 0.5 * obs[3] > 0))
                obs, _, terminated, truncated, _ = env.step(actions[-1])
                done = terminated or truncated
            episodes.append((np.array(observations), np.array(actions)))
        return episodes

    discrete = gymnasium.spaces.Discrete(2)
    fit, calibration, fresh = recorded(6, 0), recorded(22, 100), recorded(3, 200)
    fitted = monitor.fit_on_episodes(fit, discrete, dynamics_updates=20)
    saved = Path(tempfile.mkdtemp(prefix="oodmon-fuzz-recorded-")) / "robot.json"
    monitor.watch_recorded(fit, calibration, action_space=discrete, far=0.1, save=saved)

    def alarm_command(**arguments):
        command = monitor.AlarmCommand(**arguments)
        command(monitor.AlarmEvent(0, 5, 7.0, 1.0, "score > threshold", "spread"))
        command.close()

    return [
        ("Monitor", monitored_episode, dict(threshold=1.0),
         ["threshold", "score", "detector", "consecutive", "window", "sinks", "callbacks", "segment_steps", "strict",
          "log_observations", "reading_names"]),
        ("Threshold", monitor.Threshold, dict(threshold.__dict__),
         ["value", "score", "consecutive", "mode", "far", "n_episodes", "n_steps", "window", "detector", "confidence",
          "rule", "warmup", "max_steps", "reading_names"]),
        ("calibrate", monitor.calibrate, dict(episode_scores=[np.ones(10)] * 50, far=0.05),
         ["episode_scores", "far", "consecutive", "mode", "score", "window", "detector", "confidence", "rule",
          "warmup"]),
        ("calibrate step", monitor.calibrate, dict(episode_scores=[np.arange(10.0)] * 50, far=0.05, mode="step"),
         ["episode_scores", "far", "confidence"]),
        ("calibrate_agent", monitor.calibrate_agent, dict(agent=agent, episodes=50, far=0.05),
         ["episodes", "far", "consecutive", "mode", "score", "seed", "window", "detector", "obs_noise", "confidence",
          "rule", "reference_episodes", "warmup", "workers", "max_steps", "kept", "reading_names"]),
        ("validate_threshold", monitor.validate_threshold, dict(agent=agent, threshold=threshold, episodes=2),
         ["threshold", "episodes", "seed", "obs_noise", "workers", "max_steps"]),
        ("id_episode_scores", monitor.id_episode_scores, dict(agent=agent, episodes=1),
         ["episodes", "seed", "score", "max_steps"]),
        ("fit_agent_detectors", fit_agent_detectors, dict(agent=agent, detectors=["dynamics"], episodes=3, max_steps=20),
         ["detectors", "episodes", "seed", "obs_noise", "max_steps", "workers", "dynamics_updates", "kept", "explore"]),
        ("McapSink", monitor.McapSink, dict(path="x.mcap"),
         ["path", "compression", "split_episodes", "split_mb", "flush_seconds"]),
        ("RerunSink", monitor.RerunSink, dict(path="x.rrd"),
         ["path", "port", "bind", "flush_timeout", "connect_timeout", "recording_id"]),
        ("ShiftedCartPole", envs.ShiftedCartPole, dict(),
         ["onset_step", "obs_noise", "length", "gravity", "masscart", "render_mode"]),
        ("ShiftedPendulum", envs.ShiftedPendulum, dict(), ["onset_step", "obs_noise", "g", "m", "l", "max_speed"]),
        ("make_corruption", envs.make_corruption, dict(name="gaussian_noise", severity=3), ["name", "severity"]),
        ("parse_variant", envs.parse_variant, dict(spec="cartpole:length=2.0"), ["spec"]),
        ("load", agents.load, dict(task="cartpole", method="ensemble"), ["task", "method", "n_samples", "seed", "masks"]),
        ("plain_agent", agents.plain_agent, dict(policy=lambda obs: 0, env_id="CartPole-v1"),
         ["policy", "env_id", "weights"]),
        ("read_log", replay.read_log, dict(path=log), ["path"]),
        ("calibrate_from_logs", replay.calibrate_from_logs, dict(logs=[log], far=0.5, confidence=None),
         ["logs", "far", "confidence", "detector", "consecutive", "window", "warmup", "mode", "last"]),
        ("fit_detectors_from_logs", replay.fit_detectors_from_logs, dict(agent=agent, logs=[log], dynamics_updates=20),
         ["logs", "detectors", "seed", "dynamics_updates", "last"]),
        ("pettitt", pettitt, dict(values=[1.0, 2.0, 3.0]), ["values"]),
        ("burst", burst, dict(values=list(np.arange(40.0))), ["values", "share", "permutations", "seed"]),
        ("watch", oodmon.watch, dict(policy=agent, episodes=50),
         ["env_id", "far", "confidence", "episodes", "fit_episodes", "detector", "seed", "masks", "warmup", "workers",
          "dynamics_updates", "threshold", "save", "max_steps", "fit_explore", "reading_names"]),
        ("AlarmCommand", alarm_command, dict(command="true", wait=5.0), ["command", "env", "wait"]),
        ("fit_on_episodes", monitor.fit_on_episodes, dict(episodes=fit, action_space=discrete, dynamics_updates=20),
         ["episodes", "action_space", "detectors", "seed", "dynamics_updates"]),
        ("calibrate_on_episodes", monitor.calibrate_on_episodes, dict(detectors=fitted, episodes=calibration, far=0.1),
         ["detectors", "episodes", "far", "detector", "confidence", "consecutive", "window", "warmup",
          "reading_names"]),
        ("validate_on_episodes", monitor.validate_on_episodes, dict(threshold=saved, episodes=fresh),
         ["threshold", "episodes", "detectors"]),
        ("save_records", monitor.save_records, dict(path="records.npz", episodes=fresh), ["path", "episodes"]),
        ("load_records", monitor.load_records, dict(path=monitor.save_records(saved.parent / "fresh.npz", fresh)),
         ["path"]),
        ("watch_recorded", monitor.watch_recorded, dict(threshold=saved),
         ["fit_episodes", "calibration_episodes", "action_space", "far", "confidence", "detector", "sinks",
          "callbacks", "save", "threshold", "reading_names"]),
        ("ShiftAttributes", shifted_reset, dict(env=gymnasium.make("CartPole-v1"), changes={"length": 2.0}),
         ["changes", "onset_step", "env_id"]),
    ]


def answer(call, arguments: dict, seconds: int) -> tuple[str, str]:
    """The kind of the call's answer (see the module docstring) and, where it raised, what."""
    import torch

    from oodmon.errors import OodmonError

    try:
        with time_limit(seconds), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            call(**arguments)
        kind, said = "ok", ""
    except StillWorking:
        kind, said = "slow", ""
    except OodmonError:
        kind, said = "oodmon", ""
    except (TypeError, AttributeError) as error:
        kind, said = "python", f"{type(error).__name__}: {error}"
    except Exception as error:  # noqa: BLE001  (what this script looks for)
        kind, said = "finding", f"{type(error).__name__}: {error}"
    if not torch.is_grad_enabled():  # (a stop by the alarm inside a with-statement's entry can leave it so)
        torch.set_grad_enabled(True)
        return "leak", "torch's grad mode left off"
    return kind, said


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=int, default=4, help="stop a call still working after this long (default 4)")
    parser.add_argument("--all", action="store_true", help="print Python's own TypeErrors and AttributeErrors too")
    parser.add_argument("--only", help="the calls to try, by name, comma-separated (default: every one)")
    args = parser.parse_args()
    only = None if args.only is None else set(args.only.split(","))
    from oodmon.threads import limit_threads

    limit_threads()  # OODMON_TORCH_THREADS, as every oodmon command honours it
    limit_memory()  # /dev/zero read whole: a MemoryError, a finding, not the machine's memory
    counts: collections.Counter[str] = collections.Counter()
    with tempfile.TemporaryDirectory(prefix="oodmon-fuzz-api-") as folder:
        os.chdir(folder)
        os.mkdir("adir")
        for name, call, good, varied in cases():
            if only is not None and name not in only:
                continue
            for parameter in varied:
                for value in odd_values():
                    kind, said = answer(call, {**good, parameter: value}, args.seconds)
                    counts[kind] += 1
                    if kind in ("finding", "leak") or (kind == "python" and args.all):
                        print(f"{name}({parameter}={value!r:.40}): {said[:200]}")
    print(", ".join(f"{n} {kind}" for kind, n in counts.most_common()) + f" of {sum(counts.values())} calls")
    return 1 if counts["finding"] or counts["leak"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
