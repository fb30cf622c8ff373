"""Throughput of the builtin engine on the standard case; prints JSON.

Standard case (issue 2): quartz, L_i = 0.02 m, full-scale grains (about 2,000-2,500), the
collapse phase only (settling excluded), one core. Target: >= 1.5e7 particle-steps/s; for
reference LIGGGHTS 3.8.0 runs this 2D case at about 1.65e7 particle-steps/s on one core here
(benchmarks/crossval_liggghts.py measures both in one run).

    python benchmarks/builtin_engine.py [--aspect-ratio 1] [--duration 4]
"""

import argparse
import json
import os
import platform
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from dem.case import CollapseCase  # noqa: E402
from dem.collapse import simulate_collapse  # noqa: E402
from dem.packing import settle_column  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aspect-ratio", type=float, default=1.0)
    parser.add_argument("--duration", type=float, default=4.0, help="collapse duration in t*")
    args = parser.parse_args()
    case = CollapseCase(
        "quartz",
        0.02,
        args.aspect_ratio,
        friction=0.5,
        restitution=0.65,
        duration_over_tstar=args.duration,
        name="benchmark",
    )
    simulate_collapse(case.replace(L_i=0.005, duration_over_tstar=0.1))  # compile first
    t0 = time.perf_counter()
    packing = settle_column(case)
    settle_time = time.perf_counter() - t0
    traj = simulate_collapse(case, packing)
    print(
        json.dumps(
            {
                "benchmark": "builtin_engine",
                "date": time.strftime("%Y-%m-%d %H:%M"),
                "machine": platform.processor() or platform.machine(),
                "load_average_1min": os.getloadavg()[0],
                "case": {
                    "material": "quartz",
                    "L_i": 0.02,
                    "aspect_ratio": args.aspect_ratio,
                    "n_particles": case.n_particles,
                    "dt": traj.attrs["dt"],
                    "collapse_steps": traj.attrs["steps"],
                },
                "collapse_wall_time_s": round(traj.attrs["wall_time_s"], 3),
                "settle_wall_time_s": round(settle_time, 3),
                "particle_steps_per_second": traj.attrs["particle_steps_per_second"],
                "target_particle_steps_per_second": 1.5e7,
                "meets_target": traj.attrs["particle_steps_per_second"] >= 1.5e7,
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
