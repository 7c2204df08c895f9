"""Shifts of a user's own env (oodmon.envs.shift): other numbers in its attributes from an onset on."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from oodmon.envs import EnvShift, ShiftAttributes, parse_env_shift
from oodmon.envs.registration import onset_of_env, variant_of_env
from oodmon.errors import InvalidParameterError, SpecError, UnknownParameterError


def _rollout(env: gymnasium.Env, seed: int, steps: int, options: dict | None = None):
    """Observations and ``info["shifted"]`` of ``steps`` steps of a fixed action sequence."""
    obs, info = env.reset(seed=seed, options=options)
    observations, shifted = [obs], [info.get("shifted")]
    actions = np.random.default_rng(seed).integers(0, 3, steps)
    for action in actions:
        obs, _, terminated, truncated, info = env.step(int(action))
        observations.append(obs)
        shifted.append(info.get("shifted"))
        assert not (terminated or truncated)  # an untrained swing of 40 steps never reaches the goal
    return np.array(observations), shifted


def test_a_shift_is_the_env_itself_until_its_onset_and_other_physics_from_it_in_every_episode():
    plain = gymnasium.make("Acrobot-v1")
    heavy = parse_env_shift("Acrobot-v1:LINK_MASS_2=3.0").make(onset_step=10)
    assert heavy.unwrapped.LINK_MASS_2 == 1.0  # the class's own value until an episode reaches the onset
    for episode in range(2):  # the second episode starts in the env's own world again
        own, _ = _rollout(plain, seed=episode, steps=40)
        shifted_obs, flags = _rollout(heavy, seed=episode, steps=40)
        assert flags == [False] * 11 + [True] * 30  # step 10 (the 11th step() call) is the first shifted one
        np.testing.assert_array_equal(shifted_obs[:11], own[:11])  # bit for bit the same until the onset
        assert np.abs(shifted_obs[11:] - own[11:]).max() > 0.1  # a heavier link swings otherwise
        assert heavy.unwrapped.LINK_MASS_2 == 3.0
    _, flags = _rollout(heavy, seed=0, steps=5, options={"onset_step": 2})  # this episode's onset alone
    assert flags == [False] * 3 + [True] * 3 and onset_of_env(heavy) == 2
    _, flags = _rollout(heavy, seed=0, steps=12)
    assert flags == [False] * 11 + [True] * 2 and onset_of_env(heavy) == 10  # the configured onset is back
    heavy.close()
    assert heavy.unwrapped.LINK_MASS_2 == 1.0  # closed: the env as it came
    _, flags = _rollout(parse_env_shift("Acrobot-v1:LINK_MASS_2=3.0").make(), seed=0, steps=3)
    assert flags == [True] * 4  # onset 0: shifted from the first observation


def test_a_shift_names_itself_in_the_spec_the_logs_record_and_replay_reads_back():
    shift = parse_env_shift(" MountainCar-v0:gravity=0.003, force=0.0005 ")
    assert shift == EnvShift("MountainCar-v0", (("force", 0.0005), ("gravity", 0.003)))
    assert shift.spec == "MountainCar-v0:force=0.0005,gravity=0.003" and parse_env_shift(shift.spec) == shift
    env = gymnasium.wrappers.TimeAwareObservation(shift.make(onset_step=7))  # a wrapper of the user's outside it
    assert variant_of_env(env) == shift.spec and onset_of_env(env) == 7
    made_by_hand = ShiftAttributes(gymnasium.make("MountainCar-v0"), {"force": 0.0005, "gravity": 0.003})
    assert made_by_hand.shift == shift and not shift.is_id
    assert parse_env_shift("my_envs:MyEnv-v0:mass=2").env_id == "my_envs:MyEnv-v0"  # a module's env keeps its prefix


@pytest.mark.parametrize("spec, error, words", [
    ("Acrobot-v1", SpecError, "expected ENV_ID:NAME=VALUE"),
    ("Acrobot-v1:LINK_MASS_2", SpecError, "expected ENV_ID:NAME=VALUE"),
    ("Acrobot-v1:LINK_MASS_2=heavy", SpecError, "at 'LINK_MASS_2=heavy'"),
    ("Reacher-v5:model.body_mass[1]=heavy", SpecError, r"at 'model.body_mass\[1\]=heavy': expected [^;]*$"),
    ("Acrobot-v1:2x=3", SpecError, "at '2x=3'"),
    ("Reacher-v5:model.actuator_gear[0,0]=100", SpecError, (
        r"at 'model.actuator_gear\[0'.*an index for each axis, each in brackets of its own and counted from 0 "
        r"\(model.actuator_gear\[0\]\[0\] for an array of two axes, not model.actuator_gear\[0,0\] nor "
        r"model.actuator_gear\[-1\]\)")),
    ("Reacher-v5:model.actuator_gear[-1]=100", SpecError, r"\(model.actuator_gear\[0\]\[0\] for an array of two axes"),
    ("Reacher-v5:obs.bias[-1]=1", SpecError,
     r"a reading is counted from 0 in the flattened observation \(obs.bias\[0\], not obs.bias\[-1\]\)"),
    (":LINK_MASS_2=3", SpecError, "expected ENV_ID"),
    ("Acrobot-v1:a=1,a=2", SpecError, "sets 'a' twice"),
    ("Acrobot-v1::a=1", SpecError, "expected ENV_ID"),
    ("CartPole-v1:length=2.0", SpecError, r"give cartpole:length=2.0 \(in Python to oodmon.envs.parse_variant, whose "
     r"\.make\(onset_step=N\) makes the env"),
    ("CartPole-v1:obs.bias[0]=0.5", SpecError, r"give cartpole:obs.bias\[0\]=0.5"),
    ("CartPole-v1:x_threshold=1.0,length=2.0", SpecError, r"mixes cartpole's physics \(length\).*\(x_threshold\), which "
     "a shift of CartPole-v1 sets: one spec cannot hold both"),
    ("cartpole:length=2.0", SpecError, "is a variant of oodmon's cartpole"),
], ids=["no-assignment", "no-value", "not-a-number", "element-not-a-number", "not-a-name", "numpy-index",
        "index-from-the-end", "reading-from-the-end", "no-env", "twice", "double-colon", "oodmon-env",
        "oodmon-env-fault", "oodmon-env-mixed", "oodmon-spec"])
def test_a_malformed_shift_is_refused_saying_the_form(spec, error, words):
    with pytest.raises(error, match=words):
        parse_env_shift(spec)


@pytest.mark.parametrize("changes, error, words", [
    ({"LINK_MAS_2": 3.0}, UnknownParameterError, "no numeric attribute 'LINK_MAS_2'.*LINK_MASS_2"),
    ({"np_random": 3.0}, UnknownParameterError, "no numeric attribute 'np_random'"),
    ({"np_random_seed": 3}, UnknownParameterError, "no numeric attribute 'np_random_seed'"),  # a property: no setter
    ({"_private": 3.0}, UnknownParameterError, "no numeric attribute '_private'"),
    ({"LINK_MASS_2": float("nan")}, InvalidParameterError, "not a finite number"),
    ({"LINK_MASS_2": True}, InvalidParameterError, "not a finite number"),
    ({"LINK_MASS_2": 1.0}, InvalidParameterError, "are its own values"),
    ({}, InvalidParameterError, "at least one attribute"),
], ids=["misspelt", "not-numeric", "property", "private", "nan", "bool", "unchanged", "nothing"])
def test_a_shift_the_env_cannot_take_is_refused_naming_what_it_can(changes, error, words):
    with pytest.raises(error, match=words):
        ShiftAttributes(gymnasium.make("Acrobot-v1"), changes)


def test_a_whole_number_attribute_takes_whole_values_and_keeps_its_type():
    base = gymnasium.make("CartPole-v1").unwrapped  # its x_threshold is a float; a whole-number one from an int attr:
    base.kick_every = 5  # an int attribute an env of the user's might have
    with pytest.raises(InvalidParameterError, match="kick_every is a whole number"):
        ShiftAttributes(base, {"kick_every": 2.5})
    env = ShiftAttributes(base, {"kick_every": 3.0})
    env.reset(seed=0)
    assert base.kick_every == 3 and type(base.kick_every) is int


class _Option:
    """As MuJoCo's ``model.opt``: a struct whose numbers and arrays the simulation reads."""

    def __init__(self) -> None:
        self.gravity = np.array([0.0, 0.0, -9.81])
        self.timestep = 0.01


class _Model:
    """As MuJoCo's ``model``: arrays of the bodies' parameters, read at every step, set in place."""

    def __init__(self) -> None:
        self.body_mass = np.array([0.0, 1.0, 2.0])
        self.geom_friction = np.ones((2, 3))  # an array of two axes
        self.opt = _Option()


class _FallingBodies(gymnasium.Env):
    """Two bodies falling, pushed up or down: their velocities, from the model's arrays."""

    observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self) -> None:
        self.model = _Model()

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.velocity = self.np_random.normal(size=2)
        return self.velocity.astype(np.float32), {}

    def step(self, action):
        push = 1.0 if action else -1.0
        self.velocity = self.velocity + self.model.opt.timestep * (self.model.opt.gravity[2] + push / self.model.body_mass[1:])
        return self.velocity.astype(np.float32), 0.0, False, False, {}


def test_a_shift_sets_elements_of_arrays_through_attributes_as_mujocos_model_holds_them():
    changes = {"model.body_mass[1]": 4.0, "model.opt.gravity[2]": -5.0, "model.opt.timestep": 0.02}
    plain, env = _FallingBodies(), ShiftAttributes(_FallingBodies(), changes, onset_step=3)
    masses, gravity = env.unwrapped.model.body_mass, env.unwrapped.model.opt.gravity
    for _ in range(2):
        own, _ = _rollout(plain, seed=0, steps=6)
        shifted, flags = _rollout(env, seed=0, steps=6)
        assert flags == [False] * 4 + [True] * 3
        np.testing.assert_array_equal(shifted[:4], own[:4])
        assert np.abs(shifted[4:] - own[4:]).min() > 1e-3
        assert masses.tolist() == [0.0, 4.0, 2.0] and gravity.tolist() == [0.0, 0.0, -5.0]  # the env's own arrays, in place
        assert env.unwrapped.model.opt.timestep == 0.02
    env.reset(seed=0)
    assert masses.tolist() == [0.0, 1.0, 2.0] and gravity[2] == -9.81 and env.unwrapped.model.opt.timestep == 0.01
    assert env.shift.spec == "_FallingBodies:model.body_mass[1]=4.0,model.opt.gravity[2]=-5.0,model.opt.timestep=0.02"
    assert parse_env_shift(env.shift.spec) == env.shift


@pytest.mark.parametrize("name, words", [
    ("model.body_mass", r"model.body_mass is an array of shape \[3\]: shift an element, e.g. model.body_mass\[0\]"),
    ("model.body_mass[3]", r"model.body_mass\[3\] is outside model.body_mass, an array of shape \[3\]"),
    ("model.body_mass[1][0]", r"model.body_mass\[1\]\[0\] has 2 indices; model.body_mass, an array of shape \[3\], "
                              r"takes 1"),
    ("model.geom_friction[1]", (r"model.geom_friction\[1\] is a part of shape \[3\] of model.geom_friction, an array "
                                r"of shape \[2, 3\]: shift an element, an index for each axis, e.g. "
                                r"model.geom_friction\[1\]\[0\]")),
    ("model.geom_friction[0][3]", r"model.geom_friction\[0\]\[3\] is outside model.geom_friction, an array of shape "
                                  r"\[2, 3\]"),
    ("model.opt.gravty[2]", "model.opt.gravty is not a numeric array to index"),
    ("modle.body_mass[1]", "no attribute 'modle' to shift through"),
    ("model.opt", (r"no numeric attribute 'model.opt' to shift; the numeric attributes of model: none; arrays \(shift "
                   r"an element, NAME\[i\]\): body_mass\[3\]")),
    ("model.opt.gravity[-1]", r"is not an attribute name.*counted from 0 \(model.opt.gravity\[0\]\[0\] for an array"),
], ids=["array-whole", "index-outside", "too-many-indices", "a-row", "column-outside", "misspelt-array",
        "misspelt-path", "a-struct", "negative"])
def test_a_path_that_leads_to_no_number_is_refused_saying_what_is_there(name, words):
    with pytest.raises(UnknownParameterError, match=words):
        ShiftAttributes(_FallingBodies(), {name: 1.0})


def test_sensor_faults_change_the_readings_from_the_onset_and_a_stuck_one_holds_its_last_value():
    faults = {"obs.bias[0]": 0.5, "obs.scale[0]": 2.0, "obs.stuck[1]": 1}
    plain, env = _FallingBodies(), ShiftAttributes(_FallingBodies(), faults, onset_step=3)
    own, _ = _rollout(plain, seed=4, steps=6)
    read, flags = _rollout(env, seed=4, steps=6)
    assert flags == [False] * 4 + [True] * 3 and read.dtype == np.float32
    np.testing.assert_array_equal(read[:4], own[:4])  # the world itself never changes: only what is read of it
    np.testing.assert_allclose(read[4:, 0], own[4:, 0] * 2.0 + 0.5, rtol=1e-6)
    assert (read[4:, 1] == own[3, 1]).all() and len(set(own[3:, 1])) == 4  # held at the last reading before the fault
    assert env.shift.spec == "_FallingBodies:obs.bias[0]=0.5,obs.scale[0]=2.0,obs.stuck[1]=1.0"
    assert parse_env_shift(env.shift.spec).params == env.shift.params


def test_sensor_noise_is_the_same_for_the_same_seed_and_of_the_std_asked():
    env = ShiftAttributes(_FallingBodies(), {"obs.noise[1]": 0.3})  # from the first reading
    first, _ = _rollout(env, seed=7, steps=400)
    again, _ = _rollout(env, seed=7, steps=400)
    other, _ = _rollout(env, seed=8, steps=400)
    own, _ = _rollout(_FallingBodies(), seed=7, steps=400)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first[:, 1], other[:, 1])
    np.testing.assert_array_equal(first[:, 0], own[:, 0])  # reading 0 untouched
    noise = first[:, 1].astype(np.float64) - own[:, 1]
    # 401 draws of std 0.3: their std lies within 0.3 +- 12% with probability > 0.99 (chi-square, 400 dof)
    assert abs(noise.std() - 0.3) < 0.036 and abs(noise.mean()) < 0.3 * 3 / np.sqrt(401)


@pytest.mark.parametrize("changes, error, words", [
    ({"obs.blur[0]": 1.0}, UnknownParameterError, "no sensor fault; give obs.KIND"),
    ({"obs.bias[2]": 1.0}, UnknownParameterError, r"outside the observation, whose 2 readings are 0-1"),
    ({"obs.bias[x]": 1.0}, UnknownParameterError, "or obs.KIND=VALUE for every reading"),
    ({"obs.noise[0]": -0.1}, InvalidParameterError, "noise is a std"),
    ({"obs.stuck[0]": 2}, InvalidParameterError, "stuck is 1"),
    ({"obs.bias[0]": float("inf")}, InvalidParameterError, "give a finite number"),
    ({"obs.bias[0]": 0.0, "obs.scale[1]": 1.0}, InvalidParameterError,
     r"obs.bias\[0\]=0, obs.scale\[1\]=1 change no reading \(each kind's value that leaves a reading as it is: bias 0, "
     r"scale 1, noise 0, stuck 0; obs.stuck\[i\]=1 holds reading i from the onset\)"),
], ids=["kind", "index", "bad-index", "negative-noise", "stuck-2", "inf", "unchanged"])
def test_a_sensor_fault_that_cannot_be_is_refused_saying_what_can(changes, error, words):
    with pytest.raises(error, match=words):
        ShiftAttributes(_FallingBodies(), changes)


class _Camera(gymnasium.Env):
    """An 8 x 8 grey picture of bytes: a gradient from 0 to 252 that moves by one grey level a step."""

    observation_space = gymnasium.spaces.Box(0, 255, (8, 8), np.uint8)
    action_space = gymnasium.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self._picture(), {}

    def step(self, action):
        self.t += 1
        return self._picture(), 0.0, False, False, {}

    def _picture(self):
        return (np.arange(64).reshape(8, 8) * 4 + self.t % 4).astype(np.uint8)


def test_a_fault_without_an_index_is_every_readings_and_bytes_saturate_instead_of_wrapping():
    """A camera's fault is its every pixel's: ``obs.noise=30`` (without ``[i]``, refused before:
    7,056 pixels of an Atari stack could only be named one by one). A pixel pushed past 255 reads
    255 and below 0 reads 0 (the float reading cast to uint8 wrapped: 250 + 10 read 4)."""
    own, _ = _rollout(_Camera(), seed=0, steps=3)
    bright, _ = _rollout(ShiftAttributes(_Camera(), {"obs.bias": 10, "obs.bias[0]": 0}), seed=0, steps=3)
    assert bright.dtype == np.uint8
    expected = np.minimum(own.astype(int) + 10, 255)
    expected[:, 0, 0] = own[:, 0, 0]  # the one pixel named takes its own value instead
    np.testing.assert_array_equal(bright, expected)
    assert bright[:, 7, 7].tolist() == [255] * 4 and own[:, 7, 7].tolist() == [252, 253, 254, 255]
    dark, _ = _rollout(ShiftAttributes(_Camera(), {"obs.bias": -10.4}), seed=0, steps=3)
    np.testing.assert_array_equal(dark, np.maximum(own.astype(int) - 10, 0))  # rounded, then clipped at 0
    noisy, _ = _rollout(ShiftAttributes(_Camera(), {"obs.noise": 30.0}), seed=0, steps=3)
    change = noisy.astype(float) - own
    inside = (own > 90) & (own < 165)  # three stds from both ends: clipping leaves these draws alone
    # 4 x 20 or so draws of std 30 (rounded): their std within 30 +- 25% with probability > 0.99
    assert inside.sum() >= 70 and abs(change[inside].std() - 30) < 7.5 and (change[~inside] != 0).any()
    frozen, flags = _rollout(ShiftAttributes(_Camera(), {"obs.stuck": 1}, onset_step=1), seed=0, steps=3)
    assert flags == [False, False, True, True] and (frozen[2:] == own[1]).all()
    spec = ShiftAttributes(_Camera(), {"obs.noise": 30.0, "obs.noise[3]": 0.0}).shift.spec
    assert spec == "_Camera:obs.noise=30.0,obs.noise[3]=0.0" and parse_env_shift(spec).params == \
        (("obs.noise", 30.0), ("obs.noise[3]", 0.0))


def test_sensor_faults_need_a_box_discrete_values_or_a_dict_or_tuple_of_them_and_its_key_or_part():
    class TextBodies(_FallingBodies):
        observation_space = gymnasium.spaces.Text(8)

    with pytest.raises(UnknownParameterError, match=r"read the readings of a Box observation or of discrete values "
                                                    r"\(Discrete, MultiDiscrete, MultiBinary, a Tuple of Discrete\), "
                                                    r"or of a dict or tuple of them; .*Text\("):
        ShiftAttributes(TextBodies(), {"obs.bias[0]": 1.0})

    class TupleBodies(_FallingBodies):
        """The velocities, and the same again in a tuple inside the tuple (refused as a dict in a dict is)."""

        observation_space = gymnasium.spaces.Tuple((_FallingBodies.observation_space,
                                                    gymnasium.spaces.Tuple((_FallingBodies.observation_space,))))

        def reset(self, *, seed=None, options=None):
            obs, info = super().reset(seed=seed)
            return (obs, (obs,)), info

        def step(self, action):
            obs, *rest = super().step(action)
            return (obs, (obs,)), *rest

    env = ShiftAttributes(TupleBodies(), {"obs.0.bias[1]": 1.0}, onset_step=1)
    obs, _ = env.reset(seed=0)
    before, *_ = env.step(1)
    shifted, *_ = env.step(1)
    assert obs[0][1] == obs[1][0][1] and before[0][1] == before[1][0][1]  # (the fault's first observation is step 2's)
    assert isinstance(shifted, tuple) and shifted[0][1] == shifted[1][0][1] + 1 and shifted[0][0] == shifted[1][0][0]
    assert env.shift.spec == "TupleBodies:obs.0.bias[1]=1.0" and parse_env_shift(env.shift.spec).params == \
        (("obs.0.bias[1]", 1.0),)
    with pytest.raises(UnknownParameterError, match=r"'obs.bias\[0\]' names no part of its tuple observation; give "
                                                    r"obs.N.KIND\[i\]=VALUE, N one of 0, 1"):
        ShiftAttributes(TupleBodies(), {"obs.bias[0]": 1.0})
    with pytest.raises(UnknownParameterError, match=r"'obs.1.bias' names a dict or a tuple in its tuple observation"):
        ShiftAttributes(TupleBodies(), {"obs.1.bias": 1.0})
    with pytest.raises(UnknownParameterError, match=r"TupleBodies \(part 0\): obs.bias\[2\] is outside the "):
        ShiftAttributes(TupleBodies(), {"obs.0.bias[2]": 1.0})

    class DictBodies(_FallingBodies):
        observation_space = gymnasium.spaces.Dict({"v": _FallingBodies.observation_space,
                                                   "deep": gymnasium.spaces.Dict({"w": _FallingBodies.observation_space})})

    with pytest.raises(UnknownParameterError, match=r"'obs.bias\[0\]' names no key of its dict observation; give "
                                                    r"obs.KEY.KIND\[i\]=VALUE, KEY one of deep, v"):
        ShiftAttributes(DictBodies(), {"obs.bias[0]": 1.0})
    with pytest.raises(UnknownParameterError, match=r"'obs.w.bias' names no key"):
        ShiftAttributes(DictBodies(), {"obs.w.bias": 1.0})
    with pytest.raises(UnknownParameterError, match=r"DictBodies: 'obs.deep.bias' names a dict or a tuple in its "):
        ShiftAttributes(DictBodies(), {"obs.deep.bias": 1.0})
    with pytest.raises(UnknownParameterError, match=r"DictBodies \(key 'v'\): obs.bias\[9\] is outside the observation"):
        ShiftAttributes(DictBodies(), {"obs.v.bias[9]": 1.0})


class _BodiesAndCount(_FallingBodies):
    """The falling bodies' velocities twice ("v", "w") and the steps counted modulo 7 ("n"), as a dict."""

    observation_space = gymnasium.spaces.Dict({"v": _FallingBodies.observation_space, "w": _FallingBodies.observation_space,
                                               "n": gymnasium.spaces.Discrete(7)})

    def _dict(self, velocity):
        return {"v": velocity, "w": velocity.copy(), "n": self.count}

    def reset(self, *, seed=None, options=None):
        velocity, info = super().reset(seed=seed, options=options)
        self.count = 0
        return self._dict(velocity), info

    def step(self, action):
        velocity, *rest = super().step(action)
        self.count = (self.count + 1) % 7
        return self._dict(velocity), *rest


def _dict_rollout(env: gymnasium.Env, seed: int, steps: int) -> tuple[list[dict], list]:
    obs, info = env.reset(seed=seed)
    observations, shifted = [obs], [info.get("shifted")]
    for action in np.random.default_rng(seed).integers(0, 2, steps):
        obs, _, _, _, info = env.step(int(action))
        observations.append(obs)
        shifted.append(info.get("shifted"))
    return observations, shifted


def test_a_dicts_sensors_fail_each_by_its_key_and_the_other_keys_read_as_the_env_gives_them():
    own, _ = _dict_rollout(_BodiesAndCount(), seed=3, steps=200)
    faults = {"obs.v.noise[1]": 0.5, "obs.w.noise[1]": 0.5, "obs.n.stuck": 1}
    env = ShiftAttributes(_BodiesAndCount(), faults, onset_step=2)
    read, flags = _dict_rollout(env, seed=3, steps=200)
    assert flags == [False] * 3 + [True] * 198 and all(type(r) is dict and r.keys() == own[0].keys() for r in read)
    for before, mine in zip(own[:3], read[:3]):
        assert before["n"] == mine["n"] and (before["v"] == mine["v"]).all() and (before["w"] == mine["w"]).all()
    assert [r["n"] for r in read[3:]] == [2] * 198 and len({o["n"] for o in own[3:]}) == 7  # held at its last reading
    v_noise = np.array([r["v"] - o["v"] for r, o in zip(read[3:], own[3:])])
    w_noise = np.array([r["w"] - o["w"] for r, o in zip(read[3:], own[3:])])
    assert (v_noise[:, 0] == 0).all() and (w_noise[:, 0] == 0).all()  # reading 0 of each as it is
    # 198 draws of std 0.5: their std within 0.5 +- 15% with probability > 0.99; each key its own draws
    assert abs(v_noise[:, 1].std() - 0.5) < 0.075 and abs(w_noise[:, 1].std() - 0.5) < 0.075
    assert abs(np.corrcoef(v_noise[:, 1], w_noise[:, 1])[0, 1]) < 0.2
    again, _ = _dict_rollout(ShiftAttributes(_BodiesAndCount(), faults, onset_step=2), seed=3, steps=200)
    assert all((a["v"] == r["v"]).all() for a, r in zip(again, read))  # the same seed, the same noise
    spec = env.shift.spec
    assert spec == "_BodiesAndCount:obs.n.stuck=1.0,obs.v.noise[1]=0.5,obs.w.noise[1]=0.5"
    assert parse_env_shift(spec).params == (("obs.n.stuck", 1.0), ("obs.v.noise[1]", 0.5), ("obs.w.noise[1]", 0.5))
    with pytest.raises(UnknownParameterError, match=r"_BodiesAndCount \(key 'n'\): 'obs.scale' is no sensor fault of "
                                                    r"discrete values"):
        ShiftAttributes(_BodiesAndCount(), {"obs.n.scale": 2.0})


def _taxi_readings(faults: dict[str, float], seed: int, steps: int, onset: int) -> tuple[list, list, list]:
    """Taxi-v4's own states and the faulted env's readings and shifted flags, the same actions."""
    own_env, faulted = gymnasium.make("Taxi-v4"), ShiftAttributes(gymnasium.make("Taxi-v4"), faults, onset_step=onset)
    own, _ = own_env.reset(seed=seed)
    read, info = faulted.reset(seed=seed)
    owns, reads, flags = [own], [read], [info["shifted"]]
    for action in np.random.default_rng(seed).integers(0, 4, steps):  # moves only: no drop-off ends it
        owns.append(own_env.step(int(action))[0])
        read, _, _, _, info = faulted.step(int(action))
        reads.append(read)
        flags.append(info["shifted"])
    return owns, reads, flags


def test_a_discrete_sensor_miscounts_misreads_and_sticks_from_the_onset_as_the_env_types_its_values():
    owns, biased, flags = _taxi_readings({"obs.bias": 3}, seed=1, steps=30, onset=5)
    assert flags == [False] * 6 + [True] * 25 and biased[:6] == owns[:6]
    assert biased[6:] == [min(own + 3, 499) for own in owns[6:]] and {type(r) for r in biased} == {int}
    owns, stuck, _ = _taxi_readings({"obs.stuck": 1}, seed=1, steps=30, onset=5)
    assert stuck[:6] == owns[:6] and stuck[6:] == [owns[5]] * 25 and len(set(owns[6:])) > 1
    # a misread with probability 0.3, drawn from Taxi's 500 states (499 of them another): over 600
    # faulted steps the share read otherwise lies within 0.3 +- 0.06 with probability > 0.99
    readings = [_taxi_readings({"obs.noise": 0.3}, seed=seed, steps=60, onset=0) for seed in range(10)]
    misread = [r != o for owns, reads, _ in readings for o, r in zip(owns[1:], reads[1:])]
    assert abs(np.mean(misread) - 0.3) < 0.06
    assert all(0 <= r < 500 for _, reads, _ in readings for r in reads)
    assert _taxi_readings({"obs.noise": 0.3}, seed=3, steps=60, onset=0)[1] == readings[3][1]  # seeded by the episode


class _Lights(gymnasium.Env):
    """Two dials of values 1-3 and 0-4 and two lamps, counting up with each step."""

    observation_space = gymnasium.spaces.Dict()  # set per instance below
    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self, space: gymnasium.Space) -> None:
        self.observation_space, self._t = space, 0

    def _obs(self):
        values = np.array([1 + self._t % 3, self._t % 5, self._t % 2, (self._t + 1) % 2])
        return values[:2] if isinstance(self.observation_space, gymnasium.spaces.MultiDiscrete) else values[2:].astype(np.int8)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._t = 0
        return self._obs(), {}

    def step(self, action):
        self._t += 1
        return self._obs(), 0.0, False, False, {}


def test_faults_of_several_discrete_values_keep_each_reading_among_its_own_values():
    dials = gymnasium.spaces.MultiDiscrete([3, 5], start=[1, 0])
    env = ShiftAttributes(_Lights(dials), {"obs.bias[0]": 5, "obs.bias[1]": -1})
    obs, _ = env.reset(seed=0)
    readings = [obs] + [env.step(0)[0] for _ in range(6)]
    assert [r.tolist() for r in readings] == [[3, 0], [3, 0], [3, 1], [3, 2], [3, 3], [3, 0], [3, 0]]
    assert all(r.dtype == np.int64 and dials.contains(r) for r in readings)
    misread = ShiftAttributes(_Lights(dials), {"obs.noise[1]": 1.0})  # the second dial misread at every step
    obs, _ = misread.reset(seed=0)
    readings = np.array([obs] + [misread.step(0)[0] for _ in range(200)])
    assert readings[:, 0].tolist() == [1 + t % 3 for t in range(201)]  # the first dial as it is
    assert sorted(set(readings[:, 1].tolist())) == [0, 1, 2, 3, 4]  # 201 uniform draws of 5 values
    lamps = gymnasium.spaces.MultiBinary(2)
    env = ShiftAttributes(_Lights(lamps), {"obs.stuck[0]": 1, "obs.bias[1]": 1}, onset_step=1)
    obs, _ = env.reset(seed=0)
    readings = [obs] + [env.step(0)[0] for _ in range(4)]
    assert [r.tolist() for r in readings] == [[0, 1], [1, 0], [1, 1], [1, 1], [1, 1]]
    assert all(r.dtype == np.int8 for r in readings)


def test_a_tuple_of_discrete_values_is_faulted_by_element_and_read_back_as_a_tuple_of_ints():
    own, faulted = gymnasium.make("Blackjack-v1"), ShiftAttributes(gymnasium.make("Blackjack-v1"),
                                                                   {"obs.bias[1]": 1, "obs.noise[0]": 1.0})
    hands = [(own.reset(seed=seed)[0], faulted.reset(seed=seed)[0]) for seed in range(300)]
    assert all(type(read) is tuple and [type(v) for v in read] == [int] * 3 for _, read in hands)
    assert all(read[1] == min(hand[1] + 1, 10) and read[2] == hand[2] for hand, read in hands)  # the dealer's card, one up
    # the player's sum misread at every step, drawn uniformly from Discrete(32): each value is missed
    # by 300 draws with probability (31/32)**300 = 7e-5, so all are seen with probability > 0.997
    assert {read[0] for _, read in hands} == set(range(32))
    assert faulted.shift.spec == "Blackjack-v1:obs.bias[1]=1.0,obs.noise[0]=1.0"


@pytest.mark.parametrize(("faults", "error", "message"), [
    ({"obs.scale": 2.0}, UnknownParameterError, r"'obs.scale' is no sensor fault of discrete values; .*KIND one of "
                                                r"bias, noise, stuck"),
    ({"obs.bias": 0.5}, InvalidParameterError, r"obs.bias=0.5 is not allowed; the bias of discrete values is a whole"),
    ({"obs.noise": 1.5}, InvalidParameterError, r"obs.noise=1.5 is not allowed; noise of discrete values is the "
                                                r"probability of a misread, 0-1"),
    ({"obs.stuck[1]": 1}, UnknownParameterError, r"obs.stuck\[1\] is outside the observation, whose 1 readings"),
])
def test_what_a_discrete_sensor_cannot_do_is_refused_saying_why(faults, error, message):
    with pytest.raises(error, match=message):
        ShiftAttributes(gymnasium.make("Taxi-v4"), faults)


def test_an_array_handed_out_as_a_copy_is_refused_since_setting_it_changes_nothing():
    class CopiedMasses(_FallingBodies):
        @property
        def masses(self):
            return self.model.body_mass.copy()

    with pytest.raises(InvalidParameterError, match=r"masses\[1\]=4.0 changed nothing the env reads: its masses hands "
                                                    "out a copy"):
        ShiftAttributes(CopiedMasses(), {"masses[1]": 4.0}, onset_step=1)  # when made, before any episode


class _Wind(gymnasium.Wrapper):
    """A wrapper of the user's that pushes the pendulum: ``wind`` added to each torque; its ``g``
    is a number too, but the env's own ``g`` is the one a shift named ``g`` sets."""

    def __init__(self, env: gymnasium.Env) -> None:
        super().__init__(env)
        self.wind = 0.0
        self.g = 0.0

    def step(self, action):
        return self.env.step(np.asarray(action) + self.wind)


def test_a_number_of_a_wrapper_of_the_users_is_shifted_when_the_env_itself_has_none_of_that_name():
    windy = _Wind(gymnasium.make("Pendulum-v1"))
    env = ShiftAttributes(windy, {"wind": 1.5}, onset_step=5)
    calm = gymnasium.make("Pendulum-v1")
    for episode in range(2):  # the wind drops at each reset, and rises again at the onset
        obs, info = env.reset(seed=episode)
        own, _ = calm.reset(seed=episode)
        assert windy.wind == 0.0 and not info["shifted"]
        for step in range(10):
            obs, _, _, _, info = env.step(np.zeros(1, np.float32))
            own, *_ = calm.step(np.zeros(1, np.float32))
            assert info["shifted"] == (step >= 5) and windy.wind == (1.5 if step >= 5 else 0.0)
            assert np.array_equal(obs, own) == (step < 5)  # the same until the wind blows
    assert env.shift.spec == "Pendulum-v1:wind=1.5"
    env.close()
    assert windy.wind == 0.0
    both = ShiftAttributes(_Wind(gymnasium.make("Pendulum-v1")), {"g": 20.0})
    both.reset(seed=0)
    assert both.unwrapped.g == 20.0 and both.env.g == 0.0  # the env's own number first
    with pytest.raises(UnknownParameterError, match=r"no numeric attribute 'wnd'.*max_speed.*; of its wrapper _Wind: g, wind$"):
        ShiftAttributes(_Wind(gymnasium.make("Pendulum-v1")), {"wnd": 1.0})


def test_attributes_of_a_tasks_env_other_than_its_physics_are_a_shift_of_gymnasiums_id_of_it():
    """`cartpole:theta_threshold_radians=0.1` said "no parameter" and `CartPole-v1:theta_threshold_radians=0.1`
    "give cartpole:theta_threshold_radians=0.1": refused both ways (2026-12-01). A shift of gymnasium's
    id sets it (for a policy of your own there); a misspelt physics name is asked about."""
    from oodmon.envs import Variant, parse_variant

    shift = parse_env_shift("CartPole-v1:theta_threshold_radians=0.1")
    assert shift == EnvShift("CartPole-v1", (("theta_threshold_radians", 0.1),))
    env = shift.make(onset_step=3)
    env.reset(seed=0)
    assert env.unwrapped.theta_threshold_radians == pytest.approx(12 * 2 * np.pi / 360)
    for _ in range(3):
        env.step(0)
    assert env.unwrapped.theta_threshold_radians == pytest.approx(12 * 2 * np.pi / 360)
    env.step(0)  # step 3, the fourth: the first shifted one
    assert env.unwrapped.theta_threshold_radians == 0.1 and variant_of_env(env) == shift.spec
    with pytest.raises(UnknownParameterError, match=r"no parameter 'theta_threshold_radians'.*another attribute of the "
                       r"env is shifted on gymnasium's id of it, CartPole-v1:NAME=VALUE"):
        Variant("cartpole", (("theta_threshold_radians", 0.1),)).make()
    with pytest.raises(UnknownParameterError, match="no parameter 'lenght'.*did you mean 'length'"):
        Variant("cartpole", (("lenght", 2.0),)).make()
    with pytest.raises(UnknownParameterError, match="not oodmon's variants of cartpole.*`oodmon run` or `oodmon "
                       "bench` with --sb3 or --policy and --env CartPole-v1"):
        parse_variant("CartPole-v1:theta_threshold_radians=0.1")
    with pytest.raises(UnknownParameterError, match="named by its task, cartpole:length=2.0"):
        parse_variant("CartPole-v1:length=2.0")
