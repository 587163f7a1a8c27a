"""``python -m needlenet.cli`` is the ``needlenet`` command, as ``python -m needlenet`` is."""

import sys

from . import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
