"""Pictures of what a variant changes: Pong frames side by side, physics traces of an episode.

``oodmon envs show SPEC --out FILE.png`` writes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from oodmon.envs.grid import Variant
from oodmon.envs.reference import REFERENCE_CONTROLLERS, Rollout, rollout
from oodmon.outputs import save_figure, write_whole

__all__ = ["PhysicsComparison", "angle_trace", "compare_physics", "draw_state", "outline_region", "pong_preview",
           "save_physics_plot", "save_probe_plot", "save_rgb"]

_LABEL_HEIGHT = 22


#: The picture :func:`draw_state` draws: height, width.
STATE_PICTURE = (120, 240)


def draw_state(task: str, obs: np.ndarray) -> np.ndarray:
    """A picture (RGB, :data:`STATE_PICTURE`) of a CartPole or Pendulum state from its observation:
    what the env's own ``render()`` shows, drawn with OpenCV (no pygame, no display) and from the
    observation the agent saw, so that a monitor's log can show it beside the scores.

    CartPole: the cart at ``x`` on its track (+-2.4), the pole at ``theta``; Pendulum: the rod at
    the angle of ``(cos, sin)`` (upright is up) and its angular velocity as an arc.

    Raises:
        ValueError: another task (Pong's frames are pictures already).

    Example:
        >>> draw_state("cartpole", np.array([0.0, 0.0, 0.1, 0.0])).shape
        (120, 240, 3)
    """
    height, width = STATE_PICTURE
    image = np.full((height, width, 3), 255, np.uint8)
    if task == "cartpole":
        x, theta = float(obs[0]), float(obs[2])
        track = height - 30
        cv2.line(image, (0, track), (width, track), (0, 0, 0), 1)
        centre = int(width / 2 + x / 2.4 * (width / 2 - 20))
        cv2.rectangle(image, (centre - 16, track - 10), (centre + 16, track + 4), (40, 40, 40), -1)
        length = 70
        tip = (int(centre + length * math.sin(theta)), int(track - 10 - length * math.cos(theta)))
        cv2.line(image, (centre, track - 10), tip, (202, 152, 101), 6)
        cv2.circle(image, (centre, track - 10), 3, (129, 132, 203), -1)
    elif task == "pendulum":
        cos, sin, speed = float(obs[0]), float(obs[1]), float(obs[2])
        theta = math.atan2(sin, cos)  # 0: upright
        centre, length = (width // 2, height // 2), height // 2 - 12
        tip = (int(centre[0] + length * math.sin(theta)), int(centre[1] - length * math.cos(theta)))
        cv2.line(image, centre, tip, (204, 77, 77), 8)
        cv2.circle(image, centre, 4, (0, 0, 0), -1)
        sweep = int(np.clip(speed / 8.0, -1.0, 1.0) * 90)
        if sweep:
            start = math.degrees(theta) - 90
            cv2.ellipse(image, centre, (length + 6, length + 6), 0, start, start + sweep, (120, 120, 120), 2)
    else:
        raise ValueError(f"draw_state draws CartPole and Pendulum states, not {task!r}")
    return image


def pong_preview(variant: Variant, *, seed: int = 0, steps: int = 60) -> np.ndarray:
    """An RGB image of Pong's clean and corrupted frame, raw and as the agent sees them.

    The ID env and the variant run side by side from the same seed with the same random
    actions, so the two frames show the same moment of the game. Top row: the raw 210x160
    frames (scaled 2x); bottom row: the newest 84x84 frame of the agent's observation.

    Example:
        >>> from oodmon.envs import parse_variant
        >>> pong_preview(parse_variant("pong:pixelate@3"), steps=5).shape
        (784, 640, 3)
    """
    clean_env = Variant("pong").make()
    shifted_env = variant.make()
    actions = np.random.default_rng(seed)
    try:
        clean_obs, _ = clean_env.reset(seed=seed)
        shifted_obs, _ = shifted_env.reset(seed=seed)
        for _ in range(steps):
            action = int(actions.integers(clean_env.action_space.n))
            clean_obs, *_ = clean_env.step(action)
            shifted_obs, *_ = shifted_env.step(action)
        raw = [clean_env.unwrapped.last_observed_frame, shifted_env.unwrapped.last_observed_frame]
    finally:
        clean_env.close()
        shifted_env.close()
    name = variant.spec
    if variant.corruption == "frozen_region":  # one frame cannot show a freeze: show where it is
        raw[1] = outline_region(raw[1], **dict(variant.params))
        name = "pong:frozen_region, outlined"  # its parameters would not fit the label
    top = [_labelled(_scale(f, 2), title) for f, title in zip(raw, ["clean camera", name])]
    width = top[0].shape[1]
    bottom = [
        _labelled(_scale(cv2.cvtColor(obs[-1], cv2.COLOR_GRAY2RGB), width / obs.shape[-1]), title)
        for obs, title in zip([clean_obs, shifted_obs], ["agent's view, clean", "agent's view, corrupted"])
    ]
    return np.vstack([np.hstack(top), np.hstack(bottom)])


#: The colour :func:`outline_region` draws (RGB): a yellow that Pong's frames do not hold.
OUTLINE = (255, 230, 0)


def outline_region(frame: np.ndarray, *, top: float, left: float, height: float, width: float) -> np.ndarray:
    """A copy of an RGB frame with the rectangle of rows ``top`` .. ``top + height - 1`` and columns
    ``left`` .. ``left + width - 1`` outlined one pixel wide in :data:`OUTLINE`, on its border rows and
    columns: where ``pong:frozen_region`` holds the picture, which a single frame cannot show."""
    out = frame.copy()
    top, left, bottom, right = int(top), int(left), int(top + height) - 1, int(left + width) - 1
    cv2.rectangle(out, (left, top), (right, bottom), OUTLINE, 1)
    return out


def _scale(image: np.ndarray, factor: float) -> np.ndarray:
    height, width = image.shape[:2]
    size = (round(width * factor), round(height * factor))
    return cv2.resize(image, size, interpolation=cv2.INTER_NEAREST)


def _labelled(image: np.ndarray, text: str) -> np.ndarray:
    strip = np.full((_LABEL_HEIGHT, image.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([strip, image])


def save_rgb(image: np.ndarray, path: str | Path) -> Path:
    """Write an RGB uint8 image in the format of ``path``'s suffix (PNG without one), creating the
    folder, whole or not at all (:func:`~oodmon.outputs.write_whole`); return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    encoded, data = cv2.imencode(path.suffix or ".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not encoded:
        raise OSError(f"could not write an image to {path}")
    write_whole(path, lambda part: part.write_bytes(data.tobytes()))
    return path


@dataclass(frozen=True)
class PhysicsComparison:
    """Episodes of the reference controller in the ID env and in a variant, seed by seed."""

    variant: Variant
    onset_step: int
    id_rollouts: list[Rollout]
    shifted_rollouts: list[Rollout]

    @property
    def id_return(self) -> float:
        """Mean return over the ID episodes."""
        return float(np.mean([r.total_return for r in self.id_rollouts]))

    @property
    def shifted_return(self) -> float:
        """Mean return over the variant's episodes."""
        return float(np.mean([r.total_return for r in self.shifted_rollouts]))


def compare_physics(variant: Variant, *, seeds: range = range(5), onset_step: int = 0) -> PhysicsComparison:
    """Run the task's reference controller in the ID env and in ``variant`` from the same seeds.

    Example:
        >>> from oodmon.envs import parse_variant
        >>> c = compare_physics(parse_variant("cartpole:length=2.0"), seeds=range(2))
        >>> c.id_return, c.shifted_return < 100
        (500.0, True)
    """
    controller = REFERENCE_CONTROLLERS[variant.task]
    runs = []
    for v, onset in ((Variant(variant.task), 0), (variant, onset_step)):
        env = v.make(onset_step=onset)
        runs.append([rollout(env, controller, seed) for seed in seeds])
        env.close()
    return PhysicsComparison(variant, onset_step, runs[0], runs[1])


def _angle(task: str, observations: np.ndarray) -> np.ndarray:
    """The pole's angle in degrees from upright."""
    if task == "cartpole":
        return np.degrees(observations[:, 2])
    return np.degrees(np.arctan2(observations[:, 1], observations[:, 0]))


def angle_trace(task: str, observations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steps and the pole's angle in degrees from upright, to plot: where a swinging pendulum's angle
    wraps from +180 to -180 a NaN sits between the two steps, so that the line breaks there instead
    of drawing a vertical stroke across the plot (every step's angle is kept)."""
    degrees = _angle(task, observations)
    steps = np.arange(len(degrees), dtype=float)
    wraps = np.flatnonzero(np.abs(np.diff(degrees)) > 180.0) + 1
    return np.insert(steps, wraps, np.nan), np.insert(degrees, wraps, np.nan)


def save_physics_plot(comparison: PhysicsComparison, path: str | Path) -> Path:
    """Plot the pole's angle over the first episode, ID beside the variant, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    task = comparison.variant.task
    fig, ax = plt.subplots(figsize=(8, 3.5), dpi=110)
    for runs, label, colour in (
        (comparison.id_rollouts, f"{task} (ID)", "tab:blue"),
        (comparison.shifted_rollouts, comparison.variant.spec, "tab:red"),
    ):
        ax.plot(*angle_trace(task, runs[0].observations), color=colour,
                label=f"{label}: return {runs[0].total_return:.0f}")
    if comparison.onset_step:
        ax.axvline(comparison.onset_step, color="grey", linestyle="--", label="onset")
    if task == "cartpole":
        limit = math.degrees(12 * 2 * math.pi / 360)
        for sign in (-1, 1):
            ax.axhline(sign * limit, color="black", linewidth=0.5)
    ax.set_xlabel("step")
    ax.set_ylabel("pole angle from upright (deg)")
    ax.set_title(f"reference controller, first episode: {comparison.variant.spec}")
    ax.legend(loc="best", fontsize=8)
    return save_figure(fig, path)


def save_probe_plot(probe, path: str | Path) -> Path:
    """Plot a :class:`~oodmon.envs.probe.ShiftProbe` as a PNG: the largest difference between the
    shifted env's readings and its own at each step, and below it (an observation of at most 8
    readings) each reading of both episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    readings = [] if probe.own is None or probe.own.shape[1] > 8 else range(probe.own.shape[1])
    fig, axes = plt.subplots(1 + len(readings), 1, figsize=(8, 2.2 + 1.3 * len(readings)), dpi=110, sharex=True,
                             squeeze=False)
    axes = axes[:, 0]
    steps = np.arange(len(probe.per_step))
    axes[0].plot(steps, probe.per_step, color="tab:red")
    axes[0].set_yscale("symlog", linthresh=1e-6)
    axes[0].set_ylim(0, max(1e-5, float(probe.per_step.max(initial=0.0)) * 2))
    axes[0].set_ylabel("largest |difference|", fontsize=8)
    what = (f"differs from step {probe.first_difference}" if probe.changed
            else "nothing differed: the shift changed nothing here")
    acting = "same random actions" if probe.actions == "random" else "the policy acting in each"
    axes[0].set_title(f"{probe.shift.spec}\nagainst the env's own (same seed {probe.seed}, {acting}): {what}", fontsize=9)
    for ax, i in zip(axes[1:], readings):
        ax.plot(probe.own[:, i], color="tab:blue", label="own", linewidth=1.2)
        ax.plot(probe.shifted[:, i], color="tab:red", label="shifted", linewidth=1.0, linestyle="--")
        ax.set_ylabel(f"reading {i}", fontsize=8)
    if readings:
        axes[1].legend(loc="best", fontsize=7)
    for ax in axes:
        if probe.onset:
            ax.axvline(probe.onset, color="grey", linestyle=":", linewidth=1)
        ax.tick_params(labelsize=7)
    axes[-1].set_xlabel("step (0: the observation reset returned; dotted: the onset)")
    return save_figure(fig, path)
