"""CLI commands, one module each; see ``orange_plan.cli.COMMAND_MODULES``."""
