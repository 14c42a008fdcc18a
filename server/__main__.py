"""``python -m server``: the ``ergoseek`` command without the installed script."""

import sys

from server.cli import main

sys.exit(main())
