"""``python -m shapeviewer``: the ``shapeviewer`` command."""

import sys

from .cli import main

sys.exit(main())
