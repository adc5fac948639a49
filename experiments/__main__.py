"""``python -m experiments``: the ``startracker-gym`` command line."""

from experiments.cli import main

raise SystemExit(main())
