"""Regenerate docs/cli.md from the click commands: ``python tools/gen_cli_docs.py``."""

from lidarcat.cli.docs import main

if __name__ == "__main__":
    main()
