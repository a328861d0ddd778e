"""Command-line interface (typer + rich). Heavy imports happen inside commands."""
