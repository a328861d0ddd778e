"""Recipes: one YAML per sensor suite, validated by pydantic.

A recipe names the plugins to use (reference, backend, policy) with their options, the topics
and units of the input, the data selection and the training settings. Unknown keys and bad values
fail with the dotted field path. ``l2calib recipe dump`` prints a complete default recipe.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import Field, ValidationError

from l2calib.config_base import StrictModel
from l2calib.errors import ConfigError, PluginError
from l2calib.recipe_train import TrainConfig

log = logging.getLogger(__name__)


class LidarInput(StrictModel):
    """Where and how to read the LiDAR."""

    topic: str = Field("/points", description="sensor_msgs/PointCloud2 or livox CustomMsg topic")
    time_field: str | None = Field(
        None, description="per-point time field (t, time, timestamp, offset_time); null: detect"
    )
    time_unit: Literal["auto", "s", "ms", "us", "ns"] = "auto"
    time_reference: Literal["auto", "relative", "absolute"] = Field(
        "auto", description="per-point times relative to the header stamp, or absolute"
    )
    stamp_position: Literal["auto", "start", "end"] = Field(
        "auto", description="whether the header stamp marks the scan start or end"
    )
    min_range_m: float = Field(0.5, gt=0)
    max_range_m: float = Field(120.0, gt=0)


class ImuInput(StrictModel):
    """Where and how to read the IMU, and its noise (continuous-time densities)."""

    topic: str = Field("/imu", description="sensor_msgs/Imu topic")
    gyro_unit: Literal["auto", "rad/s", "deg/s"] = "auto"
    accel_unit: Literal["auto", "m/s^2", "g"] = "auto"
    gyro_noise_density: float = Field(1.7e-4, gt=0, description="rad/s/sqrt(Hz)")
    accel_noise_density: float = Field(2.0e-3, gt=0, description="m/s^2/sqrt(Hz)")
    gyro_bias_random_walk: float = Field(2.0e-5, gt=0, description="rad/s^2/sqrt(Hz)")
    accel_bias_random_walk: float = Field(3.0e-4, gt=0, description="m/s^3/sqrt(Hz)")
    gravity_m_s2: float = Field(9.81, gt=0)


class DataConfig(StrictModel):
    """Input topics, units and conventions."""

    lidar: LidarInput = Field(default_factory=LidarInput)
    imu: ImuInput = Field(default_factory=ImuInput)
    rtk_topic: str | None = Field(None, description="sensor_msgs/NavSatFix topic (rtk reference)")


class SelectionConfig(StrictModel):
    """Data selection by IMU excitation (paper Sec. III-D)."""

    enabled: bool = True
    window_s: float = Field(10.0, gt=0, description="window length (s)")
    step_s: float = Field(1.0, gt=0, description="stride between windows (s)")
    budget_s: float = Field(30.0, gt=0, description="total length of the selection (s)")
    planar_budget_s: float | None = Field(
        60.0,
        gt=0,
        description="on planar, yaw-dominant motion (a ground vehicle: train.planar_min_yaw_"
        "share) the selection keeps at least this much (s; the whole drive when shorter): a "
        "drive's turns are few, and they are what determines the horizontal lever arm; null: "
        "budget_s as on any data",
    )
    planar_window_s: float = Field(
        10.0, gt=0, description="shortest window on planar motion (s): long enough for a turn"
    )
    min_gyro_rad_s: float = Field(
        0.2, gt=0, description="per-axis RMS angular rate below which an axis is weak (rad/s)"
    )
    min_accel_m_s2: float = Field(
        0.3,
        gt=0,
        description="per-axis RMS gravity-free acceleration below which an axis is weak (m/s^2)",
    )


class PluginChoice(StrictModel):
    """A plugin by name with its options (validated against the plugin's config model)."""

    name: str
    options: dict[str, Any] = Field(default_factory=dict)


class ReferenceChoice(PluginChoice):
    """The reference plugin, plus an optional fallback for data on which it loses track."""

    fallback: PluginChoice | None = Field(
        None,
        description="reference computed instead when this one loses track on the data (e.g. "
        "ct-lidar on some 16-beam motion); a warning names it. Dropped when reference.name is "
        "overridden",
    )


class ExtrinsicPrior(StrictModel):
    """An initial guess of ``T_imu_lidar`` with its uncertainty."""

    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="roll, pitch, yaw; R = Rz(yaw) Ry(pitch) Rx(roll)"
    )
    sigma_translation_m: float = Field(0.1, gt=0)
    sigma_rotation_deg: float = Field(10.0, gt=0)

    def T_imu_lidar(self) -> Any:
        """The guess as a homogeneous transform ``[4, 4]`` (numpy, float64, LiDAR → IMU)."""
        import torch

        from l2calib import geometry as geo

        rpy = torch.deg2rad(torch.tensor(self.rpy_deg, dtype=torch.float64))
        t = torch.tensor(self.translation_m, dtype=torch.float64)
        return geo.make_transform(geo.euler_rpy_to_matrix(rpy), t).numpy()


class PolicyChoice(PluginChoice):
    """The policy plugin, plus an optional prior (none = start from no initial guess)."""

    name: str = "bingham"
    prior: ExtrinsicPrior | None = None


class RewardConfig(StrictModel):
    """Which reward turns trajectory agreement into a score."""

    kind: Literal["paper", "position"] = "paper"
    align: Literal["auto", "se3", "sim3", "none"] = Field(
        "auto",
        description="alignment of the reference onto each estimate: auto = none when the backend "
        "already outputs in the reference's frame, else se3 (Umeyama, as the paper)",
    )
    max_gap_s: float = Field(0.2, gt=0, description="largest reference gap to interpolate over")


def _reference() -> ReferenceChoice:
    return ReferenceChoice(name="kiss-icp")


def _backend() -> PluginChoice:
    return PluginChoice(name="iekf")


class Recipe(StrictModel):
    """A complete calibration recipe for one sensor suite."""

    name: str = "default"
    description: str = ""
    data: DataConfig = Field(default_factory=DataConfig)
    selection: SelectionConfig = Field(default_factory=SelectionConfig)
    reference: ReferenceChoice = Field(default_factory=_reference)
    backend: PluginChoice = Field(default_factory=_backend)
    policy: PolicyChoice = Field(default_factory=PolicyChoice)
    reward: RewardConfig = Field(default_factory=RewardConfig)
    train: TrainConfig = Field(default_factory=TrainConfig)


PLUGIN_SECTIONS = {
    "reference": "l2calib.references",
    "backend": "l2calib.backends",
    "policy": "l2calib.policies",
}
_NAME_KEYS = {f"{section}.name" for section in PLUGIN_SECTIONS}


# --------------------------------------------------------------------------- errors
def _override_for(path: str, overrides: list[str]) -> str | None:
    """The ``--set`` item that wrote field ``path`` (or switched its plugin), if any.

    The last one wins, as when applying them.
    """
    for item in reversed(overrides):
        key = item.partition("=")[0].strip()
        if path == key or path.startswith(key + ".") or key.startswith(path + "."):
            return item
        if key in _NAME_KEYS and path.startswith(key.split(".")[0] + "."):
            return item  # the options of a plugin the --set switched to
    return None


def _format_validation(
    exc: ValidationError, source: str, prefix: str = "", overrides: list[str] | None = None
) -> ConfigError:
    """One :class:`ConfigError` naming every bad field and where it came from.

    A field written (or made necessary) by a ``--set`` is attributed to that ``--set``, not to
    the recipe file.
    """
    lines, missing = [], []
    for err in exc.errors():
        path = ".".join(str(p) for p in (*filter(None, [prefix]), *err["loc"]))
        got = err.get("input")
        got_text = "" if err["type"] == "missing" or isinstance(got, dict) else f" (got {got!r})"
        msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
        item = _override_for(path, list(overrides or []))
        origin = f"--set {item}" if item is not None else source
        lines.append(f"{origin}: {path}: {msg}{got_text}")
        if err["type"] == "missing":
            missing.append(path)
    fix = "correct these fields (see `l2calib recipe dump` for every key and its default)"
    if missing:
        fix = (
            "give " + ", ".join(missing) + " in the recipe or with "
            + " ".join(f"--set {m}=VALUE" for m in missing)
            + " (`l2calib plugins` lists each plugin's options)"
        )  # fmt: skip
    return ConfigError("; ".join(lines), fix=fix)


# --------------------------------------------------------------------------- overrides
def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Applies ``a.b=c`` overrides to a nested dict; values are parsed as YAML scalars/lists.

    An override that switches a plugin (``reference.name=ct-lidar`` on a kiss-icp recipe) drops
    the file's ``options`` of that section, written for the other plugin, with a logged notice;
    ``<section>.options.*`` overrides (in any order) then apply to the new plugin.
    """
    names = [o for o in overrides if o.partition("=")[0].strip() in _NAME_KEYS]
    for item in names:
        section = item.partition("=")[0].strip().split(".")[0]
        before = data.get(section)
        old_name = before.get("name") if isinstance(before, dict) else None
        new_name = _set(data, item)
        if old_name not in (None, new_name) and "options" in data[section]:
            dropped = data[section].pop("options")
            log.info(
                "%s.name=%s replaces %s: the recipe's %s.options (%s) are not used",
                section, new_name, old_name, section, ", ".join(map(str, dropped or {})),
            )  # fmt: skip
        if old_name not in (None, new_name) and data[section].pop("fallback", None):
            log.info(
                "%s.name=%s replaces %s: its fallback is not used", section, new_name, old_name
            )
    for item in overrides:
        if item not in names:
            _set(data, item)
    return data


def _set(data: dict[str, Any], item: str) -> Any:
    """Applies one ``a.b=c`` override in place; returns the parsed value."""
    key, sep, raw = item.partition("=")
    if not sep or not key.strip():
        raise ConfigError(
            f"override {item!r} is not of the form key=value",
            fix="write e.g. --set train.seed=3",
        )
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    node = data
    parts = key.strip().split(".")
    for part in parts[:-1]:
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ConfigError(f"override {item!r}: {part!r} is not a section")
        node = child
    node[parts[-1]] = value
    return value


# --------------------------------------------------------------------------- load / dump
def recipe_from_dict(
    data: dict[str, Any],
    source: str = "recipe",
    check_plugins: bool = True,
    overrides: list[str] | None = None,
) -> Recipe:
    """Validates a recipe dict (and, if asked, each plugin's options).

    ``overrides`` are the ``--set`` items applied to ``data``: errors in fields they wrote name
    them as the source instead of ``source``.
    """
    try:
        recipe = Recipe.model_validate(data)
    except ValidationError as exc:
        raise _format_validation(exc, source, overrides=overrides) from None
    if check_plugins:
        validate_plugin_options(recipe, source, overrides)
    return recipe


BUILTIN_DIR = Path(__file__).parent / "recipes"


def builtin_recipes() -> dict[str, Path]:
    """Recipes shipped with l2calib (also in the repository's ``recipes/``), by name."""
    return {p.stem: p for p in sorted(BUILTIN_DIR.glob("*.yaml"))}


def resolve_recipe_path(path: str | Path) -> Path:
    """``path`` itself if it is a file, else the built-in recipe of that name."""
    p = Path(path)
    if p.is_file():
        return p
    builtin = builtin_recipes()
    if str(path) in builtin:
        return builtin[str(path)]
    raise ConfigError(
        f"{path}: no such recipe file or built-in recipe",
        fix=f"check the path, or use one of: {', '.join(builtin) or 'none'}",
    )


def recipe_source(path: str | Path | None) -> str:
    """How errors name a recipe: its file, or ``default recipe``."""
    return "default recipe" if path is None else str(resolve_recipe_path(path))


def load_recipe(
    path: str | Path | None, overrides: list[str] | None = None, check_plugins: bool = True
) -> Recipe:
    """Loads a recipe, applies overrides and validates it.

    ``path`` is a YAML file, the name of a built-in recipe, or ``None`` for the defaults.
    """
    data: dict[str, Any] = {}
    source = "default recipe"
    if path is not None:
        path = resolve_recipe_path(path)
        source = str(path)
        try:
            loaded = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f":{mark.line + 1}" if mark else ""
            raise ConfigError(f"{path}{where}: not valid YAML ({exc})") from None
        if loaded is None:
            raise ConfigError(
                f"{path}: the recipe file is empty",
                fix="start from a complete one: `l2calib recipe dump simulator > "
                f"{path.name}`, then edit it",
            )
        if not isinstance(loaded, dict):
            raise ConfigError(
                f"{path}: a recipe must be a YAML mapping, got {type(loaded).__name__}"
            )
        data = loaded
    data = apply_overrides(data, list(overrides or []))
    return recipe_from_dict(data, source, check_plugins, list(overrides or []))


def validate_plugin_options(
    recipe: Recipe, source: str = "recipe", overrides: list[str] | None = None
) -> Recipe:
    """Checks every plugin's options against its config model (imports only spec modules).

    ``overrides``: the ``--set`` items applied, named as the source of the fields they wrote.
    """
    from l2calib.plugins import get_plugin

    choices = [(s, g, getattr(recipe, s)) for s, g in PLUGIN_SECTIONS.items()]
    if recipe.reference.fallback is not None:
        choices.append(("reference.fallback", "l2calib.references", recipe.reference.fallback))
    for section, group, choice in choices:
        try:
            spec = get_plugin(group, choice.name)
        except PluginError as exc:
            item = _override_for(f"{section}.name", list(overrides or []))
            origin = f"--set {item}" if item is not None else source
            raise ConfigError(f"{origin}: {section}.name: {exc.message}", fix=exc.fix) from None
        try:
            spec.config.model_validate(choice.options)
        except ValidationError as exc:
            raise _format_validation(exc, source, f"{section}.options", overrides) from None
    return recipe


def filled_plugin_options(
    recipe: Recipe, source: str = "recipe", overrides: list[str] | None = None
) -> tuple[Recipe, list[str]]:
    """Returns the recipe with every plugin's options completed by its defaults.

    Args:
        recipe: The validated recipe.
        source: Where it came from (named in errors).
        overrides: The ``--set`` items applied (named in errors about the fields they wrote).

    Returns:
        The completed recipe and a list of notices for plugins that are not installed.

    Raises:
        ConfigError: if a plugin's options are invalid (e.g. a required one is missing).
    """
    from l2calib.plugins import get_plugin

    notices = []
    data = recipe.model_dump(mode="json")
    choices = [(s, g, data[s]) for s, g in PLUGIN_SECTIONS.items()]
    if data["reference"].get("fallback"):
        choices.append(("reference.fallback", "l2calib.references", data["reference"]["fallback"]))
    for section, group, choice in choices:
        try:
            spec = get_plugin(group, choice["name"])
        except PluginError as exc:
            notices.append(f"{section}: {exc} (its options are left as given)")
            continue
        try:
            options = spec.config.model_validate(choice["options"])
        except ValidationError as exc:
            raise _format_validation(exc, source, f"{section}.options", overrides) from None
        choice["options"] = options.model_dump(mode="json")
    return Recipe.model_validate(data), notices


def dump_recipe(recipe: Recipe) -> str:
    """The recipe as YAML text (keys in declaration order)."""
    return yaml.safe_dump(recipe.model_dump(mode="json"), sort_keys=False, width=100)
