"""Whether a shift of your own env changes anything: oodmon.envs.probe and `oodmon envs show`."""

from __future__ import annotations

import re

import gymnasium
import numpy as np
import pytest

from oodmon.cli import main
from oodmon.envs import parse_env_shift
from oodmon.envs.probe import probe_shift
from oodmon.errors import InvalidParameterError


class _ResetOnlyGain(gymnasium.Env):
    """A point pushed left or right; its ``gain`` is read at reset only (as LunarLander reads its
    gravity when it builds its world), and ``drag`` at every step."""

    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float64)
    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self) -> None:
        self.gain, self.drag = 1.0, 0.1

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state, self.push = self.np_random.normal(size=2), self.gain
        return self.state.copy(), {}

    def step(self, action):
        self.state = self.state * (1 - self.drag) + (self.push if action else -self.push)
        return self.state.copy(), 1.0, False, False, {}


if "ResetOnlyGainForTests-v0" not in gymnasium.registry:
    gymnasium.register("ResetOnlyGainForTests-v0", entry_point=_ResetOnlyGain, max_episode_steps=100)


def test_a_shift_that_acts_differs_from_the_step_after_its_onset_and_names_the_readings():
    probe = probe_shift(parse_env_shift("Acrobot-v1:LINK_MASS_2=3.0"), onset=10, steps=60, seed=3)
    assert probe.changed and probe.first_difference == 11 and probe.steps == 60
    np.testing.assert_array_equal(probe.own[:11], probe.shifted[:11])  # the same seed, the same actions
    assert (probe.largest > 0).all() and probe.per_step[:11].max() == 0 and probe.per_step[11] > 0
    assert "from step 11 on" in probe.summary()
    sensor = probe_shift(parse_env_shift("Acrobot-v1:obs.bias[4]=0.5"), steps=20)
    assert sensor.first_difference == 0 and np.allclose(sensor.largest, [0, 0, 0, 0, 0.5, 0])
    assert "4: 0.5" in sensor.summary()


def test_an_attribute_read_only_at_reset_changes_nothing_after_the_onset_and_is_said_so():
    """What a user of LunarLander meets with gravity: a shift that sets it after the reset that
    built the world changes nothing, and the monitor could only stay silent. At onset 0 the env
    resets in the shifted world (before 2026-12-06 in its own: such a shift changed nothing at all,
    MiniGrid's DistShift layout row included)."""
    probe = probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:gain=5.0"), onset=5, steps=50)
    assert not probe.changed and probe.steps == 50 and probe.largest.max() == 0
    assert "changed nothing" in probe.summary() and "reads only when it is made or reset" in probe.summary()
    whole = probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:gain=5.0"), steps=50)
    assert whole.changed and whole.first_difference == 1  # the first push, five times as strong
    np.testing.assert_array_equal(whole.own[0], whole.shifted[0])  # (the same start state: the seed's)
    acting = probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:drag=0.5"), onset=5, steps=50)
    assert acting.first_difference == 6 and acting.own_return == acting.shifted_return == 50.0


def test_a_probe_whose_episode_ends_before_the_onset_says_it_saw_nothing_of_the_shift(capsys):
    """The hopper's and InvertedPendulum's random actions end an episode within a few steps: the
    bench said "nothing the env returned differed ... over 5 steps, shifted from step 50 ... does the
    env read it after a reset?" of shifts that were never applied (2026-12-01)."""
    late = probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:drag=0.5"), onset=150, steps=500)
    assert late.steps == 100 and not late.reached_onset and not late.changed
    assert "not seen: the episode ended after 100 steps" in late.summary() and "before the shift began" in late.summary()
    assert "changed nothing" not in late.summary()
    at_the_last = probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:drag=0.5"), onset=99, steps=500)
    assert at_the_last.reached_onset and at_the_last.first_difference == 100  # its last step was shifted
    assert main(["envs", "show", "ResetOnlyGainForTests-v0:drag=0.5", "--onset", "150"]) == 1
    assert "not seen: the episode ended after 100 steps" in capsys.readouterr().out.replace("\n", "")


def test_the_probe_ends_with_the_first_episode_that_ends_and_refuses_no_steps():
    probe = probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:drag=0.5"), steps=500)
    assert probe.steps == 100 and probe.ended == (True, True)  # the time limit of both
    with pytest.raises(InvalidParameterError, match="steps=0 is not allowed"):
        probe_shift(parse_env_shift("ResetOnlyGainForTests-v0:drag=0.5"), steps=0)


def test_envs_show_probes_a_shift_of_your_own_env_and_plots_it(tmp_path, capsys):
    out = tmp_path / "probe.png"
    assert main(["envs", "show", "Acrobot-v1:LINK_MASS_2=3.0", "--onset", "5", "--steps", "30", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "differs from the env's own from step 6 on" in said and out.stat().st_size > 10_000
    # nothing changed: exit code 1, and obs.KIND[i] printed as written (not read as markup)
    assert main(["envs", "show", "ResetOnlyGainForTests-v0:gain=5.0", "--onset", "1", "--steps", "20"]) == 1
    assert "obs.KIND[i]=VALUE" in capsys.readouterr().out
    assert main(["envs", "show", "Acrobot-v1"]) == 2  # (before 2026-12-06: "malformed shift")
    assert "Acrobot-v1 is an env's id alone: `envs show` plays an env beside a shift of it" in capsys.readouterr().err
    assert main(["envs", "show", "Acrobot-v1:LINK_MASS_2"]) == 2
    assert "malformed shift" in capsys.readouterr().err


@pytest.mark.parametrize("env_id, words", [
    ("NoSuchEnvForTests-v0", "env 'NoSuchEnvForTests-v0': Environment `NoSuchEnvForTests` doesn't exist"),
    ("no_such_module_for_tests:X-v0", "No module named 'no_such_module_for_tests'.*on PYTHONPATH"),
])
def test_an_env_gymnasium_cannot_make_is_said_in_one_line(env_id, words, capsys, tmp_path):
    """A typo in a module's name, or an env not registered: a traceback of gymnasium's before
    (`oodmon run --sb3 ... --env my_mod:X-v0` too)."""
    from stable_baselines3 import DQN

    DQN("MlpPolicy", gymnasium.make("CartPole-v1"), policy_kwargs={"net_arch": [8]}).save(tmp_path / "m.zip")
    assert main(["envs", "show", f"{env_id}:x=1"]) == 2
    assert main(["run", "--sb3", str(tmp_path / "m.zip"), "--env", env_id]) == 2
    said = capsys.readouterr().err.splitlines()
    assert len(said) == 2 and all(line.startswith("oodmon: error: ") and re.search(words, line) for line in said)


def test_an_atari_id_is_made_without_importing_ale_py_first():
    probe = probe_shift(parse_env_shift("ALE/Pong-v5:obs.noise=30"), steps=3)
    assert probe.first_difference == 0 and probe.own is None  # 100,800 readings: compared, not kept


def test_a_policy_acts_in_each_env_and_sees_a_shift_where_its_states_lead(tmp_path, capsys):
    """Random actions may never reach the states where a shift matters; the policy's own do. Its
    actions differ once what it reads differs; before the onset both episodes are the same."""
    from stable_baselines3 import DQN

    swing = lambda obs: int(obs[4] > 0) * 2  # noqa: E731  (torque along the first joint's swing)
    probe = probe_shift(parse_env_shift("Acrobot-v1:LINK_MASS_2=3.0"), onset=10, steps=40, policy=swing)
    assert probe.actions == "policy" and probe.first_difference == 11 and "the policy's actions" in probe.summary()
    np.testing.assert_array_equal(probe.own[:11], probe.shifted[:11])
    DQN("MlpPolicy", gymnasium.make("Acrobot-v1"), policy_kwargs={"net_arch": [8]}, seed=0).save(tmp_path / "m.zip")
    argv = ["envs", "show", "Acrobot-v1:LINK_MASS_2=3.0", "--onset", "5", "--steps", "30", "--sb3", str(tmp_path / "m.zip")]
    assert main([*argv, "--frame-stack", "2"]) == 2  # a model of one observation, not of two stacked
    assert "was trained with the observation" in capsys.readouterr().err
    assert main(argv) == 0 and "from step 6 on, over 30 steps of the policy's actions" in capsys.readouterr().out
    assert main(["envs", "show", "pong:pixelate@3", "--sb3", str(tmp_path / "m.zip")]) == 2
    assert "pong:pixelate@3 is shown as its clean and corrupted frames" in capsys.readouterr().err
    assert main(["envs", "show", "cartpole:length=2.0", "--sb3", str(tmp_path / "m.zip")]) == 2  # an Acrobot model
    assert "oodmon/CartPole-v1 has Box(" in capsys.readouterr().err


def test_your_policy_in_a_variant_of_a_task_is_played_beside_the_tasks_id_env(tmp_path, monkeypatch, capsys):
    """Gravity hardly acts on a pendulum held upright: 40% more of it from step 50, when the
    reference controller holds the pendulum there, moves no reading by 0.01 (0.0022 when written)
    and leaves the return as it was; from the start, while the controller swings it up, it changes
    the episode (readings 8.3 apart). What a user's policy meets when `oodmon run` of such a shift
    alarms nowhere (before 2026-12-04, `envs show` refused --sb3 and --policy for a task's variant)."""
    from oodmon.envs import parse_variant
    from oodmon.envs.reference import pendulum_controller

    upright = probe_shift(parse_variant("pendulum:g=14.0"), onset=50, steps=200, policy=pendulum_controller)
    assert upright.first_difference == 51 and 0 < upright.largest.max() < 0.01
    assert upright.steps == 200 and abs(upright.shifted_return - upright.own_return) < 0.1
    swinging = probe_shift(parse_variant("pendulum:g=14.0"), onset=0, steps=200, policy=pendulum_controller)
    assert swinging.first_difference == 1 and swinging.largest.max() > 1.0
    (tmp_path / "probe_controller.py").write_text("from oodmon.envs.reference import pendulum_controller as act\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    argv = ["envs", "show", "pendulum:g=14.0", "--onset", "50", "--steps", "200", "--policy", "probe_controller:act"]
    assert main(argv) == 0
    assert "differs from the env's own from step 51 on, over 200 steps of the policy's actions" in capsys.readouterr().out


def test_an_env_of_dict_observations_is_compared_reading_by_reading():
    class DictGain(_ResetOnlyGain):
        observation_space = gymnasium.spaces.Dict({"x": gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float64),
                                                   "t": gymnasium.spaces.Discrete(1000)})

        def reset(self, *, seed=None, options=None):
            obs, info = super().reset(seed=seed, options=options)
            self.t = 0
            return {"x": obs, "t": 0}, info

        def step(self, action):
            obs, *rest = super().step(action)
            self.t += 1
            return {"x": obs, "t": self.t}, *rest

    if "DictGainForTests-v0" not in gymnasium.registry:
        gymnasium.register("DictGainForTests-v0", entry_point=DictGain, max_episode_steps=30)
    probe = probe_shift(parse_env_shift("DictGainForTests-v0:drag=0.5"), onset=4, steps=30)
    assert probe.first_difference == 5 and probe.largest.shape == (1002,)  # t one-hot, then x
    assert probe.largest[:1000].max() == 0 and probe.largest[1000:].min() > 0


def _unfelt_said(variant: str, env_id: str, policy, onsets: tuple[int, int]) -> str:
    """What the bench's report says of ``variant`` when none of its 10 episodes alarmed, ``policy``
    (obs -> action) the user's own that the bench played."""
    import io
    import types

    from rich.console import Console

    from oodmon.agents.plain import plain_agent
    from oodmon.bench.report import print_unfelt
    from oodmon.replay.metrics import monitor_row

    config = types.SimpleNamespace(onset_range=lambda: onsets)  # (the bench's onsets are all print_unfelt reads of it)
    unalarmed = monitor_row(env_id, "plain", variant, 10, 0, None, None, [])
    out = io.StringIO()
    print_unfelt(config, types.SimpleNamespace(alarms=[unalarmed]), Console(file=out, width=400),
                 agent=plain_agent(policy, env_id))
    return out.getvalue()


def test_the_bench_says_a_shift_no_episode_alarmed_on_was_not_seen_where_the_policys_episode_ends_before_the_onset():
    said = _unfelt_said("ResetOnlyGainForTests-v0:drag=0.5", "ResetOnlyGainForTests-v0", lambda obs: 1, (150, 160))
    assert "your policy's episode in the env ends after 100 steps, before step 150, the first onset" in said
    assert "not seen (earlier --onsets shift the episodes while your policy still runs them)" in " ".join(said.split())
    assert "only after a reset" not in said


def test_the_bench_says_an_attribute_read_at_reset_changes_nothing_where_its_episodes_shifted_after_the_reset():
    """The episodes shift at a random step of the bench's --onsets; one from step 0 resets in the
    shifted world, the others after their reset. Onsets in [0, 20): the probe shifts from step 1, as
    most episodes did, and says what to try (before 2026-12-06 it probed from step 0, which did the
    same then, the reset too being in the env's own world)."""
    said = " ".join(_unfelt_said("ResetOnlyGainForTests-v0:gain=5.0", "ResetOnlyGainForTests-v0", lambda obs: 1,
                                 (0, 20)).split())
    assert ("nothing the env returned differed from its own over 100 steps of your policy's actions, shifted from "
            "step 1: does the env read it only at a reset (a shift from onset 0 resets the env shifted: --onsets "
            "0,1)") in said
    assert _unfelt_said("ResetOnlyGainForTests-v0:gain=5.0", "ResetOnlyGainForTests-v0", lambda obs: 1, (0, 1)) == ""


def test_the_bench_probes_an_unalarmed_shift_where_the_users_policy_goes_not_where_random_actions_go():
    """A judge's bound set tighter, `CartPole-v1:theta_threshold_radians=0.1` from step 150: random
    actions drop the pole within about 20 steps, so a probe of them saw nothing of it (what the bench
    said before 2026-12-02); a controller that keeps the pole upright plays 500 steps in both, and
    nothing differs, since it never leans as far as the new bound."""
    def upright(obs):
        return int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)

    said = " ".join(_unfelt_said("CartPole-v1:theta_threshold_radians=0.1", "CartPole-v1", upright, (150, 160)).split())
    assert ("nothing the env returned differed from its own over 500 steps of your policy's actions, shifted from "
            "step 150") in said and "where your policy never goes" in said
    assert probe_shift(parse_env_shift("CartPole-v1:theta_threshold_radians=0.1"), onset=150).steps < 150  # random
    felt = _unfelt_said("CartPole-v1:theta_threshold_radians=0.001", "CartPole-v1", upright, (150, 160))
    assert felt == ""  # it ends the episode at the onset: felt, so nothing to say of the env


def test_the_bench_says_how_little_a_variant_of_a_task_moved_the_readings_where_your_policy_goes():
    """oodmon's own variants were taken as felt (before 2026-12-04 the bench said nothing of them):
    40% more gravity from step 50, when the controller holds the pendulum upright, moves sin(angle)
    by 0.0007, 0.04% of its range in the ID episode, which no detector need see; from step 0 it
    changes the swing (a reading moved by its whole range)."""
    from oodmon.envs.reference import pendulum_controller

    said = " ".join(_unfelt_said("pendulum:g=14.0", "Pendulum-v1", pendulum_controller, (50, 60)).split())
    assert ("pendulum:g=14.0: no episode alarmed; where your policy goes, over 200 steps shifted from step 50, it "
            "moved reading 1 by at most 0.04% of that reading's range in the ID episode") in said
    assert "`oodmon envs show pendulum:g=14.0 --onset 50` with your policy's --sb3 or --policy" in said
    swinging = " ".join(_unfelt_said("pendulum:g=14.0", "Pendulum-v1", pendulum_controller, (0, 10)).split())
    assert "moved reading 0 by at most 100.52% of that reading's range" in swinging
    assert _unfelt_said("pong:pixelate@3", "oodmon/Pong-v5", lambda obs: 0, (0, 10)) == ""  # frames: no probe
    stuck = " ".join(_unfelt_said("pendulum:obs.stuck[2]=1.0", "Pendulum-v1", pendulum_controller, (50, 60)).split())
    assert "`oodmon envs show 'pendulum:obs.stuck[2]=1.0' --onset 50`" in stuck  # quoted for the shell, as run's
