"""OOD-CartPole and OOD-Pendulum: the physics really change, from the onset on, and bad input is refused."""

from __future__ import annotations

import math
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import oodmon  # noqa: F401  (registers the envs)
from oodmon.envs import CARTPOLE_DEFAULTS, PENDULUM_DEFAULTS, paper_grid
from oodmon.envs.reference import cartpole_controller, pendulum_controller, rollout
from oodmon.errors import InvalidParameterError, UnknownParameterError

PHYSICS_VARIANTS = paper_grid("cartpole") + paper_grid("pendulum")


def _checker_warnings(env: gymnasium.Env) -> set[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    return {str(w.message) for w in caught}


# gymnasium's own CartPole-v1 and Pendulum-v1 draw checker warnings (infinite bounds, an
# unnormalised action space); a variant may draw those and no other.
GYMNASIUM_WARNINGS = {task: _checker_warnings(gymnasium.make(env_id)) for task, env_id in
                      [("cartpole", "CartPole-v1"), ("pendulum", "Pendulum-v1")]}


@pytest.mark.parametrize("variant", PHYSICS_VARIANTS, ids=str)
def test_every_physics_variant_passes_the_env_checker(variant):
    env = variant.make()
    assert _checker_warnings(env) <= GYMNASIUM_WARNINGS[variant.task]
    default = gymnasium.make(variant.env_id)
    assert env.observation_space == default.observation_space
    assert env.action_space == default.action_space


def _steps_until_fall(**physics) -> int:
    """Alternate pushes from one tilted start state until the episode ends."""
    env = gymnasium.make("oodmon/CartPole-v1", **physics)
    env.reset(seed=0)
    env.unwrapped.state = np.array([0.0, 0.0, 0.05, 0.0])
    for step in range(500):
        _, _, terminated, truncated, _ = env.step(step % 2)  # left, right, left, ...
        if terminated or truncated:
            return step + 1
    return 500


# The direction in which each parameter moves the time the pole stays up, from the equations of
# motion: a longer pole or a heavier cart falls more slowly; more gravity, a heavier pole or a
# stronger push makes it fall sooner.
CARTPOLE_EFFECTS = {"length": +1, "masscart": +1, "gravity": -1, "masspole": -1, "force_mag": -1}


@pytest.mark.parametrize("name", list(CARTPOLE_EFFECTS))
def test_each_cartpole_parameter_changes_how_long_the_pole_stays_up(name):
    values = sorted(v.params[0][1] for v in paper_grid("cartpole") if v.params[0][0] == name)
    steps = [_steps_until_fall(**{name: value}) for value in values]
    default = _steps_until_fall()
    direction = CARTPOLE_EFFECTS[name]
    assert all(direction * (b - a) >= 0 for a, b in zip(steps, steps[1:])), steps
    # The grid's extremes land on either side of the default.
    assert direction * (steps[0] - default) < 0 < direction * (steps[-1] - default), (steps, default)


def test_cartpole_named_examples():
    assert _steps_until_fall() == 21
    assert _steps_until_fall(length=2.0) > 2 * _steps_until_fall()
    assert _steps_until_fall(gravity=98.0) < _steps_until_fall() / 2


@pytest.mark.parametrize(
    "physics", [{}, {"masspole": 1.0}, {"masscart": 3.0, "length": 2.0}, {"gravity": 49.0, "force_mag": 2.5}, {"tau": 0.04}],
    ids=str)
def test_cartpole_step_follows_the_equations_with_derived_quantities_recomputed(physics):
    p = CARTPOLE_DEFAULTS | physics
    env = gymnasium.make("oodmon/CartPole-v1", **physics)
    env.reset(seed=0)
    x, x_dot, theta, theta_dot = state = np.array([0.1, -0.2, 0.05, 0.3])
    env.unwrapped.state = state.copy()
    obs, *_ = env.step(1)

    total_mass = p["masspole"] + p["masscart"]
    polemass_length = p["masspole"] * p["length"]
    temp = (p["force_mag"] + polemass_length * theta_dot**2 * math.sin(theta)) / total_mass
    theta_acc = (p["gravity"] * math.sin(theta) - math.cos(theta) * temp) / (
        p["length"] * (4 / 3 - p["masspole"] * math.cos(theta) ** 2 / total_mass)
    )
    x_acc = temp - polemass_length * theta_acc * math.cos(theta) / total_mass
    tau = p["tau"]
    expected = [x + tau * x_dot, x_dot + tau * x_acc, theta + tau * theta_dot, theta_dot + tau * theta_acc]
    np.testing.assert_allclose(obs, expected, rtol=1e-6)


@pytest.mark.parametrize(
    "physics, torque",
    [({}, 1.5), ({"g": 50.0}, 1.5), ({"m": 5.0}, -1.0), ({"l": 0.1}, 1.0), ({"max_torque": 0.1}, 2.0), ({"max_speed": 0.4}, 2.0),
     ({"dt": 0.1}, 1.5)],
    ids=str,
)
def test_pendulum_step_follows_the_equations_with_the_new_limits(physics, torque):
    p = PENDULUM_DEFAULTS | physics
    env = gymnasium.make("oodmon/Pendulum-v1", **physics)
    env.reset(seed=0)
    theta, theta_dot = 0.7, 0.3
    env.unwrapped.state = np.array([theta, theta_dot])
    obs, *_ = env.step(np.array([torque], np.float32))

    u = min(max(torque, -p["max_torque"]), p["max_torque"])
    new_dot = theta_dot + (3 * p["g"] / (2 * p["l"]) * math.sin(theta) + 3 / (p["m"] * p["l"] ** 2) * u) * p["dt"]
    new_dot = min(max(new_dot, -p["max_speed"]), p["max_speed"])
    new_theta = theta + new_dot * p["dt"]
    np.testing.assert_allclose(obs, [math.cos(new_theta), math.sin(new_theta), new_dot], rtol=1e-5)


def test_pendulum_keeps_the_default_spaces():
    env = gymnasium.make("oodmon/Pendulum-v1", max_speed=160.0, max_torque=40.0)
    assert env.action_space.high.tolist() == [2.0]
    assert env.observation_space.high.tolist() == [1.0, 1.0, 8.0]


@pytest.mark.parametrize(
    "env_id, physics, controller",
    [("oodmon/CartPole-v1", {"length": 2.0}, cartpole_controller), ("oodmon/Pendulum-v1", {"g": 50.0}, pendulum_controller)],
    ids=["cartpole", "pendulum"],
)
def test_shift_begins_at_the_onset_step(env_id, physics, controller):
    onset = 60
    clean = rollout(gymnasium.make(env_id), controller, seed=3)
    shifted = rollout(gymnasium.make(env_id, **physics, onset_step=onset), controller, seed=3)
    # Observation k comes from step k-1 (0 is reset's): ID up to and including step onset-1.
    assert not shifted.shifted[: onset + 1].any() and shifted.shifted[onset + 1 :].all()
    np.testing.assert_array_equal(shifted.observations[: onset + 1], clean.observations[: onset + 1])
    assert not np.allclose(shifted.observations[onset + 1], clean.observations[onset + 1])


def test_onset_zero_shifts_the_whole_episode_and_reset_restores_the_defaults():
    env = gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=3)
    _, info = env.reset(seed=0)
    assert info["shifted"] is False and env.unwrapped.length == 0.5
    for _ in range(3):
        *_, info = env.step(0)
    assert info["shifted"] is False and env.unwrapped.length == 0.5
    *_, info = env.step(1)  # step index 3: the first under the shifted physics
    assert info["shifted"] is True and env.unwrapped.length == 2.0
    _, info = env.reset()
    assert info["shifted"] is False and env.unwrapped.length == 0.5 and env.unwrapped.polemass_length == 0.05
    _, info = gymnasium.make("oodmon/CartPole-v1", length=2.0).reset(seed=0)
    assert info["shifted"] is True


def test_reference_controllers_solve_the_default_envs():
    assert rollout(gymnasium.make("oodmon/CartPole-v1"), cartpole_controller, seed=0).total_return == 500
    returns = [rollout(gymnasium.make("oodmon/Pendulum-v1"), pendulum_controller, seed=s).total_return for s in range(5)]
    assert np.mean(returns) > -200


@pytest.mark.parametrize(
    "env_id, kwargs, words",
    [
        ("oodmon/CartPole-v1", {"lenght": 2.0}, ["has no parameter 'lenght'", "length"]),
        ("oodmon/Pendulum-v1", {"mass": 2.0}, ["has no parameter 'mass'", "g, m, l, max_speed, max_torque, dt"]),
    ],
)
def test_unknown_parameter_names_it_and_what_is_allowed(env_id, kwargs, words):
    with pytest.raises(UnknownParameterError) as error:
        gymnasium.make(env_id, **kwargs)
    for word in words:
        assert word in str(error.value)


@pytest.mark.parametrize(
    "env_id, name, value",
    [
        ("oodmon/CartPole-v1", "masscart", 0.0),
        ("oodmon/CartPole-v1", "masspole", -0.1),
        ("oodmon/CartPole-v1", "length", -1.0),
        ("oodmon/CartPole-v1", "gravity", 0.0),
        ("oodmon/CartPole-v1", "force_mag", -10.0),
        ("oodmon/CartPole-v1", "length", float("nan")),
        ("oodmon/Pendulum-v1", "m", 0.0),
        ("oodmon/Pendulum-v1", "l", -1.0),
        ("oodmon/Pendulum-v1", "g", -9.8),
        ("oodmon/Pendulum-v1", "max_torque", 0.0),
    ],
)
def test_non_positive_physics_is_refused_with_the_value_and_the_rule(env_id, name, value):
    with pytest.raises(InvalidParameterError) as error:
        gymnasium.make(env_id, **{name: value})
    message = str(error.value)
    assert f"{env_id}: {name}={value!r} is not allowed" in message
    assert "finite number > 0" in message and "the default is" in message


def test_non_numeric_physics_and_bad_onset_are_refused():
    with pytest.raises(InvalidParameterError, match=r"length='long' is not allowed; length must be a number > 0"):
        gymnasium.make("oodmon/CartPole-v1", length="long")
    with pytest.raises(InvalidParameterError, match=r"onset_step=-1 is not allowed; onset_step must be an integer >= 0"):
        gymnasium.make("oodmon/CartPole-v1", onset_step=-1)
    with pytest.raises(InvalidParameterError, match=r"onset_step=2.5 is not allowed"):
        gymnasium.make("oodmon/Pendulum-v1", onset_step=2.5)


@pytest.mark.parametrize("env_id", ["oodmon/CartPole-v1", "oodmon/Pendulum-v1", "oodmon/Pong-v5"])
def test_the_id_env_never_reports_a_shift(env_id):
    env = gymnasium.make(env_id)
    _, info = env.reset(seed=0)
    flags = [info["shifted"]]
    for _ in range(5):
        *_, info = env.step(env.action_space.sample())
        flags.append(info["shifted"])
    assert flags == [False] * 6


def test_reset_option_sets_the_onset_of_that_episode_only():
    """The monitor's benchmark draws an onset per episode: reset(options={"onset_step": n})."""
    env = gymnasium.make("oodmon/CartPole-v1", length=2.0, onset_step=100)
    flags = []
    for options in ({"onset_step": 2}, None, {"onset_step": 0}):
        _, info = env.reset(seed=0, options=options)
        shifted = [info["shifted"]]
        for _ in range(4):
            *_, info = env.step(0)
            shifted.append(info["shifted"])
        flags.append(shifted)
    assert flags == [[False, False, False, True, True], [False] * 5, [True] * 5]
    # Other options still reach gymnasium's CartPole (its initial-state bounds).
    obs, _ = env.reset(seed=0, options={"onset_step": 1, "low": -0.01, "high": 0.01})
    assert np.abs(obs).max() <= 0.01
    with pytest.raises(InvalidParameterError, match="onset_step=-1"):
        env.reset(options={"onset_step": -1})


def test_the_preview_breaks_a_spinning_pendulums_angle_where_it_wraps_and_keeps_every_step():
    """`oodmon envs show pendulum:m=3.0` drew a vertical stroke across its plot at every turn of the
    heavy pendulum (+170 to -170 degrees in one step); the trace now breaks there."""
    from oodmon.envs.preview import angle_trace

    env = gymnasium.make("oodmon/Pendulum-v1", m=3.0, onset_step=10)
    run = rollout(env, pendulum_controller, seed=0)
    angles = np.degrees(np.arctan2(run.observations[:, 1], run.observations[:, 0]))
    wraps = int(np.sum(np.abs(np.diff(angles)) > 180.0))
    assert wraps >= 2  # the heavy pendulum turns over and over (5 times in this episode)
    steps, degrees = angle_trace("pendulum", run.observations)
    assert np.isnan(degrees).sum() == np.isnan(steps).sum() == wraps
    np.testing.assert_array_equal(degrees[~np.isnan(degrees)], angles)  # every step's angle, in order
    np.testing.assert_array_equal(steps[~np.isnan(steps)], np.arange(len(angles)))
    pieces = np.split(degrees, np.flatnonzero(np.isnan(degrees)))  # each piece a line without a stroke
    assert all(np.all(np.abs(np.diff(piece[~np.isnan(piece)])) <= 180.0) for piece in pieces)
    cartpole = rollout(gymnasium.make("oodmon/CartPole-v1"), cartpole_controller, seed=0).observations
    steps, degrees = angle_trace("cartpole", cartpole)  # a balanced pole never wraps
    assert not np.isnan(degrees).any()
    np.testing.assert_allclose(degrees, np.degrees(cartpole[:, 2]))
