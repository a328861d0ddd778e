"""Tables of :mod:`benchmarks.bench_backends`: one set of rows, rendered by rich and as markdown."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

Rows = list[list[str]]
_SHORT = {"OK": "", "DIVERGED": " div", "FEW_CORRESPONDENCES": " lost", "FAILED": " fail"}
NO = "NO"  # marker of a small perturbation that does not lower the reward


def _case(r: dict[str, Any]) -> str:
    return f"{r['backend']} {r['case']}"


def ape_table(res: dict[str, Any]) -> tuple[str, list[str], Rows]:
    head = ["backend", "case", "scans", "status", "APE RMSE (cm)", "max (cm)", "rot RMSE (deg)",
            "SE(3)-aligned RMSE (cm)", "eval (s)", "target (cm)", "ok"]  # fmt: skip
    rows = [
        [r["backend"], r["case"], str(r["scans"]), r["status"], f"{100 * r['ape_rmse_m']:.2f}",
         f"{100 * r['ape_max_m']:.2f}", f"{r['ape_rot_rmse_deg']:.3f}",
         f"{100 * r['ape_se3_rmse_m']:.2f}", f"{r['seconds']:.1f}",
         f"< {100 * r['target_m']:g}", "ok" if r["pass"] else "FAIL"]
        for r in res["ape"]
    ]  # fmt: skip
    for label, p in res.get("peer", {}).get("cases", {}).items():
        rows.append(
            [label, "own map, 1 run", str(p["poses"]), "-", "- (own frame)",
             f"{100 * p['ape_max_m']:.2f} (aligned)", f"{p['ape_rot_rmse_deg']:.3f} (aligned)",
             f"{100 * p['ape_rmse_m']:.2f}", f"{p['seconds']:.1f}", "-", "-"]
        )  # fmt: skip
    dur = res["sim_stats"]["handheld"]["duration_s"]
    return f"APE, true extrinsic, {dur:g} s handheld (from 1 s on)", head, rows


def sensitivity_table(res: dict[str, Any], profile: str) -> tuple[str, list[str], Rows]:
    cases = res["sensitivity"][profile]
    head = ["perturbation"] + [_case(c) for c in cases]
    rows = [["true extrinsic"] + [f"{c['true_reward']:.4f}" for c in cases]]
    for i, row in enumerate(cases[0]["rows"]):
        cells = [row["label"] + (" (large)" if row["large"] else "")]
        for c in cases:
            x = c["rows"][i]
            prev = c["true_reward"] if i == 0 or c["rows"][i - 1]["kind"] != x["kind"] or \
                c["rows"][i - 1]["axis"] != x["axis"] else c["rows"][i - 1]["reward"]  # fmt: skip
            mark = ""
            if not x["large"] and not x["lower"]:
                mark = f" {NO}"
            elif x["large"] and x["reward"] > prev + 1e-12:
                mark = " rises"
            cells.append(f"{x['reward']:.4f}{mark}{_SHORT.get(x['status'], '')}")
        rows.append(cells)
    title = (
        f"{profile}: paper reward (align none), 10 s segment; {NO} = small error not below the "
        "true reward; rises = large error scores above the next smaller one; lost/div = status"
    )
    return title, head, rows


def summary_table(res: dict[str, Any]) -> tuple[str, list[str], Rows]:
    tp = {_case(t): t["rows"] for t in res["throughput"]}
    head = ["profile", "case", "true", "flagged", "drop/1deg mean (min axis)",
            "drop/1cm mean (min axis)", "inversions / flat / pairs", "r@30deg", "r@90deg",
            "r@50cm", "not OK", "cand-scans/s K=32"]  # fmt: skip
    rows = []
    for prof, cases in res["sensitivity"].items():
        for c in cases:
            s = c["summary"]
            k32 = [r for r in tp.get(_case(c), []) if r["K"] == 32]
            rows.append(
                [prof, _case(c), f"{c['true_reward']:.4f}{_SHORT.get(c['true_status'], '')}",
                 f"{len(c['flagged'])}/{sum(not r['large'] for r in c['rows'])}",
                 f"{s['drop_per_1deg_mean']:.4f} ({s['drop_per_1deg_min']:.4f})",
                 f"{s['drop_per_1cm_mean']:.4f} ({s['drop_per_1cm_min']:.4f})",
                 f"{s['inversions']} / {s['flat_pairs']} / {s['pairs']}",
                 f"{s['reward_at_30deg']:.3f}", f"{s['reward_at_90deg']:.3f}",
                 f"{s['reward_at_50cm']:.3f}", str(s["not_ok"]),
                 f"{k32[0]['cand_scans_per_s']:.0f}" if k32 else "-"]
            )  # fmt: skip
    return "Map modes: reward sensitivity vs speed (handheld throughput)", head, rows


def throughput_table(res: dict[str, Any]) -> tuple[str, list[str], Rows]:
    head = ["backend", "case", "K", "scans", "best wall (s)", "cand-scans/s", "cand-scans/CPU-s"]
    rows = [
        [t["backend"], t["case"], str(r["K"]), str(r["scans"]), f"{r['seconds']:.2f}",
         f"{r['cand_scans_per_s']:.0f}", f"{r['cand_scans_per_cpu_s']:.0f}"]
        for t in res["throughput"]
        for r in t["rows"]
    ]  # fmt: skip
    for label, p in res.get("peer", {}).get("cases", {}).items():
        rows.append(
            ["rko-lio", label.removeprefix("rko-lio "), "1", str(p["scans"]), f"{p['seconds']:.2f}",
             f"{p['scans_per_s']:.0f}", f"{p['scans_per_cpu_s']:.0f}"]
        )  # fmt: skip
    title = (
        f"Throughput, {res['torch_threads']} torch thread(s), shared {res['cpu_count']}-core "
        f"machine (load {res['load']['start']} -> {res['load']['end']}); rko-lio: one trajectory "
        f"per run on the {res['sim_stats']['handheld']['duration_s']:g} s run"
    )
    return title, head, rows


def _all(res: dict[str, Any]) -> list[tuple[str, list[str], Rows]]:
    tables = [ape_table(res)]
    tables += [sensitivity_table(res, p) for p in res["sensitivity"]]
    return tables + [summary_table(res), throughput_table(res)]


def print_tables(res: dict[str, Any]) -> None:
    con = Console(width=220)
    for title, head, rows in _all(res):
        t = Table(title=title)
        for h in head:
            t.add_column(h)
        for row in rows:
            t.add_row(
                *[c.replace(NO, f"[red]{NO}[/]").replace("FAIL", "[red]FAIL[/]") for c in row]
            )
        con.print(t)
    if "error" in res.get("peer", {}):
        con.print(f"[yellow]peer LIO not run:[/] {res['peer']['error']}")


def write_markdown(res: dict[str, Any], path: Path) -> Path:
    lines = [
        "# Backends benchmark (`python -m benchmarks.bench_backends"
        + (" --quick`)" if res["quick"] else "`)"),
        "",
        f"Numbers in `{path.with_suffix('.json').name}`. "
        f"Python {res['python']}, torch {res['torch']} ({res['torch_threads']} thread(s), "
        f"OMP_NUM_THREADS={res['omp_num_threads']}), {res['cpu_count']} cores shared with other "
        f"jobs: load average (1, 5, 15 min) {res['load']['start']} at the start, "
        f"{res['load']['end']} at the end; total {res['seconds_total'] / 60:.1f} min.",
        "",
    ]
    for title, head, rows in _all(res):
        lines += [f"## {title}", "", "| " + " | ".join(head) + " |",
                  "|" + "---|" * len(head)]  # fmt: skip
        lines += ["| " + " | ".join(c.replace(NO, f"**{NO}**") for c in row) + " |" for row in rows]
        lines.append("")
    if "error" in res.get("peer", {}):
        lines += [f"Peer LIO not run: {res['peer']['error']}", ""]
    path.write_text("\n".join(lines))
    return path
