"""Many vehicles' logs on Ray Data: every log replayed (and, where position
fixes are given, calibrated) by canodom, one Ray task per log.

    python -m canodom.fleet MANIFEST --out DIR [--address ADDR] [--num-cpus N]

MANIFEST is a CSV with the header ``vehicle_id,log,config[,fixes]``: one row
per log; relative paths are taken from the manifest's folder. It writes:

- ``DIR/poses/vehicle_id=ID/*.parquet``: the replay's rows of every log
  (hive-partitioned by vehicle: ``pyarrow.dataset.dataset(DIR + "/poses",
  partitioning="hive")``), with the log's path in column ``log``;
- ``DIR/summary.parquet``: one row per log (frames, steps, distance, the end
  poses, gate counts, malformed lines, the calibration where fixes were
  given) and ``error``: the text of why a log could not be done, empty else;
- ``DIR/vehicles.parquet``: one row per vehicle: logs, distance, and where
  fixes were given the calibrated parameters with σ, their difference from
  the configured set, and whether that drift is flagged.

A log that cannot be read gets its error row; the job goes on and exits 0,
saying how many failed. Exit 2: the manifest itself is unusable.

Drift flags: a parameter the drives told is flagged when its difference from
the configured set is both significant (beyond --drift-sigmas times its σ)
and larger than its tolerance (--tolerance NAME=VALUE; defaults below), and
the whole calibrated set when it lies outside the configuration's
``[calibration]`` bounds (``bounds_rel``, ``max_steer_offset_deg``).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

#: The calibrated corrections: name -> (configured value, default tolerance).
#: speed_scale, rear_ratio, steering_gain and yaw_rate_scale multiply the
#: configured values (1 = as configured); the offset and the bias add (0).
PARAMETERS: Dict[str, tuple] = {
    "speed_scale": (1.0, 0.005),  # 0.5 % of distance: a tyre's wear or pressure
    "rear_ratio": (1.0, 0.002),  # 0.2 % right/left: a wheel of another size
    "steering_offset_rad": (0.0, math.radians(0.5)),
    "steering_gain": (1.0, 0.02),
    "yaw_rate_bias_radps": (0.0, math.radians(0.2)),
    "yaw_rate_scale": (1.0, 0.02),
}

#: The summary's columns from the replay's summary (schema metadata).
GATE_KEYS = ["gate_kept_rear", "gate_used_front", "gate_yaw_over_rear", "gate_yaw_refused"]


@dataclass(frozen=True)
class Entry:
    """One manifest row, its paths resolved."""

    index: int
    vehicle_id: str
    log: str
    config: str
    fixes: Optional[str]


def read_manifest(path: Path) -> List[Entry]:
    """The manifest's rows; ValueError naming the line at fault."""
    base = path.parent
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in ("vehicle_id", "log", "config") if c not in header]
        if missing:
            raise ValueError(
                f"{path}: line 1: the header must be vehicle_id,log,config[,fixes]; "
                f"missing {', '.join(missing)} (found {','.join(header) or 'nothing'})"
            )
        unknown = [h for h in header if h not in ("vehicle_id", "log", "config", "fixes")]
        if unknown:
            raise ValueError(f"{path}: line 1: unknown column(s) {', '.join(unknown)}")
        entries = []
        for line, row in enumerate(reader, start=2):
            row = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
            if not row.get("vehicle_id") or not row.get("log") or not row.get("config"):
                raise ValueError(f"{path}: line {line}: vehicle_id, log and config are required")

            def resolve(p: str) -> str:
                return str(p if os.path.isabs(p) else (base / p).resolve())

            entries.append(
                Entry(
                    index=len(entries),
                    vehicle_id=row["vehicle_id"],
                    log=resolve(row["log"]),
                    config=resolve(row["config"]),
                    fixes=resolve(row["fixes"]) if row.get("fixes") else None,
                )
            )
    if not entries:
        raise ValueError(f"{path}: no log listed")
    return entries


def _poses_path(out: str, entry: Entry) -> str:
    vehicle = urllib.parse.quote(entry.vehicle_id, safe="")
    stem = urllib.parse.quote(Path(entry.log).name, safe="")
    return os.path.join(out, "poses", f"vehicle_id={vehicle}", f"{entry.index:06d}-{stem}.parquet")


def _empty_summary(entry: Entry) -> Dict[str, Any]:
    row: Dict[str, Any] = {
        "index": entry.index,
        "vehicle_id": entry.vehicle_id,
        "log": entry.log,
        "config": entry.config,
        "fixes": entry.fixes or "",
        "frames": 0,
        "steps": 0,
        "duration_s": math.nan,
        "distance_m": math.nan,
        "end_x_m": math.nan,
        "end_y_m": math.nan,
        "end_heading_rad": math.nan,
        "rear_end_x_m": math.nan,
        "rear_end_y_m": math.nan,
        "rear_end_heading_rad": math.nan,
        "malformed": 0,
        "used": 0,
        "steps_without_front": 0,
        "rejects": "{}",
        "calibration": "",
        "seconds": 0.0,
        "error": "",
    }
    for key in GATE_KEYS:
        row[key] = 0
    return row


def process_log(item: Dict[str, Any], out: str) -> Dict[str, Any]:
    """Replays one log (and calibrates it against its fixes): its poses to
    Parquet, its summary row returned; any failure is the row's error."""
    import canodom  # imported in the worker

    entry = Entry(**json.loads(item["entry"]))
    row = _empty_summary(entry)
    started = time.perf_counter()
    try:
        poses = canodom.replay(entry.log, entry.config)
        summary = json.loads(poses.schema.metadata[b"canodom.summary"])
        row.update(
            frames=summary["frames"],
            steps=summary["steps"],
            used=summary["used"],
            steps_without_front=summary["steps_without_front"],
            malformed=summary["malformed"],
            rejects=json.dumps(summary["rejects"], sort_keys=True),
        )
        for key in GATE_KEYS:
            row[key] = summary[key]
        if poses.num_rows:
            last = {name: poses.column(name)[poses.num_rows - 1].as_py() for name in poses.column_names}
            x = poses.column("odo_x_m").to_numpy()
            y = poses.column("odo_y_m").to_numpy()
            distance = float(np.hypot(np.diff(x), np.diff(y)).sum())
            row.update(
                duration_s=last["t_s"],
                distance_m=distance,
                end_x_m=last["x_m"],
                end_y_m=last["y_m"],
                end_heading_rad=last["heading_rad"],
                rear_end_x_m=last["odo_x_m"],
                rear_end_y_m=last["odo_y_m"],
                rear_end_heading_rad=last["odo_heading_rad"],
            )
        path = _poses_path(out, entry)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        poses = poses.replace_schema_metadata(None)
        # pa.repeat, not a Python list of num_rows strings (0.02-0.5 s per
        # 200,000 rows, measured); a dictionary only for the one column that
        # repeats: pyarrow's default tries one on every float column, which
        # took 0.32 s against 0.07 s (and 16.2 MB against 14.0 MB) for the
        # 204,000 poses of a 613,000-frame log, longer than its replay (0.24 s).
        poses = poses.append_column("log", pa.repeat(pa.scalar(entry.log, pa.string()), poses.num_rows))
        tmp = path + ".tmp"
        pq.write_table(poses, tmp, use_dictionary=["log"])
        os.replace(tmp, path)  # a half-written file never looks like a result
        if entry.fixes:
            row["calibration"] = json.dumps(canodom.calibrate_fixes(entry.log, entry.config, entry.fixes))
    except Exception as e:  # noqa: BLE001 - every failure of a log is its row's error
        row["error"] = f"{type(e).__name__}: {e}"
    row["seconds"] = time.perf_counter() - started
    return row


def vehicles_table(summary: pa.Table, drift_sigmas: float, tolerances: Dict[str, float]) -> pa.Table:
    """Per vehicle: logs, distance, and the drives' calibration combined
    (inverse-variance mean of each told correction), its difference from the
    configured set and the flags."""
    rows = summary.to_pylist()
    by_vehicle: Dict[str, List[Dict[str, Any]]] = {}
    for r in rows:
        by_vehicle.setdefault(r["vehicle_id"], []).append(r)
    out = []
    for vehicle in sorted(by_vehicle):
        logs = by_vehicle[vehicle]
        ok = [r for r in logs if not r["error"]]
        rec: Dict[str, Any] = {
            "vehicle_id": vehicle,
            "logs": len(logs),
            "failed_logs": len(logs) - len(ok),
            "frames": sum(r["frames"] for r in ok),
            "distance_m": float(sum(r["distance_m"] for r in ok if not math.isnan(r["distance_m"]))),
        }
        calibrations = [json.loads(r["calibration"]) for r in ok if r["calibration"]]
        rec["calibrated_logs"] = len(calibrations)
        flagged = []
        for name, (configured, _) in PARAMETERS.items():
            told = [
                c["estimates"][name]
                for c in calibrations
                if name in c["estimates"] and c["estimates"][name]["observable"] and c["estimates"][name]["sigma"] > 0
            ]
            if told:
                weights = [1.0 / e["sigma"] ** 2 for e in told]
                value = sum(w * e["value"] for w, e in zip(weights, told)) / sum(weights)
                sigma = math.sqrt(1.0 / sum(weights))
                diff = value - configured
                flag = abs(diff) > drift_sigmas * sigma and abs(diff) > tolerances[name]
            else:
                value = sigma = diff = None
                flag = False
            rec[name] = value
            rec[f"{name}_sigma"] = sigma
            rec[f"{name}_diff"] = diff
            rec[f"{name}_flagged"] = flag
            if flag:
                flagged.append(name)
        bounds = sorted({c["out_of_bounds"] for c in calibrations if c.get("out_of_bounds")})
        rec["out_of_bounds"] = "; ".join(bounds)
        rec["calibrated"] = json.dumps(calibrations[-1]["calibrated"]) if calibrations else ""
        rec["configured"] = json.dumps(calibrations[-1]["configured"]) if calibrations else ""
        rec["flagged"] = ",".join(flagged + (["out_of_bounds"] if bounds else []))
        out.append(rec)
    return pa.Table.from_pylist(out)


def run(
    manifest: Path,
    out: Path,
    address: Optional[str] = None,
    num_cpus: Optional[int] = None,
    drift_sigmas: float = 3.0,
    tolerances: Optional[Dict[str, float]] = None,
) -> Dict[str, pa.Table]:
    """The fleet job (see the module's doc); returns the summary and vehicles tables."""
    import ray

    entries = read_manifest(manifest)
    tolerances = {**{k: v[1] for k, v in PARAMETERS.items()}, **(tolerances or {})}
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    if not ray.is_initialized():
        if address:
            ray.init(address=address)
        else:
            ray.init(num_cpus=num_cpus, include_dashboard=False)
    items = [{"entry": json.dumps(e.__dict__)} for e in entries]
    out_text = str(out)
    # One block per log, so one task per log; each task streams its log.
    ds = ray.data.from_items(items, override_num_blocks=len(items))
    ds = ds.map(process_log, fn_kwargs={"out": out_text}, num_cpus=1)
    rows = sorted(ds.take_all(), key=lambda r: r["index"])
    summary = pa.Table.from_pylist(rows).drop_columns(["index"])
    pq.write_table(summary, out / "summary.parquet")
    vehicles = vehicles_table(summary, drift_sigmas, tolerances)
    pq.write_table(vehicles, out / "vehicles.parquet")
    elapsed = time.perf_counter() - started
    print_report(summary, vehicles, out, elapsed)
    return {"summary": summary, "vehicles": vehicles}


def print_report(summary: pa.Table, vehicles: pa.Table, out: Path, elapsed: float) -> None:
    """The one-screen summary at the end."""
    rows = summary.to_pylist()
    failed = [r for r in rows if r["error"]]
    frames = sum(r["frames"] for r in rows)
    task_s = sum(r["seconds"] for r in rows)
    print()
    print(f"canodom fleet: {len(rows)} logs of {vehicles.num_rows} vehicles in {elapsed:.1f} s")
    print(f"  {frames} frames ({frames / max(elapsed, 1e-9):,.0f} frames/s overall, "
          f"{frames / max(task_s, 1e-9):,.0f} frames/s per task)")
    print(f"  {len(failed)} failed" + (":" if failed else ""))
    for r in failed[:10]:
        print(f"    {r['vehicle_id']} {r['log']}: {r['error']}")
    if len(failed) > 10:
        print(f"    ... and {len(failed) - 10} more (summary.parquet, column error)")
    flagged = [v for v in vehicles.to_pylist() if v["flagged"]]
    print(f"  {len(flagged)} vehicles with calibration drift flagged" + (":" if flagged else ""))
    for v in flagged[:15]:
        parts = []
        for name in v["flagged"].split(","):
            if name == "out_of_bounds":
                parts.append(f"out of bounds ({v['out_of_bounds']})")
            else:
                parts.append(f"{name} {v[name + '_diff']:+.5f} ± {v[name + '_sigma']:.5f}")
        print(f"    {v['vehicle_id']}: " + ", ".join(parts))
    if len(flagged) > 15:
        print(f"    ... and {len(flagged) - 15} more (vehicles.parquet, column flagged)")
    print(f"  written: {out / 'poses'}/, {out / 'summary.parquet'}, {out / 'vehicles.parquet'}")


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m canodom.fleet",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Example manifest:\n  vehicle_id,log,config,fixes\n  car-07,logs/car-07/monday.log.zst,configs/car-07.toml,"
        "fixes/car-07-monday.csv\n  car-08,logs/car-08/monday.blf,configs/car-08.toml,\n\n"
        "Local: python -m canodom.fleet manifest.csv --out results\n"
        "Cluster: python -m canodom.fleet manifest.csv --out /shared/results --address ray://head:10001\n"
        "(paths must be readable, and --out writable, on every node: a shared file system)\n\n"
        "Default tolerances: " + ", ".join(f"{k}={v[1]:.4g}" for k, v in PARAMETERS.items()),
    )
    parser.add_argument("manifest", type=Path, help="CSV vehicle_id,log,config[,fixes]")
    parser.add_argument("--out", type=Path, required=True, help="the output folder")
    parser.add_argument("--address", help="an existing Ray cluster (ray://HOST:10001 or auto); default: a local Ray")
    parser.add_argument("--num-cpus", type=int, help="CPUs of the local Ray (default: all)")
    parser.add_argument("--drift-sigmas", type=float, default=3.0, help="significance of a flagged drift (default 3)")
    parser.add_argument("--tolerance", action="append", default=[], metavar="NAME=VALUE",
                        help="the drift a parameter may have before it is flagged")
    args = parser.parse_args(argv)
    tolerances = {}
    for t in args.tolerance:
        name, _, value = t.partition("=")
        if name not in PARAMETERS:
            parser.error(f"--tolerance {t}: unknown parameter {name!r} (one of {', '.join(PARAMETERS)})")
        try:
            tolerances[name] = float(value)
        except ValueError:
            parser.error(f"--tolerance {t}: {value!r} is not a number")
    try:
        result = run(args.manifest, args.out, args.address, args.num_cpus, args.drift_sigmas, tolerances)
    except (OSError, ValueError) as e:
        print(f"canodom fleet: {e}", file=sys.stderr)
        return 2
    failed = sum(1 for e in result["summary"].column("error").to_pylist() if e)
    print(f"canodom fleet: {failed} of {result['summary'].num_rows} logs failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
