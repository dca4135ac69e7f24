"""Command-line sub-commands contributed by the scene stage (see evsda.graph.commands)."""

COMMANDS: list = []
