"""``python -m formation_bench.cli``: the ``formation-bench`` command."""

import sys

from formation_bench.cli.main import main

sys.exit(main())
