"""Command-line sub-commands contributed by the readout stage (see evsda.graph.commands)."""

COMMANDS: list = []
