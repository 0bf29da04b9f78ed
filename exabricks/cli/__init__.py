"""The `exabricks` command line: one thin module per command, shared options in options.py."""
