"""Studies of the turntable's imperfections: point-to-mesh error of a plant scan.

Three studies, each written as a CSV and a PNG plot:

- ``jitter``: error against the magnitude of each jitter source (torque ripple,
  torque noise, backlash), continuous mode at ``--rpm``, default 4096-tick
  encoder, with and without de-skew.
- ``encoder``: error against encoder resolution, noise, eccentricity and
  latency (no jitter), continuous mode.
- ``speed``: error against rotation speed, with and without de-skew
  (default 4096-tick encoder, no jitter).

The error is the exact distance of every plant point to the plant's mesh
(:func:`plantsim.metrics.point_to_mesh_distance`), in the turntable frame.

    PYTHONPATH=. python scripts/dynamics_study.py all --mesh /work/shared/seed-rig/maize.stl --up y
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np

from plantsim.turntable.options import TurntableOptions
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan
from plantsim.turntable.dynamics import JitterConfig, TurntableDynamics
from plantsim.turntable.encoder import EncoderConfig
from plantsim.errors import SimulationError
from plantsim.plant.mesh import load_plant
from plantsim.evaluation.metrics import MeshProximity
from plantsim.cloud.reconstruct import reconstruct
from plantsim.sensor.spec import PRESETS

LIDAR = PRESETS["urg-04lx-ug01"]
MAX_POINTS = 20_000  # plant points measured per scan
FIELDS = ["study", "series", "value", "unit", "rpm", "deskew", "points", "rms_mm", "p95_mm", "max_mm",
          "status"]


class Study:
    def __init__(self, plant, sweep_deg: float, seed: int):
        self.plant = plant
        self.sweep_deg = sweep_deg
        self.seed = seed
        self.proximity = MeshProximity(plant.vertices_turntable, plant.faces)

    def error(self, options: TurntableOptions) -> dict:
        try:
            # The ideal sensor: these rows isolate what the turntable does to the cloud.
            config = RunConfig(sensor="ideal", seed=self.seed, scan=StepScan(sweep_deg=self.sweep_deg),
                               turntable=options.replace(physics="dynamic"))
            result = run_scan(config, plant=self.plant)
        except (SimulationError, ValueError) as exc:
            return {"points": 0, "rms_mm": math.nan, "p95_mm": math.nan, "max_mm": math.nan,
                    "status": str(exc).split(";")[0]}
        cloud = reconstruct(result.raw).plant_only()
        points = cloud.points_turntable
        if len(points) > MAX_POINTS:  # the exact distance is costly; a fixed sample suffices
            points = points[np.random.default_rng(0).choice(len(points), MAX_POINTS, replace=False)]
        d = self.proximity.query(points).distance * 1e3
        return {"points": len(cloud), "rms_mm": float(np.sqrt(np.mean(d**2))),
                "p95_mm": float(np.percentile(d, 95)), "max_mm": float(d.max()), "status": "ok"}


def jitter_rows(study: Study, rpm: float):
    series = {
        "ripple_torque_nm": ("N m", [0.0, 0.01, 0.02, 0.05, 0.1, 0.2]),
        "torque_noise_nm": ("N m", [0.0, 0.01, 0.02, 0.05, 0.1, 0.2]),
        "backlash_deg": ("deg", [0.0, 0.1, 0.25, 0.5, 1.0, 2.0]),
    }
    for name, (unit, values) in series.items():
        for value in values:
            for deskew in (True, False):
                jitter = JitterConfig(**{name: value})
                options = TurntableOptions(mode="continuous", rpm=rpm, deskew=deskew,
                                           dynamics=TurntableDynamics(jitter=jitter))
                yield {"study": "jitter", "series": name + ("" if deskew else " no-deskew"),
                       "value": value, "unit": unit, "rpm": rpm, "deskew": deskew, **study.error(options)}


def encoder_rows(study: Study, rpm: float):
    base = EncoderConfig.ideal()
    series = {
        "ticks_per_rev": ("ticks", [256, 1024, 4096, 16384, 0],
                          lambda v: base.replace(ticks_per_rev=v or None)),
        "noise_rad": ("rad", [0.0, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3], lambda v: base.replace(noise_rad=v)),
        "eccentricity_rad": ("rad", [0.0, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3],
                             lambda v: base.replace(eccentricity_rad=v)),
        "latency_s": ("s", [0.0, 0.005, 0.01, 0.02, 0.05, 0.1], lambda v: base.replace(latency_s=v)),
    }
    for name, (unit, values, make) in series.items():
        for value in values:
            options = TurntableOptions(mode="continuous", rpm=rpm, encoder=make(value))
            yield {"study": "encoder", "series": name, "value": value, "unit": unit, "rpm": rpm,
                   "deskew": True, **study.error(options)}


def speed_rows(study: Study, rpm: float):
    for speed in [0.5, 1.0, 2.0, 5.0, 10.0, 20.0]:
        for deskew in (True, False):
            options = TurntableOptions(mode="continuous", rpm=speed, deskew=deskew)
            yield {"study": "speed", "series": "deskew" if deskew else "no-deskew", "value": speed,
                   "unit": "rpm", "rpm": speed, "deskew": deskew, **study.error(options)}


STUDIES = {"jitter": jitter_rows, "encoder": encoder_rows, "speed": speed_rows}


def plot(rows: list[dict], name: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[dict]] = {}
    for row in rows:
        groups.setdefault(row["series"], []).append(row)
    if name == "speed":
        fig, axes = plt.subplots(1, 1, figsize=(6, 4))
        axes = [axes]
        panels = [list(groups)]
    else:
        bases = list(dict.fromkeys(g.split(" ")[0] for g in groups))
        fig, axes = plt.subplots(1, len(bases), figsize=(4.2 * len(bases), 3.8))
        panels = [[g for g in groups if g.split(" ")[0] == b] for b in bases]
    for ax, panel in zip(axes, panels):
        for series in panel:
            rs = [r for r in groups[series] if r["status"] == "ok"]
            x = [r["value"] if not (series == "ticks_per_rev" and r["value"] == 0) else 65536 for r in rs]
            ax.plot(x, [r["rms_mm"] for r in rs], "o-", label=f"{series} RMS")
            ax.plot(x, [r["p95_mm"] for r in rs], "s--", label=f"{series} p95")
        unit = groups[panel[0]][0]["unit"]
        ax.set_xlabel(f"{panel[0].split(' ')[0] if name != 'speed' else 'speed'} ({unit})"
                      + (" (65536 = exact)" if panel[0] == "ticks_per_rev" else ""))
        ax.set_ylabel("point-to-mesh error (mm)")
        if panel[0] in ("ticks_per_rev",) or name == "speed":
            ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"plantsim turntable study: {name}")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", choices=[*STUDIES, "all"])
    parser.add_argument("--mesh", default="assets/maize.stl")
    parser.add_argument("--up", default="z")
    parser.add_argument("--units", default="m")
    parser.add_argument("--rpm", type=float, default=2.0, help="speed of the jitter and encoder studies")
    parser.add_argument("--sweep-deg", type=float, default=360.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out-dir", default="results")
    args = parser.parse_args(argv)
    plant = load_plant(args.mesh, units=args.units, up=args.up)
    study = Study(plant, args.sweep_deg, args.seed)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name in (STUDIES if args.study == "all" else [args.study]):
        t0 = time.perf_counter()
        rows = []
        print(f"== {name} ({args.mesh}, {plant.n_faces:,} faces)")
        print(f"{'series':>18} {'value':>9} {'rpm':>5} {'deskew':>6} {'points':>7} {'rms_mm':>8} "
              f"{'p95_mm':>8} {'max_mm':>8}  status")
        for row in STUDIES[name](study, args.rpm):
            rows.append(row)
            print(f"{row['series']:>18} {row['value']:>9g} {row['rpm']:>5g} {str(row['deskew']):>6} "
                  f"{row['points']:>7} {row['rms_mm']:>8.4f} {row['p95_mm']:>8.4f} {row['max_mm']:>8.3f}  "
                  f"{row['status']}", flush=True)
        with open(out / f"dynamics_{name}.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=FIELDS)
            writer.writeheader()
            writer.writerows(rows)
        plot(rows, name, out / f"dynamics_{name}.png")
        print(f"wrote {out / f'dynamics_{name}.csv'} and .png in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
