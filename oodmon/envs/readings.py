"""The names of the readings of envs whose observation layout gymnasium documents, by index.

An alarm names the readings whose change the dynamics model predicted worst by their index in the
observation (:attr:`~oodmon.monitor.alarms.AlarmEvent.readings`, ``[2]``, as a sensor fault's spec
names them, ``obs.stuck[2]``); where the env is one of these, its line adds the reading's name
(``[2] (pole angle)``). oodmon's CartPole and Pendulum read as gymnasium's do.
"""

from __future__ import annotations

__all__ = ["READING_NAMES", "reading_names"]

#: Each env's readings by index (gymnasium 1.x's classic-control docs), by id without a namespace.
READING_NAMES: dict[str, tuple[str, ...]] = {
    "CartPole-v1": ("cart position", "cart velocity", "pole angle", "pole angular velocity"),
    "Pendulum-v1": ("cos of the angle", "sin of the angle", "angular velocity"),
    "Acrobot-v1": ("cos of joint 1's angle", "sin of joint 1's angle", "cos of joint 2's angle",
                   "sin of joint 2's angle", "joint 1's angular velocity", "joint 2's angular velocity"),
    "MountainCar-v0": ("car position", "car velocity"),
    "MountainCarContinuous-v0": ("car position", "car velocity"),
}
READING_NAMES["CartPole-v0"] = READING_NAMES["CartPole-v1"]


def reading_names(env_id: str | None) -> tuple[str, ...]:
    """The names of ``env_id``'s readings by index (``oodmon/CartPole-v1`` reads as
    ``CartPole-v1``); empty for an env whose layout is not listed here.

    Example:
        >>> reading_names("oodmon/CartPole-v1")[2], reading_names("my_envs:MyEnv-v0"), reading_names(None)
        ('pole angle', (), ())
    """
    if not isinstance(env_id, str):
        return ()
    return READING_NAMES.get(env_id.rpartition("/")[2], ())
