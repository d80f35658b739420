"""Command-line commands: each module parses its arguments and calls plain functions.

Every module here exposes ``register(subparsers)``, which adds its sub-command(s) with a
``func`` default taking the parsed ``argparse.Namespace`` and returning an exit status.
"""
