"""`python -m ftcgym.cli` runs the `ftcgym` command line."""
import sys

from ftcgym.cli import main

sys.exit(main())
