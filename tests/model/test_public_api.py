import subprocess
import sys

import lumos3d_cli
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import Lumos3DOutput, build_model


def test_the_network_api_is_re_exported_from_the_package():
    assert lumos3d_cli.build_model is build_model and lumos3d_cli.load_model is load_model
    assert lumos3d_cli.Lumos3DOutput is Lumos3DOutput
    assert {"build_model", "load_model", "save_checkpoint", "summarize_checkpoint"} <= set(dir(lumos3d_cli))


def test_importing_the_package_does_not_import_torch():
    code = "import sys, lumos3d_cli; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"
