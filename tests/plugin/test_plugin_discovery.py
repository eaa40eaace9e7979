"""LeRobot's own plugin scan must import our package, with no flags."""

import subprocess
import sys


def test_register_third_party_plugins_imports_our_package():
    # A fresh interpreter, so that nothing imported by the test session hides a failure.
    code = (
        "import sys\n"
        "from lerobot.utils.import_utils import register_third_party_plugins\n"
        "assert 'lerobot_policy_actionflow' not in sys.modules\n"
        "register_third_party_plugins()\n"
        "assert 'lerobot_policy_actionflow' in sys.modules, 'plugin scan did not import us'\n"
        "import lerobot_policy_actionflow as p\n"
        "from lerobot.configs.policies import PreTrainedConfig\n"
        "assert {'actionflow', 'euclidean_flow'} <= set(PreTrainedConfig.get_known_choices())\n"
        "from lerobot.envs.configs import EnvConfig\n"
        "assert 'actionflow' in EnvConfig.get_known_choices()\n"
        "from lerobot.robots.config import RobotConfig\n"
        "assert 'actionflow_sim' in RobotConfig.get_known_choices()\n"
        "print('registered:', ','.join(p.REGISTERED))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "registered:" in out.stdout


def test_distribution_name_is_importable_as_is():
    """The scan imports the distribution's metadata Name verbatim: it must be a module name."""
    import importlib.metadata as md

    name = md.metadata("lerobot_policy_actionflow")["Name"]
    assert name == "lerobot_policy_actionflow"
    assert name.startswith("lerobot_policy_")
