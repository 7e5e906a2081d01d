"""``python -m xviz_server``: the ``xviz-server`` command."""

import sys

from .cli import main

sys.exit(main())
