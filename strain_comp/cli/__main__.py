"""``python -m strain_comp.cli``: the ``strain-comp`` command line."""

import sys

from strain_comp.cli import main

sys.exit(main())
