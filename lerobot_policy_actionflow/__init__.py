"""LeRobot plugin entry point.

`lerobot.utils.import_utils.register_third_party_plugins()` (run first by `lerobot-train`,
`lerobot-eval` and LeRobot's other CLIs) imports this module because the installed
distribution is named `lerobot_policy_actionflow`. Importing it registers all of
lerobot-actionflow's policy and env types; the library itself is `lerobot_actionflow`.
"""

from lerobot_actionflow.registry import register_all

REGISTERED = register_all()
