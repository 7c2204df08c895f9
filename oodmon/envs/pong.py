"""OOD-Pong: ALE Pong seen through a degraded camera.

The corruption is applied to each raw 210x160x3 RGB frame that the agent observes, before the
standard Atari preprocessing, which this env does itself: frame skip 4, the last two frames of
the skip turned grey and max-pooled, resized to 84x84 with area interpolation, and a stack of the
last 4 such frames, channel first. It cannot be done with ``gymnasium.wrappers.AtariPreprocessing``:
that wrapper reads the screen straight from the emulator, so a corrupting wrapper beneath it
changes nothing the agent sees.

Every episode starts with 1..30 no-op steps (drawn from the env's generator), as in the usual
Atari protocol, so that seeded episodes differ. Actions are deterministic
(``repeat_action_probability=0``) unless asked otherwise. Rewards are the game's score changes,
not clipped: clipping is a training choice.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from oodmon.envs.checks import check_onset_step, episode_onset
from oodmon.envs.corruptions import Corruption, make_corruption
from oodmon.errors import InvalidParameterError

__all__ = ["FRAME_SKIP", "FRAME_STACK", "NOOP_MAX", "SCREEN_SIZE", "CorruptedPong", "to_agent_view"]

FRAME_SKIP = 4
FRAME_STACK = 4
SCREEN_SIZE = 84
NOOP_MAX = 30
_MAX_FRAMES = 108_000  # ALE v5's episode limit: 30 minutes of play at 60 frames/s


def to_agent_view(frames: list[np.ndarray]) -> np.ndarray:
    """Turn the last (one or two) RGB frames of a frame skip into one 84x84 grey agent frame.

    Example:
        >>> to_agent_view([np.zeros((210, 160, 3), np.uint8)]).shape
        (84, 84)
    """
    import cv2  # imported where used: 15-20 ms of every command's start (replay, check) at the top

    grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    pooled = np.maximum(grey[0], grey[1]) if len(grey) == 2 else grey[0]
    return cv2.resize(pooled, (SCREEN_SIZE, SCREEN_SIZE), interpolation=cv2.INTER_AREA)


class CorruptedPong(gymnasium.Env):
    """ALE Pong with a corrupted camera; registered as ``oodmon/Pong-v5``.

    Args:
        corruption: ``None`` (the ID env), a corruption name (``gaussian_noise``,
            ``impulse_noise``, ``motion_blur``, ``pixelate``; ``frozen_region``, not the paper's,
            with its parameters) or a :class:`Corruption`.
        severity: 1..5, the paper's parameters for the named corruption.
        onset_step: index of the first ``step()`` of each episode whose frames are corrupted
            (0: every frame, including the one ``reset`` returns).
        repeat_action_probability: ALE's sticky-action probability, 0 by default.
        render_mode: ``"rgb_array"`` renders the last raw frame the camera delivered.
        **params: the corruption's own parameters instead of a severity (``sigma=0.2``).

    ``info["shifted"]`` says whether the observation's newest frame is corrupted (never, without a
    corruption).
    ``last_clean_frame`` and ``last_observed_frame`` hold the newest raw RGB frame before and
    after the corruption.

    Raises:
        UnknownParameterError: an unknown corruption or a parameter it does not take.
        InvalidParameterError: a severity outside 1..5, parameters without a corruption, or a
            parameter value outside its range.

    Example:
        >>> import gymnasium, oodmon
        >>> env = gymnasium.make("oodmon/Pong-v5", corruption="pixelate", severity=3)
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape, obs.dtype.name, info["shifted"]
        ((4, 84, 84), 'uint8', True)
    """

    #: Its observation is a stack of its last frames along its first axis, oldest first, the first
    #: frame of an episode filling the stack at the reset: what the newest frames a monitor logs
    #: rebuild, step by step (:func:`oodmon.monitor.detectors.fitting.stacks_from_frames`; an env
    #: of yours stacking so may say it too).
    STACK_FILLED_BY_FIRST_FRAME = True

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}
    ENV_ID = "oodmon/Pong-v5"

    def __init__(
        self,
        corruption: str | Corruption | None = None,
        severity: int | None = None,
        *,
        onset_step: int = 0,
        repeat_action_probability: float = 0.0,
        render_mode: str | None = None,
        **params: float,
    ) -> None:
        import ale_py  # heavy; only Pong needs it
        from ale_py.env import AtariEnv

        ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Error)  # no banner on every CLI call
        self.corruption = self._build_corruption(corruption, severity, params)
        #: The corruption as named when made (a monitor records the variant from it); None for a
        #: corruption object passed in, which has no name.
        self.corruption_named = (corruption, severity, dict(params)) if not isinstance(corruption, Corruption) else None
        self.onset_step = self._configured_onset = check_onset_step(self.ENV_ID, onset_step)
        if render_mode not in (None, "rgb_array"):
            raise InvalidParameterError(
                f"{self.ENV_ID}: render_mode={render_mode!r} is not allowed; use None or 'rgb_array'"
            )
        self.render_mode = render_mode
        self._atari = AtariEnv(
            game="pong",
            obs_type="rgb",
            frameskip=1,
            repeat_action_probability=repeat_action_probability,
            max_num_frames_per_episode=_MAX_FRAMES,
        )
        self._sticky = repeat_action_probability > 0
        self.action_space = self._atari.action_space
        self.observation_space = spaces.Box(
            0, 255, (FRAME_STACK, SCREEN_SIZE, SCREEN_SIZE), dtype=np.uint8
        )
        self._stack = np.zeros(self.observation_space.shape, np.uint8)
        self._steps = 0
        self.last_clean_frame: np.ndarray | None = None
        self.last_observed_frame: np.ndarray | None = None

    @classmethod
    def _build_corruption(
        cls, corruption: str | Corruption | None, severity: int | None, params: dict[str, float]
    ) -> Corruption | None:
        if isinstance(corruption, Corruption):
            if severity is not None or params:
                raise InvalidParameterError(
                    f"{cls.ENV_ID}: a Corruption object carries its own parameters; "
                    f"drop severity={severity!r} and {sorted(params)}"
                )
            return corruption
        if corruption is None:
            if severity is not None or params:
                raise InvalidParameterError(
                    f"{cls.ENV_ID}: severity and corruption parameters need a corruption; "
                    "pass corruption='gaussian_noise', 'impulse_noise', 'motion_blur' or 'pixelate'"
                )
            return None
        return make_corruption(corruption, severity, **params)

    def _observe(self, frames: list[np.ndarray], shifted: bool) -> np.ndarray:
        """Corrupt (if shifted) the observed raw frames, preprocess them, push onto the stack."""
        self.last_clean_frame = frames[-1]
        if shifted and self.corruption is not None:
            frames = [self.corruption(f, self.np_random) for f in frames]
        self.last_observed_frame = frames[-1]
        self._stack[:-1] = self._stack[1:]
        self._stack[-1] = to_agent_view(frames)
        return self._stack.copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.onset_step, _ = episode_onset(self.ENV_ID, self._configured_onset, options)
        super().reset(seed=seed)
        if self.corruption is not None:
            self.corruption.begin_episode()  # (a frozen region holds the new episode's own frame)
        # The emulator is seeded from our generator, so one seed fixes the whole episode. Its own
        # generator draws only sticky actions: without them a seed changes nothing in the game, and
        # applying one reloads the ROM (90 ms a reset), so it is drawn (the no-ops' draws stay the
        # same) and applied only for sticky actions.
        atari_seed = None if seed is None else int(self.np_random.integers(2**31))
        frame, info = self._atari.reset(seed=atari_seed if self._sticky else None)
        frames = [frame]
        for _ in range(int(self.np_random.integers(1, NOOP_MAX + 1))):
            frame, _, terminated, truncated, info = self._atari.step(0)
            frames = [frames[-1], frame]
            if terminated or truncated:
                frame, info = self._atari.reset()
                frames = [frame]
        self._steps = 0
        shifted = self.onset_step == 0 and self.corruption is not None
        self._observe(frames, shifted)
        self._stack[:-1] = self._stack[-1]
        return self._stack.copy(), self._info(info, shifted)

    def step(self, action):
        shifted = self._steps >= self.onset_step and self.corruption is not None
        self._steps += 1
        reward = 0.0
        frames: list[np.ndarray] = []
        for _ in range(FRAME_SKIP):
            frame, r, terminated, truncated, info = self._atari.step(action)
            reward += r
            frames = [frames[-1], frame] if frames else [frame]
            if terminated or truncated:
                break
        obs = self._observe(frames, shifted)
        return obs, reward, terminated, truncated, self._info(info, shifted)

    @staticmethod
    def _info(atari_info: dict[str, Any], shifted: bool) -> dict[str, Any]:
        return {
            "shifted": shifted,
            "lives": atari_info["lives"],
            "episode_frame_number": atari_info["episode_frame_number"],
        }

    def render(self) -> np.ndarray | None:
        if self.render_mode == "rgb_array":
            return self.last_observed_frame
        return None

    def close(self) -> None:
        self._atari.close()
