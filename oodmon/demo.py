"""``make demo``: the OOD environments doing real work.

The monitor is not built yet (see the monitor issue); until it is, the demo shows what the
environments change: a competent hand-written controller that solves the default CartPole and
Pendulum fails in some of the paper's variants, a shift that begins mid-episode takes effect at
its onset, and Pong's corruptions degrade the frames the agent would see.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table

from oodmon.envs.grid import TASKS, paper_grid, parse_variant
from oodmon.envs.preview import compare_physics, pong_preview, save_physics_plot, save_rgb

__all__ = ["run_demo"]

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


def run_demo(out_dir: str | Path = "runs/demo", console: Console | None = None) -> dict[str, float]:
    """Run the demo, write its pictures to ``out_dir`` and return the mean returns by spec."""
    console = console or Console(soft_wrap=True)
    out = Path(out_dir)
    console.print(
        "[bold]oodmon demo[/bold]: the monitor is not built yet, so this shows the OOD "
        "environments doing real work with a hand-written reference controller.\n"
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
