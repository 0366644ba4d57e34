"""``hil`` subcommands: a module with ``register(app)`` adds its commands (see :mod:`hil.cli`)."""
