"""One error hierarchy for everything l2calib raises on purpose.

Every error carries what went wrong and, where we know it, how to fix it. The CLI prints
``error: <what> — fix: <how>`` and exits with status 1; library users catch ``L2CalibError``.
"""

from __future__ import annotations


class L2CalibError(Exception):
    """Root of all errors raised by l2calib on purpose.

    Args:
        message: What went wrong, naming the file, topic or field involved.
        fix: How the user can fix it (optional but strongly encouraged).
    """

    def __init__(self, message: str, fix: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.fix = fix

    def __str__(self) -> str:
        if self.fix:
            return f"{self.message} — fix: {self.fix}"
        return self.message


class ConfigError(L2CalibError):
    """A recipe, CLI option or plugin configuration is invalid."""


class DataError(L2CalibError):
    """Input data (trajectory file, bag, topic, message field) is missing, malformed or unusable."""


class FormatError(DataError):
    """A file does not follow the format it claims (e.g. a TUM file with 7 columns)."""


class PluginError(L2CalibError):
    """A plugin cannot be found, loaded, or is registered twice or with the wrong type."""


class BackendError(L2CalibError):
    """An odometry backend cannot run (a failure of the whole call, not of one candidate)."""


class ReferenceSourceError(L2CalibError):
    """A reference trajectory cannot be computed or loaded."""


class ReferenceLostTrackError(ReferenceSourceError):
    """A LiDAR-odometry reference lost track on this data (the recipe's fallback may take over).

    Args:
        message: Where and how track was lost (time, scan).
        fix: What the user can do.
        lost: Names of the segments on which track was lost (when the source knows them).
        tracked: The references of the segments on which it did not lose track.
    """

    def __init__(
        self,
        message: str,
        fix: str | None = None,
        lost: list[str] | None = None,
        tracked: list | None = None,  # list[ReferenceTrajectory]; no import cycle
    ) -> None:
        super().__init__(message, fix)
        self.lost = lost or []
        self.tracked = tracked or []


class TrainingError(L2CalibError):
    """Training cannot start or continue (bad checkpoint, no valid candidates, ...)."""


class NotImplementedPluginError(PluginError):
    """A registered plugin is a documented placeholder that cannot run yet."""


class OutputError(L2CalibError):
    """An output path (``--out``) cannot be created or written."""


class NotCalibratedError(DataError):
    """A calibration result holds no extrinsic to use: its status is ``not-calibrated``."""
