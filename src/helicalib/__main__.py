"""``python -m helicalib`` runs the command-line interface."""

from helicalib.cli import main

raise SystemExit(main())
