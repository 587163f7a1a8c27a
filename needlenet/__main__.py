"""``python -m needlenet`` is the ``needlenet`` command."""

import sys

from .cli import main

sys.exit(main())
