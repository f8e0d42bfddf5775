"""``python -m covviz.cli``: the same as the ``covviz`` command."""

import sys

from covviz.cli import main

sys.exit(main())
