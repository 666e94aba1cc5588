"""Sub-commands of the ``helicalib`` CLI: one module each, with ``register(subparsers)``.

A module's ``register`` adds its parser and sets ``func`` to a handler ``(args) -> int``.
Keep heavy imports inside the handler so ``helicalib --help`` stays fast.
"""
