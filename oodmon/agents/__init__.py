"""What acts: uncertainty-aware DQN and DDPG policies (MC Dropout, MC DropConnect, ensembles).

Not built yet: see the agents issue. The subpackage exists so that the package's layout, and the
direction of imports (envs -> agents -> monitor -> replay), is fixed from the start.
"""

__all__: list[str] = []
