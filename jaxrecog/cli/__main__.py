"""``python -m jaxrecog.cli``: the ``jaxrecog`` command."""

import sys

from . import main

sys.exit(main())
