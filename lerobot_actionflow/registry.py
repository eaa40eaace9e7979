"""Registration of every LeRobot policy, env and robot type (and processor step) this package
provides.

LeRobot finds policies by naming convention once their config class is registered with
``PreTrainedConfig.register_subclass``, which happens when the configuration module is
imported. Each later feature adds its module to :data:`PLUGIN_MODULES`.
"""

from __future__ import annotations

import importlib

#: Modules whose import registers a LeRobot config subclass (policy, env or robot type) or a
#: processor step that saved pipelines name.
PLUGIN_MODULES: tuple[str, ...] = (
    "lerobot_actionflow.policies.actionflow.configuration_actionflow",
    "lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow",
    "lerobot_actionflow.envs.configuration",
    "lerobot_actionflow.robots.actionflow_sim.config_actionflow_sim",
    "lerobot_actionflow.robots.processor",
)


def register_all() -> tuple[str, ...]:
    """Import every plugin module; returns their names. Idempotent."""
    for name in PLUGIN_MODULES:
        importlib.import_module(name)
    return PLUGIN_MODULES
