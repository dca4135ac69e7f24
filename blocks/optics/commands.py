"""Command-line sub-commands contributed by the optics stage (see evsda.graph.commands)."""

COMMANDS: list = []
