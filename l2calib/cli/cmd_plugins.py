"""``l2calib plugins``: list every plugin group, name and the distribution that provides it."""

from __future__ import annotations

import typer


def plugins() -> None:
    """List installed plugins (backends, references, policies) with their distributions."""
    from rich.console import Console
    from rich.table import Table

    from l2calib.errors import PluginError
    from l2calib.plugins import GROUPS, discover

    table = Table(title="l2calib plugins")
    for col in ("group", "name", "distribution", "description"):
        table.add_column(col)
    problems = []
    for group in GROUPS:
        try:
            found = discover(group)
        except PluginError as exc:
            problems.append(str(exc))
            continue
        if not found:
            table.add_row(group, "[dim]none installed[/dim]", "", "")
        for name, (spec, dist) in found.items():
            table.add_row(group, name, dist or "?", spec.description)
    console = Console()
    console.print(table)
    if problems:
        raise PluginError("; ".join(problems), fix="see the messages above for each plugin")


def register(app: typer.Typer) -> None:
    """Adds the command to ``app``."""
    app.command("plugins")(plugins)
