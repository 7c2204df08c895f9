"""``make demo``: the monitor at work, and a tour of the OOD environments.

:func:`run_demo` (``oodmon demo``, what ``make demo`` runs) calibrates a shipped CartPole agent's
threshold on held-out ID episodes, runs it under the monitor in the ID env and in a world whose
pole grows to 2 m at step 100, writes the logs to MCAP and Rerun files, and prints false alarms
and detection delays.

:func:`run_env_tour` (``oodmon envs tour``) shows what the environments change, without an
agent: a hand-written controller in some of the paper's variants, a shift mid-episode, and
Pong's corrupted frames.
"""

from __future__ import annotations

import shlex
from pathlib import Path

from rich.console import Console
from rich.table import Table

from oodmon.envs.grid import TASKS, paper_grid, parse_variant
from oodmon.seeds import DEMO
from oodmon.envs.preview import compare_physics, pong_preview, save_physics_plot, save_rgb

__all__ = ["run_demo", "run_env_tour"]

_PHYSICS_SPECS = [
    "cartpole:length=2.0",
    "cartpole:gravity=98.0",
    "cartpole:force_mag=1.0",
    "cartpole:masscart=10.0",
    "pendulum:g=50.0",
    "pendulum:l=5.0",
    "pendulum:m=5.0",
    "pendulum:max_torque=0.1",
]
_ONSET_SPEC, _ONSET_STEP = "cartpole:length=2.0", 100
_PONG_SPECS = ["pong:gaussian_noise@3", "pong:impulse_noise@3", "pong:motion_blur@3", "pong:pixelate@3"]


def run_env_tour(out_dir: str | Path = "runs/tour", console: Console | None = None) -> dict[str, float]:
    """Show what the environments change; write pictures to ``out_dir``; return mean returns by spec."""
    console = console or Console(soft_wrap=True)
    out = Path(out_dir)
    console.print(
        "[bold]oodmon envs tour[/bold]: the OOD environments doing real work with a hand-written "
        "reference controller (no agent, no monitor).\n"
    )
    table = Table(title="Reference controller, mean return over 5 seeds")
    table.add_column("variant")
    for column in ("ID return", "variant return", "change"):
        table.add_column(column, justify="right")
    returns: dict[str, float] = {}
    for spec in _PHYSICS_SPECS:
        comparison = compare_physics(parse_variant(spec))
        returns[spec] = comparison.shifted_return
        returns[comparison.variant.task] = comparison.id_return
        change = comparison.shifted_return - comparison.id_return
        table.add_row(spec, f"{comparison.id_return:.1f}", f"{comparison.shifted_return:.1f}", f"{change:+.1f}")
    console.print(table)

    onset = compare_physics(parse_variant(_ONSET_SPEC), onset_step=_ONSET_STEP)
    plot = save_physics_plot(onset, out / "cartpole_length2_onset100.png")
    lengths = [r.length for r in onset.shifted_rollouts]
    console.print(
        f"\nShift mid-episode: {_ONSET_SPEC} from step {_ONSET_STEP}: the pole stays up until the "
        f"onset and falls {min(lengths) - _ONSET_STEP}-{max(lengths) - _ONSET_STEP} steps after it "
        f"(episode lengths {lengths}). Trace: {plot}"
    )
    console.print("\nPong frames, clean beside corrupted (raw camera and the agent's 84x84 view):")
    for spec in _PONG_SPECS:
        path = save_rgb(pong_preview(parse_variant(spec)), out / f"{spec.replace(':', '_').replace('@', '_')}.png")
        console.print(f"  {spec:24s} {path}")
    size = sum(len(paper_grid(task)) for task in TASKS)
    console.print(f"\nNext: `oodmon envs` lists the {size} variants of the paper's grid.")
    return returns


DEMO_METHOD = "ensemble"
DEMO_SHIFT, DEMO_ONSET = "cartpole:length=2.0", 100
#: The detector the demo's alarm reads. On the demo's shift (a 2 m pole from step 100) measured:
#: ``dynamics`` alarms 1 step after the onset in all 5 episodes, ``combined`` (the best mean
#: per-step AUROC over CartPole's failing variants, docs/detectors.md's detector table, and `calibrate`'s
#: default) after 2-3 (both with m = 1; with m = 3: 3 and 3-5); neither raised a false alarm in the
#: 5 ID episodes. Every detector is logged.
DEMO_DETECTOR = "dynamics"


def run_demo(out_dir: str | Path = "runs/demo", console: Console | None = None, *, calibration_episodes: int = 45,
             episodes: int = 5, detector: str = DEMO_DETECTOR) -> dict[str, object]:
    """Calibrate, monitor ID and shifted CartPole episodes, log them, print a summary; return it.

    The alarm reads ``detector`` (the agent's shipped fitted detectors; ``spread`` needs none)."""
    from oodmon.agents import load
    from oodmon.envs import Variant
    from oodmon.monitor import McapSink, Monitor, RerunSink, calibrate_agent
    from oodmon.monitor.detectors import detectors_for

    console = console or Console(soft_wrap=True)
    out = Path(out_dir)
    try:
        agent = load("cartpole", DEMO_METHOD)
        detectors = detectors_for(agent)
        console.print(f"[bold]oodmon demo[/bold]: the shipped {agent.task}/{agent.method} agent "
                      f"(ID return {agent.metadata['id_return_mean']}) under the monitor, every step scored by "
                      f"{', '.join(detectors.names) if detectors else 'spread'}.")
        threshold = calibrate_agent(agent, calibration_episodes, far=0.05, detectors=detectors, detector=detector)
    except KeyboardInterrupt as interrupt:
        # (`oodmon demo` says that nothing was written yet; stopped as it loaded the agent, it said
        # "every finished episode is in the logs" until 2026-12-06)
        interrupt.nothing_written = True
        raise
    threshold.save(out / "threshold.json")
    console.print(f"1. Calibrated on {threshold.n_episodes} held-out ID episodes: alarm when the {detector} "
                  f"{threshold.rule_text} ({threshold.promise}). -> {out / 'threshold.json'}")
    runs, logs, failures = {}, {}, {}
    for name, variant, onset in (("id", Variant("cartpole"), 0), ("shifted", parse_variant(DEMO_SHIFT), DEMO_ONSET)):
        env = variant.make(onset_step=onset)
        files = {"McapSink": out / f"{name}.mcap", "RerunSink": out / f"{name}.rrd"}
        sinks = [McapSink(files["McapSink"], overwrite=True),  # the demo's own logs, made again each time
                 RerunSink(files["RerunSink"], overwrite=True)]
        with Monitor(agent, threshold, detectors=detectors, sinks=sinks) as monitor:
            runs[name] = [monitor.run_episode(env, seed=DEMO + e, variant=variant.spec) for e in range(episodes)]
        env.close()
        failed = failures[name] = monitor.sinks.failures  # after the sinks closed, as `oodmon run` reads them
        written = [str(path) for sink, path in files.items() if sink not in failed]
        logs[name] = " ".join(([f"-> {', '.join(written)}"] if written else []) + (
            [f"(not written whole: {', '.join(str(files[sink]) for sink in failed)}; see the warnings)"] if failed else []))
    false_alarms = sum(r.alarms > 0 for r in runs["id"])
    detected = [r for r in runs["shifted"] if r.delay is not None]
    early = sum(r.alarmed_early for r in runs["shifted"])
    delays = [r.delay for r in detected]
    falls = ", ".join(str(r.length - r.onset) if r.terminated else "never" for r in runs["shifted"])  # kept up to 500
    console.print(f"2. ID: {false_alarms} of {episodes} episodes raised a (false) alarm; returns "
                  f"{[round(r.total_return) for r in runs['id']]}. {logs['id']}")
    console.print(f"3. {DEMO_SHIFT} from step {DEMO_ONSET}: {len(detected)} of {episodes} shifts detected, delays "
                  f"{delays} steps (the pole falls [{falls}] steps after the onset); {early} alarm(s) before the onset. "
                  f"{logs['shifted']}")
    if not failures["shifted"]:  # its logs written whole
        rrd, logs, plots = (shlex.quote(str(path)) for path in (out / "shifted.rrd", out, out / "plots"))
        console.print(f"Open the logs with `rerun {rrd}` or Foxglove; every detector's AUROC and plots: "
                      f"`oodmon replay {logs} --plots {plots}`; `oodmon run --help` for your own runs.")
    return {"false_alarms": false_alarms, "detected": len(detected), "delays": delays, "early": early}
