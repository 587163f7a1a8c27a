"""The runtime imports and runs without torch."""

import subprocess
import sys


def test_needlenet_imports_without_torch():
    code = (
        "import sys\n"
        "sys.modules['torch'] = None\n"  # any 'import torch' now fails
        "sys.modules['lightning'] = None\n"
        "import needlenet, needlenet.cli, needlenet.features, needlenet.trackers\n"
        "import needlenet.backends, needlenet.eval, needlenet.io, synth\n"
        "from needlenet.cli import main\n"
        "assert main(['synth', '--list']) == 0\n"
        "rc = main(['train', 'inplane'])\n"
        "assert rc == 2, rc\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "training extra" in r.stderr
