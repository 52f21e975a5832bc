"""Serve the shape-completion viewer: ``python app.py [--port 8080] [--seed N] [--cloud PATH] [--weights PATH]``.

The same as ``shapeviewer serve``; run ``python app.py --help`` for every option.
"""

import sys

from shapeviewer.cli import main

if __name__ == "__main__":
    sys.exit(main(["serve", *sys.argv[1:]]))
