"""``python -m plantbench.runner CACHE KIND KEY FOLDER PARAMS``: one job in its own process
(:func:`plantbench.runner.worker.main`). The executor starts jobs through the package rather than ``-m
plantbench.runner.worker``, which the package's own imports have already loaded (runpy warns about that in every
job log)."""

import sys

from plantbench.runner.worker import main

sys.exit(main(sys.argv[1:]))
