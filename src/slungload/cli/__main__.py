"""``python -m slungload.cli``: the ``slungload`` command."""

import sys

from . import main

sys.exit(main())
