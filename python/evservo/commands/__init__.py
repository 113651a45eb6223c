"""Subcommands of the ``evservo`` command line, one module each. Every module exposes
``add_parser(subparsers)``, which registers its command and sets ``func`` to the handler
(``handler(args) -> int`` exit code)."""
