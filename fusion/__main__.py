"""``python -m fusion`` runs the command line."""

from fusion.cli import main

raise SystemExit(main())
