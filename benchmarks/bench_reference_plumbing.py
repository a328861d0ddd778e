"""Every reference source on the paper's three rigs: APE against ``gt_lidar.tum``.

The LiDAR-only references are measured over the whole matrix of rigs and motions by
``bench_references``; this benchmark checks the other sources and the plumbing around them
(frames, clocks, warm-up) on the paper's platforms.

Run: ``python -m benchmarks.bench_reference_plumbing [--only handheld uav ugv]`` (about 30-40 min
on 2 busy cores; ``--only`` re-runs some cases and keeps the other rows of the JSON); prints a
table and writes ``benchmarks/results/reference_plumbing.json``. Target: under 5 cm translation
RMSE (SE(3)-aligned APE, as evo) on every row of a source; ``passed`` per source says whether
all its rows met it (a lost track misses it).

Cases follow the paper's platforms: hand-held (Livox MID-360 on its hand-held rig), UAV (NTU
VIRAL: Ouster OS1-16) and UGV (MCD: Ouster OS1-64). Sources:

* ``kiss-icp`` — the options of the rig's built-in recipe (``CASES``), ``max_range_m`` defaulting
  to the sensor's range (at most 100 m; KISS-ICP's voxel is 1/100 of it unless the recipe sets
  ``voxel_size``), 3 deskew iterations, on the whole sequence;
* ``ct-lidar`` — the continuous-time LiDAR odometry, defaults but ``max_range_m`` as above;
* ``gt-file (imu)`` — ``gt_imu.tum`` turned into the LiDAR with the true extrinsic and clock
  offset: checks the frame and clock plumbing (expected ~0);
* ``rtk`` — NavSatFix synthesised from the exact LiDAR poses: antenna 0.6 m from the LiDAR,
  10 Hz, σ = 1 cm horizontal / 2 cm vertical, lever arm removed with the KISS-ICP attitude.

Also: both LiDAR-only references on a 10 s hand-held segment cut from the middle, with and
without the 1 s warm-up.
Rotation is reported as the median 1 s relative rotation error (RPE): the APE's rotation depends
on how well positions fix the alignment.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from benchmarks.machine import machine_info
from l2calib import geometry as geo
from l2calib.alignment import ape
from l2calib.data import NS_PER_S
from l2calib.errors import L2CalibError
from l2calib.io.navsat import NavSatFixes
from l2calib.io.trajectory_files import read_tum
from l2calib.plugins import get_plugin
from l2calib.references.geodesy import LocalEnu
from l2calib.sim import SimConfig, simulate, write_run

RESULTS = Path(__file__).parent / "results" / "reference_plumbing.json"
TARGET_M = 0.05
DURATION_S = 40.0
LEVER_M = (0.3, -0.2, 0.45)
#: case -> (simulator overrides, the built-in recipe for that rig: its LiDAR-odometry settings)
CASES = {
    "handheld": (
        {"rig": {"preset": "paper-handheld"}, "world": {"name": "urban"}},
        "livox-mid360-mti300",
    ),
    "uav": ({"rig": {"preset": "ntu-viral"}, "world": {"name": "urban"}}, "ntu-viral-os1-16-vn100"),
    "ugv": (
        {"rig": {"preset": "mcd"}, "world": {"name": "urban"}, "lidar": {"columns": 512}},
        "mcd-ouster-vn200",
    ),
}


def synth_fixes(run, seed: int = 0) -> NavSatFixes:
    """10 Hz fixes of an antenna at ``LEVER_M`` (LiDAR frame), σ 1 cm (E, N) / 2 cm (U)."""
    gt = run.gt_lidar
    t = np.arange(gt.stamps_ns[0], gt.stamps_ns[-1] + 1, NS_PER_S // 10, dtype=np.int64)
    T = run.lidar_poses(t)
    sig = np.array([0.01, 0.01, 0.02])
    ant = T[:, :3, 3] + T[:, :3, :3] @ np.asarray(LEVER_M)
    ant += np.random.default_rng(seed).normal(0.0, 1.0, ant.shape) * sig
    lat, lon, h = LocalEnu(48.1486, 11.5681, 520.0).to_geodetic(ant)
    n = len(t)
    return NavSatFixes(
        t, lat, lon, h, np.tile(np.diag(sig**2), (n, 1, 1)), np.full(n, 2, np.uint8),
        np.full(n, 2, np.int8), np.ones(n, np.uint16),
    )  # fmt: skip


def rpe_rot_deg(gt, est, delta_s: float = 1.0) -> float:
    """Median relative rotation error over ``delta_s`` (deg)."""
    g, e = gt.interpolate(est.stamps_ns).matrices(), est.matrices()
    k = int(np.searchsorted(est.stamps_ns, est.stamps_ns[0] + int(delta_s * NS_PER_S)))
    d = geo.transform_inverse(geo.transform_inverse(g[:-k]) @ g[k:]) @ (
        geo.transform_inverse(e[:-k]) @ e[k:]
    )
    return float(np.degrees(np.median(geo.rotation_angle(d[:, :3, :3]).numpy())))


def covers(ref, seg) -> bool:
    points = np.unique(np.concatenate([s.point_stamps_ns for s in seg.scans]))
    return bool(ref.trajectory.sample(points, max_gap_s=0.2)[1].all())


def evaluate(label, source, ref, gt, seg, seconds) -> dict:
    res = ape(gt, ref.trajectory)
    pose = ref.constrains == "pose"
    print(f"{label} | {source}: APE {res.rmse_t:.4f} m in {seconds:.1f} s", flush=True)
    return {
        "case": label,
        "source": source,
        "poses": len(ref.trajectory),
        "ape_t_rmse_m": round(res.rmse_t, 4),
        "ape_t_max_m": round(float(res.e_t.max()), 4),
        "rpe_r_deg_1s": round(rpe_rot_deg(gt, ref.trajectory), 3) if pose else None,
        "constrains": ref.constrains,
        "covers_all_points": covers(ref, seg),
        "seconds": round(seconds, 1),
    }


def guarded(label, source, compute, gt, seg) -> dict:  # noqa: ANN001
    """:func:`evaluate` of ``compute()``, or a row saying why the source gave no reference."""
    t = time.perf_counter()
    try:
        ref = compute()
    except L2CalibError as exc:
        print(f"{label} | {source}: {exc}", flush=True)
        return {"case": label, "source": source, "error": str(exc), "constrains": None,
                "seconds": round(time.perf_counter() - t, 1)}  # fmt: skip
    return evaluate(label, source, ref, gt, seg, time.perf_counter() - t)


def lidar_odometry_options(recipe_name: str, max_range_m: float, cache: Path) -> dict:
    """The recipe's ``kiss-icp`` options; ``max_range_m`` = the sensor's (≤ 100 m) unless set."""
    from l2calib.recipe import load_recipe

    reference = load_recipe(recipe_name).reference
    opts = dict(reference.options) if reference.name == "kiss-icp" else {}
    return {"max_range_m": min(100.0, max_range_m), **opts, "cache_dir": str(cache)}


def passed_flags(rows: list[dict]) -> dict[str, bool]:
    """Per source: did every one of its rows stay under ``TARGET_M`` (an error row misses)?"""
    return {
        source: all(
            r.get("ape_t_rmse_m", float("inf")) < TARGET_M for r in rows if r["source"] == source
        )
        for source in dict.fromkeys(r["source"] for r in rows)
    }


def run_case(name: str, overrides: dict, recipe: str, tmp: Path, cache: Path) -> list[dict]:
    cfg = SimConfig.model_validate(
        {"duration_s": DURATION_S, "seed": 1, "motion": {"profile": name}, **overrides}
    )
    run = simulate(cfg)
    files = write_run(run, tmp / name, write_bag_file=False)
    gt = read_tum(files["gt_lidar"], "lidar")
    seq = run.sequence()
    seg = seq.segment()
    label = f"{name} {DURATION_S:.0f} s ({run.lidar_spec.name})"
    rows = []
    t = time.perf_counter()
    kiss_opts = lidar_odometry_options(recipe, run.lidar_spec.max_range_m, cache)
    kiss = get_plugin("l2calib.references", "kiss-icp").build(kiss_opts)
    rows.append(
        evaluate(label, "kiss-icp", kiss.compute([seg])[0], gt, seg, time.perf_counter() - t)
    )
    t = time.perf_counter()
    ct_opts = {"max_range_m": kiss_opts["max_range_m"], "cache_dir": str(cache)}
    ct = get_plugin("l2calib.references", "ct-lidar").build(ct_opts)
    rows.append(guarded(label, "ct-lidar", lambda: ct.compute([seg])[0], gt, seg))
    t = time.perf_counter()
    gtf = get_plugin("l2calib.references", "gt-file").build(
        {
            "path": files["gt_imu"],
            "body_frame": "imu",
            "T_body_lidar": run.T_imu_lidar.tolist(),
            "time_offset_s": -run.time_offset_s,
            "constrains": "pose",
        }
    )
    rows.append(
        evaluate(label, "gt-file (imu)", gtf.compute([seg])[0], gt, seg, time.perf_counter() - t)
    )
    t = time.perf_counter()
    rtk = get_plugin("l2calib.references", "rtk").build(
        {"lever_arm_m": LEVER_M, "cache_dir": str(cache), "kiss_icp": kiss_opts},
        fixes={seq.name: synth_fixes(run)},
    )
    rows.append(evaluate(label, "rtk", rtk.compute([seg])[0], gt, seg, time.perf_counter() - t))
    if name == "handheld":
        st = seq.scans.stamps_ns
        mid = seq.segment(int(st[200]), int(st[300]))
        for source, opts in (("kiss-icp", kiss_opts), ("ct-lidar", ct_opts)):
            for warm, seqs in (("with 1 s warm-up", [seq]), ("no warm-up", None)):
                src = get_plugin("l2calib.references", source).build(opts, sequences=seqs)
                lab = f"handheld 10 s mid-segment, {warm}"
                rows.append(guarded(lab, source, lambda src=src: src.compute([mid])[0], gt, mid))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--only", nargs="*", choices=sorted(CASES), help="cases to (re)run; the others' rows in "
        "reference_plumbing.json are kept as measured",
    )  # fmt: skip
    args = parser.parse_args()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        for name, (overrides, recipe) in CASES.items():
            if not args.only or name in args.only:
                rows += run_case(name, overrides, recipe, Path(tmp), cache)
    if args.only and RESULTS.is_file():  # keep the rows of the cases not re-run
        old = json.loads(RESULTS.read_text())["rows"]
        rows = [r for r in old if r["case"].split()[0] not in args.only] + rows
        rows.sort(key=lambda r: list(CASES).index(r["case"].split()[0]))
    passed = passed_flags(rows)
    table = Table(title="Reference APE against gt_lidar.tum (SE(3)-aligned)")
    for col in ("case", "source", "poses", "APE RMSE m", "APE max m", "RPE rot 1 s deg", "s"):
        table.add_column(col)
    for r in rows:
        if "error" in r:
            table.add_row(r["case"], r["source"], "-", "error", "-", "-", f"{r['seconds']:.1f}")
            continue
        rot = "-" if r["rpe_r_deg_1s"] is None else f"{r['rpe_r_deg_1s']:.3f}"
        table.add_row(
            r["case"], r["source"], str(r["poses"]), f"{r['ape_t_rmse_m']:.4f}",
            f"{r['ape_t_max_m']:.4f}", rot, f"{r['seconds']:.1f}",
        )  # fmt: skip
    console = Console(width=150)
    console.print(table)
    for source, ok in passed.items():
        console.print(f"{source}: every row under {TARGET_M} m: {'PASS' if ok else 'FAIL'}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(
        json.dumps(
            {
                "benchmark": "bench_reference_plumbing",
                "target_m": TARGET_M,
                "passed": passed,
                "rows": rows,
                "lever_arm_m": LEVER_M,
                "cases_run": args.only or list(CASES),  # the others' rows: an earlier run's
                "machine": {**machine_info(), "load_before": load_before},
            },
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
