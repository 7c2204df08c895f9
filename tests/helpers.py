"""Helpers shared by the tests."""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import time
import warnings
from pathlib import Path

import gymnasium
import numpy as np

#: The README and the pages of docs/: what a reader reads, what tests/test_docs.py and the
#: shell-block test of tests/test_cli.py read.
DOC_PAGES = [Path(__file__).resolve().parents[1] / "README.md",
             *sorted((Path(__file__).resolve().parents[1] / "docs").glob("*.md"))]


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """``oodmon ARGS`` run in this process, its output captured as a subprocess's would be.

    In-process saves the 3-4 s a new interpreter spends importing torch, per call; ``python -m
    oodmon`` itself is run as a subprocess by tests/test_cli.py. Warnings are printed to the
    captured stderr every time, as a fresh process would print them.
    """
    from oodmon.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.filterwarnings("error", category=DeprecationWarning, module="oodmon.*")
        warnings.showwarning = lambda message, category, filename, lineno, file=None, line=None: sys.stderr.write(
            warnings.formatwarning(message, category, filename, lineno, line))
        code = main(list(args))
    return subprocess.CompletedProcess(["oodmon", *args], code, out.getvalue(), err.getvalue())


def run_as_written(commands: list[list[str]], folder, monkeypatch, *, python_path, module: str) -> None:
    """A README shell block's oodmon commands run as a user runs them: from ``folder``, with
    ``python_path`` on the import path (the block's ``export PYTHONPATH=``) and ``module`` (the one
    its ``--policy`` names) imported afresh; each must exit 0."""
    from oodmon.cli import main

    monkeypatch.chdir(folder)
    monkeypatch.syspath_prepend(str(python_path))
    monkeypatch.delitem(sys.modules, module, raising=False)
    for argv in commands:
        assert main(argv) == 0, argv


def blas_threads() -> set[int]:
    """The threads of every BLAS loaded in this process (numpy's, opencv's, scipy's OpenBLAS)."""
    from threadpoolctl import threadpool_info

    return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}


def once_per_run(tmp_path_factory, worker_id: str, name: str, make):
    """``make(folder)``'s JSON-able result, computed once for the whole run: pytest-xdist's workers
    each run a module-scoped fixture of the tests they take (``--dist worksteal`` splits a module's
    tests among them), so a fixture of seconds ran twice in ``make test``. The first worker computes
    it into a folder of the run's temporary directory, under a lock; the others wait and read it
    (pytest-xdist's own recipe for a fixture run once). Without workers, ``make`` runs as a fixture."""
    import json

    if worker_id == "master":
        return make(tmp_path_factory.mktemp(name))
    from filelock import FileLock  # (torch's dependency)

    root = tmp_path_factory.getbasetemp().parent  # this run's, shared by its workers
    done = root / name / "result.json"
    with FileLock(str(root / f"{name}.lock")):
        if not done.is_file():
            done.parent.mkdir(exist_ok=True)  # (a worker whose make failed left it)
            done.write_text(json.dumps(make(done.parent)))
    return json.loads(done.read_text())


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, killed and not yet reaped, does not; Linux's /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def wait_until_dead(pid: int, seconds: float = 10.0) -> bool:
    """Whether process ``pid`` stops running within ``seconds`` (a signal acts at once: this waits
    for it, not for a duration)."""
    deadline = time.monotonic() + seconds
    while alive(pid):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def load_script(name: str):
    """The repository's root and scripts/<name>.py loaded as a module (the scripts' own imports of
    each other need scripts/ on sys.path: pytest's ``monkeypatch.syspath_prepend``)."""
    import importlib.util
    from pathlib import Path

    import oodmon

    root = Path(oodmon.__file__).parent.parent
    spec = importlib.util.spec_from_file_location(name, root / "scripts" / f"{name}.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return root, script


class RandomButtons:
    """A plain policy pressing Pong's six buttons at random (any policy: the picture detectors read
    the picture, not the policy)."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs) -> int:
        return int(self.rng.integers(6))


def ball_pictures(xs, *, hidden=range(0), size=(20, 40)):
    """A ``Trajectory`` of a 2x2 ball on a grey picture with a bright wall along its top row, at
    columns ``xs`` of rows 6-7 (tile row 1 of 4), not drawn at the columns in ``hidden``: what the
    vanishing detector's tests fit and score."""
    from oodmon.monitor.detectors import Trajectory

    frames = []
    for x in xs:
        frame = np.full(size, 50, np.uint8)
        frame[0] = 200
        if x not in hidden:
            frame[6:8, x:x + 2] = 255
        frames.append(frame)
    return Trajectory(np.array(frames), np.zeros(len(frames) - 1, np.int64))


#: A ball across a 40-pixel picture and back, 3 columns a step, three times (:func:`ball_pictures`).
RALLY = [*range(0, 38, 3), *range(37, -1, -3)] * 3


def scores_along(detector, trajectory) -> list[float]:
    """A detector's score at each acted-on step of ``trajectory`` (a ``Trajectory``), from a reset,
    each step with its action and the one before, as the monitor gives them."""
    from oodmon.monitor.detectors import StepContext

    detector.reset()
    before = [None, *trajectory.actions[:-1]]
    return [detector.score(StepContext(obs, action, prev_action=prev))
            for obs, action, prev in zip(trajectory.observations[:-1], trajectory.actions, before)]


class NoisePictures(gymnasium.Env):
    """RGB pictures of noise (channels last, ``shape``), ``steps`` steps an episode, two actions:
    an env of image observations for the tests of users' own models."""

    action_space = gymnasium.spaces.Discrete(2)

    def __init__(self, shape: tuple[int, int, int] = (40, 40, 3), steps: int = 30) -> None:
        self.shape, self.steps = shape, steps
        self.observation_space = gymnasium.spaces.Box(0, 255, shape, np.uint8)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.integers(0, 256, self.shape, dtype=np.uint8), {}

    def step(self, action):
        self.t += 1
        return self.np_random.integers(0, 256, self.shape, dtype=np.uint8), 1.0, False, self.t >= self.steps, {}


class ActedOn(gymnasium.Wrapper):
    """Records the observation each action was taken on (after an episode's end, the next one's
    first), a copy (of a dict, its keys)."""

    def __init__(self, env: gymnasium.Env, acted: list) -> None:
        super().__init__(env)
        self.acted, self.current = acted, None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.current = obs.copy()
        return obs, info

    def step(self, action):
        self.acted.append(self.current)
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.current = obs.copy()
        return obs, reward, terminated, truncated, info


def tear_inside_episode_one(monitor, env, variant: str, folder, memory, steps: int = 40):
    """Begin episode 1 of ``env`` (seed 1, onset 20), play ``steps`` steps that must not end it,
    copy ``folder/run.mcap`` as a kill would leave it to ``folder/torn.mcap``, and close the
    monitor. Returns the torn log as replay reads it (its RecoveryWarning checked: the running
    episode kept from its ``steps`` steps on disk) and the monitor's own step records of episode 1
    (``memory``, a MemorySink of the monitor)."""
    import shutil

    import pytest

    from oodmon.replay import RecoveryWarning, read_log

    obs, info = env.reset(seed=1)
    monitor.begin_episode(env_id="oodmon/CartPole-v1", variant=variant, onset=20, seed=1)
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(monitor.step(obs, shifted=info["shifted"]))
        monitor.add_reward(reward)
        assert not (terminated or truncated)
    shutil.copy(folder / "run.mcap", folder / "torn.mcap")  # the file as a kill would leave it
    monitor.close()
    with pytest.warns(RecoveryWarning, match=f"the running episode 1 is kept as interrupted from its {steps} steps on disk"):
        log = read_log(folder / "torn.mcap")
    return log, [s for s in memory.steps if s.episode == 1]


def saved_ensemble_acts_as_its_members(models, tmp_path, env_id: str, steps: int):
    """``models`` saved and loaded as one agent (``load_sb3``): an ensemble whose samples are each
    model's predict(deterministic=True) and whose first model acts, step by step over ``steps``
    steps of ``env_id`` from seed 0. Returns the saved files' paths."""
    from oodmon.agents.sb3 import load_sb3

    paths = [tmp_path / f"member{k}.zip" for k in range(len(models))]
    for model, path in zip(models, paths):
        model.save(path)
    agent = load_sb3(paths, env_id)
    assert agent.estimator is not None and agent.estimator.n_samples == len(models)
    env = gymnasium.make(env_id)
    obs, _ = env.reset(seed=0)
    for _ in range(steps):
        theirs = [m.predict(obs, deterministic=True)[0] for m in models]
        np.testing.assert_allclose(agent.estimate(obs).samples[:, 0], theirs, rtol=1e-5, atol=1e-5)
        assert np.array_equal(agent.act(obs), theirs[0])  # the first model acts
        obs, *_ = env.step(agent.act(obs))
    return paths
