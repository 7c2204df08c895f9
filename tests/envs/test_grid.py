"""The paper's grid as data, and spec strings that parse back exactly."""

from __future__ import annotations

import pytest

from oodmon.envs import TASKS, Variant, paper_grid, parse_variant
from oodmon.errors import InvalidParameterError, SpecError, UnknownParameterError

ALL_VARIANTS = [v for task in TASKS for v in paper_grid(task)]


def test_grid_sizes_are_the_papers():
    assert {task: len(paper_grid(task)) for task in TASKS} == {"cartpole": 90, "pendulum": 40, "pong": 20}
    assert len(set(ALL_VARIANTS)) == 150  # all different
    assert not any(v.is_id for v in ALL_VARIANTS)


def test_grid_holds_the_papers_values():
    lengths = [v.params[0][1] for v in paper_grid("cartpole") if v.params[0][0] == "length"]
    assert lengths[:2] == [0.05, 0.0556] and lengths[-1] == 5.0 and len(lengths) == 18
    assert [v.spec for v in paper_grid("pendulum")][:3] == ["pendulum:g=0.5", "pendulum:g=1.0", "pendulum:g=2.0"]
    assert [v.spec for v in paper_grid("pong")][-5:] == [f"pong:pixelate@{s}" for s in range(1, 6)]


@pytest.mark.parametrize("variant", ALL_VARIANTS, ids=str)
def test_every_spec_parses_back_to_its_variant(variant):
    assert parse_variant(variant.spec) == variant
    assert parse_variant(variant.spec).spec == variant.spec


@pytest.mark.parametrize(
    "text, spec, kwargs",
    [
        ("cartpole", "cartpole", {}),
        ("cartpole:length=2.0", "cartpole:length=2.0", {"length": 2.0}),
        ("cartpole:length=2", "cartpole:length=2.0", {"length": 2.0}),
        ("pendulum:g=50", "pendulum:g=50.0", {"g": 50.0}),
        ("cartpole:length=2.0,gravity=20", "cartpole:gravity=20.0,length=2.0", {"gravity": 20.0, "length": 2.0}),
        ("pong:motion_blur@3", "pong:motion_blur@3", {"corruption": "motion_blur", "severity": 3}),
        ("pong:motion_blur:radius=15,sigma=8", "pong:motion_blur:radius=15,sigma=8.0",
         {"corruption": "motion_blur", "radius": 15, "sigma": 8.0}),
        ("pong:gaussian_noise:sigma=1e-1", "pong:gaussian_noise:sigma=0.1", {"corruption": "gaussian_noise", "sigma": 0.1}),
        ("pong", "pong", {}),
    ],
)
def test_spec_strings(text, spec, kwargs):
    variant = parse_variant(text)
    assert variant.spec == spec and variant.kwargs() == kwargs
    assert parse_variant(spec) == variant


def test_variant_makes_its_env_with_an_onset():
    env = parse_variant("cartpole:masspole=0.5").make(onset_step=7)
    assert env.unwrapped.onset_step == 7 and env.unwrapped.shifted_physics["masspole"] == 0.5
    assert parse_variant("cartpole").is_id and parse_variant("pong").is_id


@pytest.mark.parametrize(
    "text, error, words",
    [
        ("cartpole:length", SpecError, "malformed variant spec 'cartpole:length' at 'length': expected TASK"),
        ("cartpole:length=two", SpecError, "malformed variant spec 'cartpole:length=two'"),
        ("", SpecError, "malformed variant spec '': expected TASK"),
        ("cartpole:length=1,length=2", SpecError, "sets 'length' twice"),
        ("pong:pixelate@x", SpecError, "severity 'x' is not an integer from 1 to 5"),
        ("pong:pixelate", SpecError, "malformed variant spec 'pong:pixelate'"),
        ("cartpole:pixelate@3", SpecError, "malformed variant spec 'cartpole:pixelate@3'"),
        ("hopper:g=1", UnknownParameterError, "unknown task 'hopper'; choose one of cartpole, pendulum, pong"),
        # gymnasium's id of a task (a user of --sb3 --env Pendulum-v1 writes it): told the task's name
        ("Pendulum-v1:m=2.0", UnknownParameterError, "variants of Pendulum-v1 are named by its task, pendulum:m=2.0"),
        ("oodmon/Pong-v5:pixelate@3", UnknownParameterError, "named by its task, pong:pixelate@3"),
        ("CartPole-v1", UnknownParameterError, "variants of CartPole-v1 are named by its task, cartpole (see"),
        ("cartpole:lenght=2", UnknownParameterError, "oodmon/CartPole-v1 has no parameter 'lenght'"),
        ("cartpole:masscart=0", InvalidParameterError, "masscart=0.0 is not allowed"),
        ("pendulum:l=-2", InvalidParameterError, "l=-2.0 is not allowed"),
        ("pong:fog@2", UnknownParameterError, "unknown corruption 'fog'"),
        ("pong:pixelate@6", InvalidParameterError, "severity=6 is not allowed"),
        ("pong:pixelate:sigma=0.1", UnknownParameterError, "pixelate has no parameter 'sigma'"),
        # sensor faults of a task
        ("cartpole:obs.bias[4]=1", UnknownParameterError, "cartpole: obs.bias[4] is outside the observation, whose 4 readings"),
        ("cartpole:obs.tilt=1", UnknownParameterError, "'obs.tilt' is no sensor fault"),
        ("cartpole:obs.noise=-1", InvalidParameterError, "noise is a std"),
        ("pong:motion_blur:radius=5,obs.stuck=1", SpecError, "pong: a corruption and sensor faults at once"),
        ("cartpole:obs.bias[0]=0", InvalidParameterError, "cartpole: obs.bias[0]=0 changes no reading"),
    ],
)
def test_bad_specs_are_named(text, error, words):
    with pytest.raises(error) as raised:
        parse_variant(text)
    assert words in str(raised.value)


def test_variant_refuses_corruptions_on_physics_tasks():
    with pytest.raises(SpecError, match="cartpole variants change physics, not frames"):
        Variant("cartpole", corruption="pixelate", severity=2)
    with pytest.raises(UnknownParameterError, match="unknown task 'walker'"):
        paper_grid("walker")


def test_a_sensor_fault_of_a_task_parses_back_and_faults_its_own_env_from_the_onset():
    import numpy as np

    from oodmon.envs.registration import variant_of_env

    both = parse_variant("cartpole:length=2.0,obs.stuck[3]=1")
    assert (both.params, both.faults, both.spec) == ((("length", 2.0),), (("obs.stuck[3]", 1.0),),
                                                     "cartpole:length=2.0,obs.stuck[3]=1.0")
    assert parse_variant("cartpole:obs.stuck[3]=1,length=2.0") == both  # in either order
    for spec in ("cartpole:obs.stuck[3]=1.0", "pendulum:obs.bias[2]=0.5", "pong:obs.stuck=1.0", both.spec):
        assert parse_variant(spec).spec == spec and not parse_variant(spec).is_id
        assert variant_of_env(parse_variant(spec).make(onset_step=3)) == spec  # what the logs record
    plain, stuck = parse_variant("cartpole:length=2.0").make(onset_step=2), both.make(onset_step=2)
    own, _ = plain.reset(seed=4)
    read, info = stuck.reset(seed=4)
    owns, reads, flags = [own], [read], [info["shifted"]]
    for _ in range(6):
        owns.append(plain.step(1)[0])
        read, _, _, _, info = stuck.step(1)
        reads.append(read)
        flags.append(info["shifted"])
    owns, reads = np.array(owns), np.array(reads)
    assert flags == [False] * 3 + [True] * 4
    np.testing.assert_array_equal(reads[:, :3], owns[:, :3])  # the world and the other readings: the long pole's
    assert (reads[:3, 3] == owns[:3, 3]).all() and (reads[3:, 3] == owns[2, 3]).all() and len(set(owns[3:, 3])) == 4
    # the monitor's benchmark gives each episode its onset: the physics and the faults shift there alike
    env = both.make(onset_step=100)
    env.reset(seed=4, options={"onset_step": 2})
    assert [env.step(1)[4]["shifted"] for _ in range(4)] == [False, False, True, True] and env.unwrapped.length == 2.0
