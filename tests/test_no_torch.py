"""The runtime imports and runs without torch."""

import subprocess
import sys


def test_needlenet_imports_without_torch():
    code = (
        "import importlib.abc, sys\n"
        "class Absent(importlib.abc.MetaPathFinder):\n"  # torch and lightning are not there
        "    def find_spec(self, name, path, target=None):\n"
        "        if name.split('.')[0] in ('torch', 'lightning', 'onnx'):\n"
        "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
        "sys.meta_path.insert(0, Absent())\n"
        "import importlib, pkgutil, needlenet, synth\n"
        "for m in pkgutil.walk_packages(needlenet.__path__, 'needlenet.'):\n"
        "    importlib.import_module(m.name)\n"  # every runtime module, __main__ included

        "from needlenet.cli import main\n"
        "assert main(['synth', '--list']) == 0\n"
        "rc = main(['train', 'inplane'])\n"
        "assert rc == 2, rc\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "training extra" in r.stderr
