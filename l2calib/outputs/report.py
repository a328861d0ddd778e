"""``report.html``: one self-contained page a person reads after a calibration.

From the top: the status in colour with its reasons, the axes the data could not determine and
any warnings; the result table exactly as ``calibrate`` prints it (recorded from the same rich
printing code, :mod:`l2calib.outputs.console_summary`); the figures (``report.png``,
``trajectories.png``, ``selection.png``) embedded as data URIs, so the page can be mailed or
attached to a ticket on its own; and the full ``calibration.yaml`` at the bottom.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

from l2calib.assess.status import NOT_CALIBRATED, UNRELIABLE

#: Background and border colour per status.
STATUS_COLORS = {
    "calibrated": ("#e6f4ea", "#1e8e3e"),
    UNRELIABLE: ("#fef7e0", "#e37400"),
    NOT_CALIBRATED: ("#fce8e6", "#d93025"),
}

CSS = """
body{font-family:system-ui,sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#202124}
.box{border-left:6px solid;padding:.5em 1em;margin:.8em 0;border-radius:4px}
.box h2{margin:.2em 0;font-size:1.2em}
.warn{background:#fef7e0;border-color:#e37400}
pre.cli{font-size:13px;line-height:1.3;background:#fff;border:1px solid #ddd;padding:.6em;
overflow-x:auto}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption{color:#5f6368;font-size:.9em}
details pre{background:#f8f9fa;padding:.6em;font-size:12px;overflow-x:auto}
"""


def cli_summary_html(result: Any, truth: Any = None) -> str:
    """The result table and status as ``calibrate`` prints them, as an HTML ``<pre>`` block."""
    from rich.console import Console

    from l2calib.outputs.console_summary import print_result, print_status

    console = Console(record=True, width=110, file=io.StringIO(), color_system="truecolor")
    if not result.stopped_before_training:
        print_result(console, result, truth=truth)
    print_status(console, result)
    return console.export_html(inline_styles=True, code_format='<pre class="cli">{code}</pre>')


def _items(values: list[str]) -> str:
    return "<ul>" + "".join(f"<li>{html.escape(v)}</li>" for v in values) + "</ul>"


def _alerts(result: Any) -> str:
    """Status, undetermined axes and warnings at the top of the page, in colour."""
    bg, border = STATUS_COLORS.get(result.status, STATUS_COLORS[NOT_CALIBRATED])
    reasons = _items(result.status_reasons) if result.status_reasons else ""
    out = (
        f'<div class="box" id="status" style="background:{bg};border-color:{border}">'
        f"<h2>status: {html.escape(result.status)}</h2>{reasons}</div>"
    )
    if result.undetermined:
        out += (
            '<div class="box warn" id="undetermined"><h2>Not determined by the data — do not '
            "trust these components; record motion that excites them</h2>"
            f"{_items(result.undetermined)}</div>"
        )
    warnings = [w for w in result.warnings if w not in result.status_reasons]  # said above
    if warnings:
        out += f'<div class="box warn" id="warnings"><h2>Warnings</h2>{_items(warnings)}</div>'
    return out


def _figure(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure id="{html.escape(path.stem)}"><img alt="{html.escape(path.name)}" '
        f'src="data:image/png;base64,{data}"><figcaption>{html.escape(caption)}</figcaption>'
        "</figure>"
    )


def write_html(
    path: Path,
    result: Any,
    figures: list[tuple[Path, str]],
    calibration_yaml: Path | None = None,
    truth: Any = None,
) -> Path:
    """Writes the self-contained report page.

    Args:
        path: ``report.html`` to write.
        result: The :class:`~l2calib.assess.result.CalibrationResult`.
        figures: ``(png path, caption)`` pairs, embedded in this order (missing files skipped).
        calibration_yaml: The written ``calibration.yaml``, shown in full at the bottom.
        truth: Optional ground-truth ``T_imu_lidar`` (4×4): the table then shows the error.
    """
    body = _alerts(result) + "<h2>Result</h2>" + cli_summary_html(result, truth)
    body += "".join(_figure(p, c) for p, c in figures if p.is_file())
    if calibration_yaml is not None and calibration_yaml.is_file():
        body += (
            f"<details><summary>{html.escape(calibration_yaml.name)}</summary>"
            f"<pre>{html.escape(calibration_yaml.read_text())}</pre></details>"
        )
    path.write_text(
        "<!doctype html><html lang=en><meta charset=utf-8>"
        f"<title>l2calib report — {html.escape(result.status)}</title><style>{CSS}</style>"
        f"<h1>l2calib calibration report</h1>{body}</html>\n"
    )
    return path
