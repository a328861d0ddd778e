"""``l2calib recipe dump|check``: print a complete recipe, or validate one."""

from __future__ import annotations

from pathlib import Path

import typer

recipe_app = typer.Typer(help="Print or check calibration recipes.", no_args_is_help=True)

_SET_HELP = "Override a field, e.g. --set train.seed=3 (repeatable)."


@recipe_app.command("dump")
def dump(
    recipe: Path | None = typer.Argument(None, help="Recipe to start from (default: built-in)."),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
) -> None:
    """Print a complete recipe (every key with its default) as YAML."""
    from l2calib.recipe import dump_recipe, filled_plugin_options, load_recipe, recipe_source

    loaded = load_recipe(recipe, set_, check_plugins=False)
    filled, notices = filled_plugin_options(loaded, recipe_source(recipe), list(set_))
    for notice in notices:
        typer.echo(f"# note: {notice}", err=True)
    typer.echo(dump_recipe(filled), nl=False)


@recipe_app.command("check")
def check(
    recipe: Path = typer.Argument(..., help="Recipe YAML file."),
    set_: list[str] = typer.Option([], "--set", help=_SET_HELP),
) -> None:
    """Validate a recipe, including each plugin's options."""
    from l2calib.recipe import load_recipe

    load_recipe(recipe, set_, check_plugins=True)
    typer.echo(f"{recipe}: ok")


def register(app: typer.Typer) -> None:
    """Adds the ``recipe`` command group to ``app``."""
    app.add_typer(recipe_app, name="recipe")
