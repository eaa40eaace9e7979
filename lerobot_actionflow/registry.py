"""Registration of every LeRobot policy and env type this package provides.

LeRobot finds policies by naming convention once their config class is registered with
``PreTrainedConfig.register_subclass``, which happens when the configuration module is
imported. Each later feature adds its module to :data:`PLUGIN_MODULES`.
"""

from __future__ import annotations

import importlib

#: Modules whose import registers a LeRobot config subclass (policy or env type).
PLUGIN_MODULES: tuple[str, ...] = (
    "lerobot_actionflow.policies.actionflow.configuration_actionflow",
    "lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow",
    "lerobot_actionflow.envs.configuration",
)


def register_all() -> tuple[str, ...]:
    """Import every plugin module; returns their names. Idempotent."""
    for name in PLUGIN_MODULES:
        importlib.import_module(name)
    return PLUGIN_MODULES
