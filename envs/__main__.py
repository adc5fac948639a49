"""``python -m envs``: the ``startracker-gym`` command line (a shim; the commands live in ``experiments``)."""

from experiments.cli import main

raise SystemExit(main())
